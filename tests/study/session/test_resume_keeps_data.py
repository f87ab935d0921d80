"""--resume never loses what is on disk (auditor: resume_truncates_row, resume_deletes_user_tmp): a complete
last row that only lacks its newline is kept; a torn one is kept in ``trials.csv.torn`` with a note; only
the atomic writes' own temporary files are removed, never a user's ``*.tmp``.

Each session (the one killed, then its ``--resume``) runs ``study run`` in a forked child of this warm process
(:func:`tests.support.kills.forked`): a process of its own, killed by a real SIGKILL, without an interpreter
start-up and its imports each time."""

import signal
import subprocess
from pathlib import Path

import pytest

import study.session.store as store
from tests.support.files import sha256
from tests.support.kills import forked

from tests.support.study import quick_args, read_rows, run_study

SAMPLES = ("--samples", "wood,firm")


def _study(tmp: Path, *args, env=None) -> subprocess.CompletedProcess:
    """``study run --quiet`` (a new simulated session, or ``--resume``) in a forked child: its exit status
    (-signal when killed), what it printed on stdout and on stderr."""
    argv = ["run", "--quiet", *[str(a) for a in args]]
    if "--resume" not in args:
        argv[2:2] = ["--device", "sim", "--participant", "simulated"]
    out, err = tmp / "study.stdout", tmp / "study.stderr"
    code = forked(argv, dict(env or {}), stdout=out, stderr=err)
    return subprocess.CompletedProcess(argv, code, out.read_text(), err.read_text())


@pytest.fixture(scope="module")
def killed_after_second_row(tmp_path_factory):
    """A function making a session SIGKILLed right after its 2nd familiarization row reached trials.csv."""
    ref = tmp_path_factory.mktemp("ref")
    log = ref / "steps.log"
    # the uninterrupted session runs in this process, counting its durable steps: the forks then inherit its
    # imports
    store._CRASH_COUNT = 0
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("STUDY_CRASH_LOG", str(log))
        assert run_study(*quick_args(ref, "S02", 3, *SAMPLES)) == 0
    steps = [ln.split(" ", 1) for ln in log.read_text().splitlines()]
    at = next(n for n, name in steps if name == "row written: familiarization 2/1")

    def make(tmp: Path) -> Path:
        res = _study(tmp, *quick_args(tmp, "S02", 3, *SAMPLES), env={"STUDY_CRASH_AT": at})
        assert res.returncode == -signal.SIGKILL, res.stderr
        return tmp / "DATA" / "S02"

    return make


def test_resume_keeps_a_complete_last_row_that_lacks_its_newline(tmp_path, killed_after_second_row):
    folder = killed_after_second_row(tmp_path)
    trials = folder / "trials.csv"
    data = trials.read_bytes()
    assert data.endswith(b"\n") and data.count(b"\n") == 3          # header + 2 rows
    trials.write_bytes(data[:-1])                                   # the crash lost only the newline
    last_row = data[:-1].rsplit(b"\n", 1)[1]
    res = _study(tmp_path, "--subject", "S02", "--out", tmp_path / "DATA", "--resume", *SAMPLES)
    assert res.returncode == 0, res.stderr
    after = trials.read_bytes()
    assert after.startswith(data)                                   # both rows kept, byte for byte
    keys = [(r["phase"], r["trial"], r["attempt"]) for r in read_rows(folder)]
    assert keys.count(("familiarization", "2", "1")) == 1 and len(keys) == len(set(keys))
    assert after.count(last_row + b"\n") == 1
    assert "torn" not in res.stdout and not (folder / "trials.csv.torn").exists()


def test_resume_keeps_a_torn_last_row_in_a_torn_file_with_a_note(tmp_path, killed_after_second_row):
    folder = killed_after_second_row(tmp_path)
    trials = folder / "trials.csv"
    data = trials.read_bytes()
    torn = data[:-1].rsplit(b"\n", 1)[1][:25]                       # half of the 2nd row
    cut = data[:-1].rfind(b"\n") + 1
    trials.write_bytes(data[:cut] + torn)
    res = _study(tmp_path, "--subject", "S02", "--out", tmp_path / "DATA", "--resume", *SAMPLES)
    assert res.returncode == 0, res.stderr
    assert f"note: {trials} line 3 was torn" in res.stdout and f"{trials}.torn" in res.stdout
    assert (folder / "trials.csv.torn").read_bytes() == torn + b"\n"
    assert trials.read_bytes().startswith(data[:cut])              # the whole rows before it are kept
    keys = [(r["phase"], r["trial"], r["attempt"]) for r in read_rows(folder)]
    assert len(keys) == len(set(keys)) and ("familiarization", "2", "1") in keys   # measured again


def test_resume_keeps_the_users_own_tmp_files(tmp_path, killed_after_second_row):
    folder = killed_after_second_row(tmp_path)
    notes = folder / "notes.2026-11-26.tmp"
    notes.write_text("the experimenter's notes\n")
    draft = folder / "traces" / "my.draft.tmp"
    draft.write_text("mine too\n")
    half = folder / "traces" / "testing_t001_a01.npz.k1ll3d_x.tmp"   # atomic_open's own, never renamed
    half.write_bytes(b"PK\x03\x04 half")
    sums = {p: sha256(p) for p in (notes, draft)}
    res = _study(tmp_path, "--subject", "S02", "--out", tmp_path / "DATA", "--resume", *SAMPLES)
    assert res.returncode == 0, res.stderr
    assert {p: sha256(p) for p in (notes, draft)} == sums
    assert not half.exists()
    assert "removed 1 half-written temporary file(s) of the interrupted run (testing_t001_a01.npz.k1ll3d_x.tmp)" \
        in res.stdout
