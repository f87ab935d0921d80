"""A forced-choice session's files are checked on ``--resume`` as strictly as the rating study's: every row against
the plan (or the staircases' replay), schedule.jsonl and staircase_state.jsonl against trials.csv, session.json's
experiment against its settings; each refusal one ``error:`` line naming the file and line, nothing changed.

Once: a row whose ``correct`` contradicted its answer, an edited intensity, another subject's id, swapped samples,
``attempt = 0``, NaN and an extra field were all accepted; an ``intensity_scale`` changed in session.json gave one
file with two scales; a duplicated or foreign staircase state line was kept; a 50 MB line was a traceback.
"""

from __future__ import annotations

import csv
import io
import json
import shutil
from pathlib import Path

import pytest

from study.__main__ import main
from tests.support.kills import ADAPTIVE_DETECTION, QUICK
from tests.support.study import write
from tests.support.files import tree_hashes

CONSTANT = QUICK + """
[experiment]
kind = "discrimination"
sample = "firm"
reference = 700.0
levels = [500.0, 950.0]
trials_per_level = 2
"""


def _session(root: Path, subject: str, protocol: str, seed: int) -> Path:
    proto = write(root / f"{subject}.toml", protocol)
    assert main(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject", subject,
                 "--seed", str(seed), "--out", str(root / "DATA"), "--protocol", str(proto)]) == 0
    return root / "DATA" / subject


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """Two finished sessions: constant stimuli (4 trials) and interleaved staircases with catch trials."""
    root = tmp_path_factory.mktemp("fc_checks")
    return {"C": _session(root, "C", CONSTANT, 2), "K": _session(root, "K", ADAPTIVE_DETECTION.format(n=2), 4)}


def _unfinished(finished: dict, subject: str, tmp_path: Path) -> Path:
    """A copy of a finished session, made resumable (``finished_at`` null)."""
    folder = tmp_path / "DATA" / subject
    shutil.copytree(finished[subject], folder)
    session = json.loads((folder / "session.json").read_text())
    session["finished_at"] = None
    (folder / "session.json").write_text(json.dumps(session, indent=2) + "\n")
    return folder


def _resume(folder: Path) -> int:
    return main(["run", "--quiet", "--subject", folder.name, "--out", str(folder.parent), "--resume"])


def _rows(folder: Path) -> tuple[list, list]:
    with open(folder / "trials.csv", newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader)
        return header, [dict(zip(header, r)) for r in reader]


def _write_rows(folder: Path, header: list, rows: list, extra: dict | None = None) -> None:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for i, r in enumerate(rows):
        w.writerow([r[h] for h in header] + ((extra or {}).get(i) or []))
    (folder / "trials.csv").write_text(buf.getvalue())


def _edit_row(index: int, **changes):
    def edit(folder: Path) -> None:
        header, rows = _rows(folder)
        rows[index].update({k: str(v) for k, v in changes.items()})
        _write_rows(folder, header, rows)
    return edit


def _swap_samples(folder: Path) -> None:
    header, rows = _rows(folder)
    r = rows[1]
    r["sample_1"], r["sample_2"] = r["sample_2"], r["sample_1"]
    _write_rows(folder, header, rows)


def _extra_field(folder: Path) -> None:
    header, rows = _rows(folder)
    _write_rows(folder, header, rows, extra={2: ["surplus"]})


def _wrong_correct(folder: Path) -> None:
    header, rows = _rows(folder)
    rows[1]["correct"] = str(1 - int(rows[1]["correct"]))
    _write_rows(folder, header, rows)


def _other_subject(folder: Path) -> None:
    _edit_row(1, subject="S02")(folder)


def _edited_intensity(folder: Path) -> None:
    header, rows = _rows(folder)
    x = float(rows[2]["intensity_physical"]) * 1.1
    rows[2]["intensity"] = rows[2]["intensity_physical"] = repr(x)     # the row itself stays consistent
    _write_rows(folder, header, rows)


