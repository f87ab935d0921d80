"""A psychophysics session holds schedule.jsonl and staircase_state.jsonl like trials.csv: one truncated or
appended to by another program while the session runs stops it before anything more is written, and after
``--resume`` (which reads and mends them) they are held again.

Once: staircase_state.jsonl was neither held nor checked, so a truncation mid-session went unnoticed.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import study.session.store
from study.__main__ import main
from tests.support.kills import ADAPTIVE_DETECTION, session_args
from tests.support.study import write


def _listing(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != ".lock"}


def _change(path: Path, how: str) -> None:
    if how == "truncated":
        data = path.read_bytes()
        path.write_bytes(data[:data[:-1].rfind(b"\n") + 1])           # its last line lost
    else:
        with open(path, "ab") as fh:
            fh.write(b'{"event": "foreign"}\n')


@pytest.mark.parametrize("name", ["staircase_state.jsonl", "schedule.jsonl"])
@pytest.mark.parametrize("how", ["truncated", "appended"])
@pytest.mark.parametrize("resumed", [False, True], ids=["new", "resumed"])
def test_a_json_lines_file_changed_under_the_runner_stops_the_session(tmp_path, monkeypatch, capsys, name, how,
                                                                      resumed):
    proto = write(tmp_path / "p.toml", ADAPTIVE_DETECTION.format(n=3))
    folder = tmp_path / "DATA" / "K"
    real = study.session.store.crash_point
    seen = {"n": 0}
    at = 1 if resumed else 2            # the rows written by this process: act after its 1st (or 2nd), before
    #                                     that trial's state line (a resumed session: before it wrote any)

    def after_step(label: str) -> None:
        real(label)
        if label.startswith("row written") and "files" not in seen:
            seen["n"] += 1
            if seen["n"] == at:
                _change(folder / name, how)
                seen["files"] = _listing(folder)

    if resumed:   # a session stopped after two trials, resumed: the files it holds now are those it read
        calls = {"n": 0}

        def stop_after_two(label: str) -> None:
            real(label)
            if label.startswith("staircase state written"):
                calls["n"] += 1
                if calls["n"] == 2:
                    raise KeyboardInterrupt
        monkeypatch.setattr(study.session.store, "crash_point", stop_after_two)
        main(session_args(proto, tmp_path / "DATA", "K", 4))
        assert json.loads((folder / "session.json").read_text())["finished_at"] is None
        capsys.readouterr()
    monkeypatch.setattr(study.session.store, "crash_point", after_step)
    args = session_args(proto, tmp_path / "DATA", "K", 4, resumed)
    code = main(args)
    err = capsys.readouterr().err
    assert "files" in seen, err
    change = "truncated" if how == "truncated" else "appended to by another program"
    assert code == 5, err
    assert err.startswith(f"error: {folder / name} was {change} while the session ran"), err
    assert "Traceback" not in err
    assert _listing(folder) == seen["files"]          # nothing written after the change
