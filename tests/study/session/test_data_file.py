"""Issue 38, items 2 and 3: trials.csv is held for the whole session and checked before each write; --resume
checks every row and refuses a damaged file naming the line, with the repair docs/study.md describes."""

import json
import shutil
from pathlib import Path

import pytest

import study.session.store
from plumbing.studyfiles import RATING_COLUMNS
from analysis.load import load_study

from tests.support.study import quick_args, read_session, run_study

ARGS = ("--samples", "wood,firm", "--repetitions", "2")


def _listing(folder: Path) -> dict:
    """Every file of a subject folder (but the lock) -> its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != ".lock"}


def _change(kind: str, trials: Path) -> None:
    """What another program (or a careless person) does to trials.csv while the session runs."""
    if kind == "moved":
        trials.rename(trials.with_name("moved-away.csv"))
    elif kind == "deleted":
        trials.unlink()
    elif kind == "replaced":
        other = trials.with_name("edited.csv")
        other.write_bytes(trials.read_bytes())   # same content, another file (an editor's save)
        other.replace(trials)
    elif kind == "truncated":
        with open(trials, "r+b") as fh:
            fh.truncate(len(trials.read_bytes().split(b"\n", 1)[0]) + 1)
    elif kind == "appended":
        with open(trials, "ab") as fh:
            fh.write(b"R01,testing,9,1,wood,real,7,false,false,false,true,1,0.1,0.001,0.1,0.001,"
                     b"2026-11-27T21:13:35.985Z,1.0,false\n")


@pytest.mark.parametrize("kind, says", [
    ("moved", "was moved away or deleted while the session ran (the runner's file is now "),
    ("deleted", "was moved away or deleted while the session ran; "),
    ("replaced", "was replaced by another file while the session ran"),
    ("truncated", "was truncated while the session ran"),
    ("appended", "was appended to by another program while the session ran"),
])
def test_trials_csv_changed_under_the_runner_stops_the_session_at_once(kind, says, tmp_path, monkeypatch, capsys):
    """Before: a moved trials.csv was recreated without a header, every later row went there, finished_at
    was set and the session exited 2 only at its end."""
    folder = tmp_path / "DATA" / "R01"
    trials = folder / "trials.csv"
    seen = {}
    real_crash_point = study.session.store.crash_point

    def after_step(name: str) -> None:  # the runner's durable steps, in order: act after the 3rd row
        real_crash_point(name)
        if name.startswith("row written") and "rows" not in seen:
            seen["n"] = seen.get("n", 0) + 1
            if seen["n"] == 3:
                seen["rows"] = trials.read_bytes()
                _change(kind, trials)
                seen["files"] = _listing(folder)

    monkeypatch.setattr(study.session.store, "crash_point", after_step)
    code = run_study(*quick_args(tmp_path, "R01", 3, *ARGS))
    err = capsys.readouterr().err
    assert code == 5, err
    assert err.startswith(f"error: {trials} {says}"), err
    assert "Traceback" not in err and "continue with --resume" in err
    assert _listing(folder) == seen["files"]            # nothing written after the change: no row, trace, event
    assert read_session(folder)["finished_at"] is None
    if kind == "moved":                                  # the runner's file keeps every row it had
        assert (folder / "moved-away.csv").read_bytes() == seen["rows"]
        assert not trials.exists()
        assert f"the runner's file is now {folder / 'moved-away.csv'}" in err


def test_put_back_the_session_resumes(tmp_path, monkeypatch, capsys):
    folder = tmp_path / "DATA" / "R01"
    trials = folder / "trials.csv"
    real_crash_point = study.session.store.crash_point
    count = {"n": 0}

    def after_step(name: str) -> None:
        real_crash_point(name)
        if name.startswith("row written"):
            count["n"] += 1
            if count["n"] == 4:
                trials.rename(folder / "aside.csv")

    monkeypatch.setattr(study.session.store, "crash_point", after_step)
    assert run_study(*quick_args(tmp_path, "R01", 3, *ARGS)) == 5
    monkeypatch.setattr(study.session.store, "crash_point", real_crash_point)
    (folder / "aside.csv").rename(trials)                 # the repair the message asks for
    assert run_study("--subject", "R01", "--out", tmp_path / "DATA", "--resume") == 0
    assert read_session(folder)["finished_at"]
    load_study(tmp_path / "DATA")                         # and analysis reads it


@pytest.fixture(scope="module")
def unfinished(tmp_path_factory):
    """A finished sim session marked unfinished, its last 3 rows removed: each case damages a copy."""
    tmp = tmp_path_factory.mktemp("damaged_rows")
    assert run_study(*quick_args(tmp, "R01", 3, *ARGS)) == 0
    folder = tmp / "DATA" / "R01"
    session = json.loads((folder / "session.json").read_text())
    session["finished_at"] = None
    (folder / "session.json").write_text(json.dumps(session))
    lines = (folder / "trials.csv").read_text().splitlines(keepends=True)
    (folder / "trials.csv").write_text("".join(lines[:-3]))
    return tmp / "DATA"


def _edit_cell(line: str, column: str, value: str) -> str:
    cells = line.rstrip("\n").split(",")
    cells[RATING_COLUMNS.index(column)] = value
    return ",".join(cells) + "\n"


DAMAGE = {
    "row cut in half": lambda ln: ln[:len(ln) // 2] + "\n",
    "short row": lambda ln: ln.rstrip("\n").rsplit(",", 1)[0] + "\n",
    "extra field": lambda ln: ln.rstrip("\n") + ",extra\n",
    "rating 92": lambda ln: _edit_cell(ln, "rating", "92"),
    "rating 0": lambda ln: _edit_cell(ln, "rating", "0"),
    "nan velocity": lambda ln: _edit_cell(ln, "incoming_velocities_m_s", "nan;0.1"),
    "inf mean velocity": lambda ln: _edit_cell(ln, "incoming_velocity_mean_m_s", "inf"),
    "negative penetration": lambda ln: _edit_cell(ln, "penetration_depths_m", "-0.001;0.001"),
    "taps not as counted": lambda ln: _edit_cell(ln, "n_taps", "5"),
    "attempt out of sequence": lambda ln: _edit_cell(ln, "attempt", "3"),
    "another subject": lambda ln: _edit_cell(ln, "subject", "R02"),
    "unknown phase": lambda ln: _edit_cell(ln, "phase", "warmup"),
    "bad time": lambda ln: _edit_cell(ln, "started_at", "yesterday"),
}
SAYS = {"row cut in half": "fields, the header has 19", "short row": "18 fields, the header has 19",
        "extra field": "20 fields, the header has 19", "rating 92": "rating='92' is not 1-7",
        "rating 0": "rating='0' is not 1-7", "nan velocity": "incoming_velocities_m_s='nan' must be a finite number",
        "inf mean velocity": "incoming_velocity_mean_m_s='inf' must be a finite number",
        "negative penetration": "penetration_depths_m='-0.001' must be a finite number >= 0",
        "taps not as counted": "values but n_taps=5",
        "attempt out of sequence": "attempt 3, expected attempt 1",
        "another subject": "subject='R02', but the session is 'R01'",
        "unknown phase": "phase='warmup' is not one of", "bad time": "started_at='yesterday' is not an ISO 8601"}


@pytest.mark.parametrize("case", sorted(DAMAGE))
def test_resume_refuses_a_damaged_row_in_the_middle_naming_the_line(case, unfinished, tmp_path, capsys):
    """Before: a row cut in half, a short row, an extra field or rating 92 in the middle were accepted and the
    session was marked complete (and `analysis report` failed on it later)."""
    data = tmp_path / "DATA"
    shutil.copytree(unfinished, data)
    trials = data / "R01" / "trials.csv"
    lines = trials.read_text().splitlines(keepends=True)
    target = next(i for i, ln in enumerate(lines) if ",demonstration," in ln)  # a row in the middle
    lines[target] = DAMAGE[case](lines[target])
    trials.write_text("".join(lines))
    before = _listing(data / "R01")
    assert run_study("--subject", "R01", "--out", data, "--resume") == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {trials} line {target + 1}: "), err
    assert SAYS[case] in err, err
    assert 'Repair (docs/study.md, "A damaged trials.csv")' in err and "trials.csv.damaged" in err
    assert _listing(data / "R01") == before               # refused before anything was written


def test_the_documented_repair_resumes_and_analysis_reads_the_result(unfinished, tmp_path, capsys):
    data = tmp_path / "DATA"
    shutil.copytree(unfinished, data)
    trials = data / "R01" / "trials.csv"
    lines = trials.read_text().splitlines(keepends=True)
    target = next(i for i, ln in enumerate(lines) if ",demonstration," in ln)
    lines[target] = _edit_cell(lines[target], "rating", "92")
    trials.write_text("".join(lines))
    assert run_study("--subject", "R01", "--out", data, "--resume") == 2
    # docs/study.md: keep a copy; move the damaged line and every line after it to trials.csv.damaged
    (data / "R01" / "trials.csv.damaged").write_text("".join(lines[target:]))
    trials.write_text("".join(lines[:target]))
    assert run_study("--subject", "R01", "--out", data, "--resume") == 0
    rows = study.session.store.SessionStore(data, "R01").read_trials()
    assert [r["phase"] for r in rows].count("testing") == 4 and read_session(data / "R01")["finished_at"]
    assert len(load_study(data).trials) == len(rows)


def test_analysis_reads_every_file_the_study_accepts(unfinished):
    """The untouched interrupted session: the study's check passes and analysis loads the same rows."""
    rows = study.session.store.SessionStore(unfinished, "R01").read_trials()
    assert len(load_study(unfinished).trials) == len(rows) > 0


@pytest.mark.parametrize("subject", ["CON", "nul", "Aux", "PRN", "COM1", "lpt9"])
def test_windows_device_names_are_refused_as_subject_ids(subject, tmp_path, capsys):
    assert run_study(*quick_args(tmp_path, subject, 3, *ARGS)) == 2
    err = capsys.readouterr().err
    assert f"subject id {subject!r} is not allowed: Windows reserves it for a device" in err
    assert not (tmp_path / "DATA").exists() or not any((tmp_path / "DATA").iterdir())