def _schedule(folder: Path) -> list:
    return [json.loads(ln) for ln in (folder / "schedule.jsonl").read_text().splitlines()]


def _append_event(folder: Path, event: dict, times: int = 1) -> None:
    with open(folder / "schedule.jsonl", "a") as fh:
        for _ in range(times):
            fh.write(json.dumps({"at": "2026-01-01T00:00:00.000Z", **event}) + "\n")


def _invalid(trial: int, attempt: int = 1) -> dict:
    return {"event": "invalid_attempt", "trial": trial, "attempt": attempt, "reason": "rejected", "response": "x",
            "n_taps": [1, 1], "samples": ["a", "b"]}


def _edited_plan(folder: Path) -> None:
    lines = (folder / "schedule.jsonl").read_text().splitlines(keepends=True)
    plan = json.loads(lines[0])
    plan["trials"][0]["target_interval"] = 3 - plan["trials"][0]["target_interval"]
    (folder / "schedule.jsonl").write_text(json.dumps(plan) + "\n" + "".join(lines[1:]))


def _session_scale(folder: Path) -> None:
    session = json.loads((folder / "session.json").read_text())
    session["experiment"]["intensity_scale"] = "log10"
    (folder / "session.json").write_text(json.dumps(session))


def _both_scales(folder: Path) -> None:
    """session.json edited consistently (entry and settings): the rows on disk then disagree."""
    session = json.loads((folder / "session.json").read_text())
    session["experiment"]["intensity_scale"] = session["experiment"]["config"]["intensity_scale"] = "log10"
    (folder / "session.json").write_text(json.dumps(session))


def _huge_line(folder: Path) -> None:
    lines = (folder / "trials.csv").read_text().splitlines(keepends=True)
    (folder / "trials.csv").write_text(lines[0] + lines[1] + "C,2," + "x" * 50_000_000 + "\n" + "".join(lines[2:]))


CONSTANT_CASES = [
    ("correct contradicts the answer", _wrong_correct, "line 3: bad value (correct="),
    ("an edited intensity", _edited_intensity, "line 4: trial 3 has intensity_physical"),
    ("another subject", _other_subject, "line 3: subject='S02', but the session is 'C'"),
    ("swapped samples", _swap_samples, "line 3: trial 2 has sample_1"),
    ("attempt 0", _edit_row(1, attempt=0), "line 3: bad value (attempt='0' must be >= 1)"),
    ("NaN intensity", _edit_row(1, intensity="nan", intensity_physical="nan"),
     "line 3: bad value (intensity='nan' must be a finite number)"),
    ("NaN velocity", _edit_row(0, incoming_velocity_mean_1_m_s="nan"),
     "line 2: bad value (incoming_velocity_mean_1_m_s='nan' must be a finite number)"),
    ("an extra field", _extra_field, "line 4: 24 fields, the header has 23"),
    ("no taps", _edit_row(0, n_taps_2=0), "line 2: bad value (n_taps_2='0' must be >= 1)"),
    ("a staircase label on a constant trial", _edit_row(3, staircase="A"), "line 5: trial 4 has staircase 'A'"),
    ("an attempt beyond the cap", _edit_row(0, attempt=11), "trial 1 attempt 11, beyond max_attempts = 10"),
    ("a duplicated invalid attempt", lambda f: _append_event(f, _invalid(5), times=2),
     "trial 5 attempt 1 is logged twice"),
    ("an invalid attempt of a trial not yet run", lambda f: _append_event(f, _invalid(9)),
     "an attempt of trial 9, but trials.csv and the trials not renderable end at trial 4"),
    ("an invalid attempt after the valid one", lambda f: _append_event(f, _invalid(2)),
     "invalid attempt 1 of trial 2, but trials.csv records its attempt 1 as the valid one"),
    ("an edited plan", _edited_plan, "schedule.jsonl line 1: not this session's plan"),
    ("intensity_scale changed in session.json", _session_scale,
     "experiment.intensity_scale is 'log10' but the session's settings (experiment.config) give 'linear'"),
    ("both scales changed", _both_scales, "line 2: trial 1 has intensity"),
    ("a 50 MB line", _huge_line, "line 3: not CSV (field larger than field limit (131072))"),
]


