"""No command's ``--out`` can remove or overwrite what it did not write: a study folder, a subject folder, a
folder that contains one, or an input is refused with or without ``--force`` (one ``error:`` line, every file
as it was); ``--force`` replaces only a folder this program wrote (its marker file), never another command's
or a folder holding someone else's files.

Once: ``analysis report DATA --out . --force`` (or any ``--out`` containing DATA) deleted every subject, and the
refusal without ``--force`` listed ``DATA/`` as "earlier results"; ``study simulate-observer --out DATA/S01
--force`` deleted that subject's trials.csv, even while the session held the subject lock.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from analysis.__main__ import main as analysis_main
from plumbing.outdir import MARKER, FileLock
from plumbing.studyfiles import LOCK_NAME
from study.__main__ import main as study_main
from tests.support.files import tree_hashes
from tests.support.kills import QUICK
from tests.support.study import write

CONSTANT = QUICK + """
[experiment]
kind = "discrimination"
sample = "firm"
reference = 700.0
levels = [500.0, 950.0]
trials_per_level = 2
"""


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """``<root>/DATA/C``: a finished forced-choice session (4 trials)."""
    root = tmp_path_factory.mktemp("nodestroy")
    proto = write(root / "p.toml", CONSTANT)
    assert study_main(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject", "C",
                       "--seed", "2", "--out", str(root / "DATA"), "--protocol", str(proto)]) == 0
    return root


def _refused(capsys, code: int, says: str) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    assert says in err, err
    return err


SIMULATE = ["simulate-observer", "--method", "updown", "--threshold", "2", "--trials", "10"]


@pytest.mark.parametrize("command, out, says", [
    ("report", ".", "contains the data folder DATA, which this command reads"),
    ("report", "DATA", "is the study folder"),
    ("report", "DATA/C/report", "lies inside the subject folder"),
    ("psychometric", ".", "contains the data DATA, which this command reads"),
    ("psychometric", "DATA/C", "is the subject folder"),
    ("simulate", "DATA/C", "is the subject folder"),
    ("simulate", "DATA", "is the study folder"),
    ("simulate", ".", "holds files this program did not write (DATA/,"),
])
@pytest.mark.parametrize("force", [False, True], ids=["plain", "force"])
def test_an_out_that_is_or_holds_study_data_is_refused_whatever_force(study, capsys, monkeypatch, command, out,
                                                                      says, force):
    monkeypatch.chdir(study)
    before = tree_hashes(study / "DATA")
    flags = ["--out", out] + (["--force"] if force else [])
    capsys.readouterr()
    if command == "simulate":
        code = study_main(SIMULATE + flags)
    else:
        code = analysis_main([command, "DATA", *flags])
    err = _refused(capsys, code, says)
    assert "earlier results" not in err                      # never an invitation to --force
    assert tree_hashes(study / "DATA") == before


def test_simulate_observer_is_refused_while_the_session_holds_the_subject_lock(study, capsys):
    folder = study / "DATA" / "C"
    before = tree_hashes(folder)
    lock = FileLock(folder / LOCK_NAME)
    assert lock.try_acquire()
    try:
        code = study_main(SIMULATE + ["--out", str(folder), "--force"])
    finally:
        lock.release()
    _refused(capsys, code, "is the subject folder")
    assert {k: v for k, v in tree_hashes(folder).items() if k != LOCK_NAME} == before


def test_force_replaces_only_a_folder_this_command_wrote(study, tmp_path, capsys):
    out = tmp_path / "SIM"
    assert study_main(SIMULATE + ["--out", str(out)]) == 0
    assert json.loads((out / MARKER).read_text())["command"]
    assert study_main(SIMULATE + ["--out", str(out), "--force", "--seed", "3"]) == 0   # its own: replaced
    mine = tmp_path / "MINE"
    mine.mkdir()
    (mine / "thesis.tex").write_text("years of work")
    capsys.readouterr()
    _refused(capsys, study_main(SIMULATE + ["--out", str(mine), "--force"]), "holds files this program did not write")
    assert (mine / "thesis.tex").read_text() == "years of work" and sorted(p.name for p in mine.iterdir()) == \
        ["thesis.tex"]
    fits = tmp_path / "FITS"
    assert analysis_main(["psychometric", str(study / "DATA"), "--out", str(fits)]) == 0
    before = tree_hashes(fits)
    capsys.readouterr()
    _refused(capsys, study_main(SIMULATE + ["--out", str(fits), "--force"]), "not replacing them")
    assert tree_hashes(fits) == before                      # another command's results are not replaced
