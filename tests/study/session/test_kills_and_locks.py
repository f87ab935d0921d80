"""SIGKILL at start-up and at every phase boundary, then --resume: the data equal an uninterrupted run.
Two runners on one subject: exactly one runs, the other names the lock holder. Bad files name the file.

The full 200-case run is ``python -m benchmarks study_kill``; here a seeded subset (start-up steps, the
familiarization and demonstration boundaries, one random step) keeps the test short.
"""

import json
import os
import random
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.support.kills import KillHarness
from plumbing.fileio import atomic_write_text
from plumbing.npzfile import load_npz
from study.session.store import SessionStore

from tests.support.study import quick_args, read_rows, run_study

ROOT = Path(__file__).resolve().parents[3]


def test_sigkill_at_startup_and_phase_boundaries_then_resume_matches_an_uninterrupted_run(tmp_path):
    harness = KillHarness(tmp_path)
    steps = harness.steps
    where = [s.split(" ", 1)[1] for s in steps]
    last_fam_row = max(i for i, w in enumerate(where) if w.startswith("row written: familiarization")) + 1
    last_demo_row = max(i for i, w in enumerate(where) if w.startswith("row written: demonstration")) + 1
    assert where[last_fam_row] == "event logged: familiarization_ended"  # the window the old code lost
    picks = [2, last_fam_row, last_demo_row, random.Random(7).randint(1, len(steps))]
    results = [harness.case(step, i) for i, step in enumerate(picks)]
    assert [r.get("error") for r in results] == [None] * len(picks), results
    assert all(r["killed"] == -signal.SIGKILL for r in results)
    assert results[0].get("restarted")            # killed before the folder existed: a fresh start works
    # the reference itself has the protocol's counts: 2 samples x 2 repetitions valid in testing, each once
    # in demonstration, familiarization up to familiarization_max_windows = 3
    ref = harness.reference
    assert sum(r[0] == "testing" and r[4] == "true" for r in ref) == 4
    assert sum(r[0] == "demonstration" and r[4] == "true" for r in ref) == 2
    assert sum(r[0] == "familiarization" for r in ref) == 3


def test_two_runners_on_one_subject_exactly_one_runs(tmp_path):
    args = [str(a) for a in quick_args(tmp_path, "T01", 4, "--samples", "wood", "--repetitions", "1")]
    cmd = [sys.executable, "-m", "study", "run", "--device", "sim", "--participant", "simulated", "--quiet", *args]
    procs = [subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(2)]
    outs = [p.communicate(timeout=300) for p in procs]
    codes = sorted(p.returncode for p in procs)
    assert codes == [0, 2], outs
    loser = outs[[p.returncode for p in procs].index(2)][1]
    assert loser.startswith("error: subject 'T01'") and "pid " in loser and " on host " in loser, loser
    rows = read_rows(tmp_path / "DATA" / "T01")
    keys = [(r["phase"], r["trial"], r["attempt"]) for r in rows]
    assert len(keys) == len(set(keys))
    assert sum(r["phase"] == "testing" and r["valid"] == "true" for r in rows) == 1
    assert not list((tmp_path / "DATA").glob(".*starting*"))


def test_second_resume_while_one_runs_names_the_holder(tmp_path, capsys):
    store = SessionStore(tmp_path / "DATA", "H01")
    store.check()
    store.create({"subject": "H01", "finished_at": None})
    # another process holds the lock: the resume is refused with its pid and host, nothing written
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; sys.path.insert(0, '.');"
        "from study.session.store import SubjectLock; from pathlib import Path;"
        f"SubjectLock(Path({str(store.dir)!r})).acquire('H01'); print('locked', flush=True); time.sleep(60)")],
        cwd=ROOT, stdout=subprocess.PIPE, text=True)
    store.release()
    try:
        assert holder.stdout.readline().strip() == "locked"
        before = {p.name: p.read_bytes() for p in store.dir.iterdir() if p.is_file()}
        assert run_study("--subject", "H01", "--out", tmp_path / "DATA", "--resume") == 2
        err = capsys.readouterr().err
        assert f"pid {holder.pid} on host " in err and err.startswith("error: subject 'H01' is in use"), err
        assert {p.name: p.read_bytes() for p in store.dir.iterdir() if p.is_file()} == before
    finally:
        holder.kill()
        holder.wait()


def test_files_follow_the_umask(tmp_path):
    old = os.umask(0o002)
    try:
        store = SessionStore(tmp_path, "U01")
        store.check()
        store.create({"subject": "U01", "finished_at": None})
        store.write_trace("testing", 1, 1, {"x": np.zeros(3)})
        path = atomic_write_text(tmp_path / "x.txt", "hi")
    finally:
        os.umask(old)
        store.release()
    for p in (store.session_path, store.trials_path, store.schedule_path, path,
              store.trace_path("testing", 1, 1)):
        assert oct(p.stat().st_mode & 0o777) == oct(0o664), p
    assert oct(store.dir.stat().st_mode & 0o777) == oct(0o775)


@pytest.mark.parametrize("content, expected", [
    (b"\x80\x04K\x01.", "is a Python pickle"),
    (b"hello, not a zip", "is not an .npz (zip) archive"),
    (b"PK\x03\x04truncated", "truncated or corrupt zip"),
    (b"\x93NUMPY\x01\x00", "single-array .npy"),
    (b"", "is empty"),
])
def test_bad_npz_named_and_told_apart(tmp_path, content, expected):
    path = tmp_path / "lib.npz"
    path.write_bytes(content)
    with pytest.raises(ValueError) as exc:
        load_npz(path, "HFAM library")
    assert str(exc.value).startswith(f"{path}: HFAM library") and expected in str(exc.value)


@pytest.mark.parametrize("content, expected", [
    (b"\xff\xfe\x00binary", "not UTF-8 text"),
    (b'{"subject": "B01", "seed": ', "truncated JSON"),
    (b"", "empty file"),
])
def test_damaged_session_json_named(tmp_path, capsys, content, expected):
    folder = tmp_path / "DATA" / "B01"
    (folder / "traces").mkdir(parents=True)
    (folder / "session.json").write_bytes(content)
    (folder / "trials.csv").write_text("x\n")
    assert run_study("--subject", "B01", "--out", tmp_path / "DATA", "--resume") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {folder / 'session.json'}:") and expected in err[0], err


def test_non_utf8_trials_csv_named(tmp_path):
    store = SessionStore(tmp_path, "C01")
    store.check()
    store.create({"subject": "C01", "finished_at": None})
    store.release()
    with open(store.trials_path, "ab") as fh:
        fh.write(b"C01,testing,1,1,w\xe9od\n")
    with pytest.raises(ValueError, match=r"trials.csv line 2: not UTF-8 text"):
        store.read_trials()


def test_interrupted_startup_debris_is_cleaned_and_a_fresh_start_works(tmp_path):
    data = tmp_path / "DATA"
    debris = data / ".D01.starting-abc123"
    debris.mkdir(parents=True)
    (debris / "session.json").write_text("{")
    store = SessionStore(data, "D01")
    store.check()
    assert not debris.exists()
    store.create({"subject": "D01", "finished_at": None})
    store.release()
    assert json.loads(store.session_path.read_text())["subject"] == "D01"