@pytest.mark.parametrize("what, damage, says", CONSTANT_CASES, ids=[c[0] for c in CONSTANT_CASES])
def test_a_damaged_constant_session_is_refused_in_one_line(finished, tmp_path, capsys, what, damage, says):
    folder = _unfinished(finished, "C", tmp_path)
    damage(folder)
    before = tree_hashes(folder)
    capsys.readouterr()
    assert _resume(folder) == 2, what
    err = capsys.readouterr().err
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err[:500]
    assert says in err, err[:500]
    assert tree_hashes(folder) == before                      # nothing written, nothing mended


def _duplicate_state(folder: Path) -> None:
    path = folder / "staircase_state.jsonl"
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines) + lines[-1])


def _foreign_state(folder: Path) -> None:
    path = folder / "staircase_state.jsonl"
    lines = [json.loads(ln) for ln in path.read_text().splitlines()]
    lines[1]["estimate"]["threshold"] = 123.0
    path.write_text("".join(json.dumps(ln) + "\n" for ln in lines))


def _staircase_row(folder: Path) -> None:
    header, rows = _rows(folder)
    r = next(r for r in rows if r["is_catch"] == "0")
    x = float(r["intensity_physical"]) * 2
    r["intensity_physical"], r["intensity"] = repr(x), repr(__import__("math").log10(x))
    _write_rows(folder, header, rows)


ADAPTIVE_CASES = [
    ("an intensity the staircase did not ask for", _staircase_row, "has intensity_physical"),
    ("a duplicated state line", _duplicate_state, "a staircase state for trial"),
    ("a foreign state line", _foreign_state, "staircase_state.jsonl line 2: the staircase state of trial"),
]


@pytest.mark.parametrize("what, damage, says", ADAPTIVE_CASES, ids=[c[0] for c in ADAPTIVE_CASES])
def test_a_damaged_adaptive_session_is_refused_in_one_line(finished, tmp_path, capsys, what, damage, says):
    folder = _unfinished(finished, "K", tmp_path)
    damage(folder)
    before = tree_hashes(folder)
    capsys.readouterr()
    assert _resume(folder) == 2, what
    err = capsys.readouterr().err
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1, err[:500]
    assert says in err, err[:500]
    assert tree_hashes(folder) == before


def test_lost_state_lines_are_written_again_from_trials_csv(finished, tmp_path, capsys):
    """A truncated staircase_state.jsonl (lines lost while no session held it) is repaired from the rows."""
    folder = _unfinished(finished, "K", tmp_path)
    path = folder / "staircase_state.jsonl"
    whole = path.read_text()
    lines = whole.splitlines(keepends=True)
    assert len(lines) >= 4
    path.write_text(lines[0])
    capsys.readouterr()
    assert _resume(folder) == 0
    assert path.read_text() == whole
    assert f"note: {path} had 1 staircase states for {len(lines)} trials" in capsys.readouterr().out


def test_a_session_begun_without_the_attempt_cap_resumes_without_it(finished, tmp_path, capsys):
    """session.json's protocol without max_attempts (a session begun by a version before the cap): its rows are
    replayed as they were run, a trial's 11th attempt included."""
    folder = _unfinished(finished, "C", tmp_path)
    _edit_row(0, attempt=11)(folder)
    session = json.loads((folder / "session.json").read_text())
    del session["protocol"]["max_attempts"]
    (folder / "session.json").write_text(json.dumps(session, indent=2) + "\n")
    capsys.readouterr()
    assert _resume(folder) == 0, capsys.readouterr().err
    assert json.loads((folder / "session.json").read_text())["finished_at"]
