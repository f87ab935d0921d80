"""A session killed with SIGKILL resumes exactly where it stopped: nothing lost, nothing duplicated."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.support.cli import run_cli
from tests.support.study import quick_args, read_rows, read_session, run_study

ROOT = Path(__file__).resolve().parents[3]
SAMPLES = "wood,wood_on_foam,firm,pulse_soft,sinusoid_firm,hfam_firm"


def test_sigkill_then_resume_completes_without_loss_or_duplicates(tmp_path):
    args = [str(a) for a in quick_args(tmp_path, "K01", 9, "--samples", SAMPLES, mistakes=True)]
    cmd = [sys.executable, "-m", "study", "run", "--device", "sim", "--participant", "simulated", "--quiet", *args]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    folder = tmp_path / "DATA" / "K01"
    trials = folder / "trials.csv"
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline:
            if trials.exists() and trials.read_text().count(",testing,") >= 6:
                break
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.02)
        else:
            raise AssertionError("the session did not reach the testing phase in time")
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    before = trials.read_bytes()
    complete_before = before[:before.rfind(b"\n") + 1]
    assert read_session(folder)["finished_at"] is None
    n_before = complete_before.count(b"\n") - 1

    # without --resume the existing subject is refused and nothing is touched
    assert run_study(*quick_args(tmp_path, "K01", 9, "--samples", SAMPLES)) == 2
    assert trials.read_bytes() == before

    # a trace the kill interrupted mid-write (atomic write: a temporary file never renamed into place)
    (folder / "traces" / "testing_t099_a01.npz.k1ll3d_x.tmp").write_bytes(b"PK\x03\x04 half")
    assert run_study("--subject", "K01", "--out", tmp_path / "DATA", "--resume") == 0
    after = trials.read_bytes()
    assert after.startswith(complete_before)              # rows on disk were kept byte for byte
    rows = read_rows(folder)
    assert len(rows) > n_before
    keys = [(r["phase"], r["trial"], r["attempt"]) for r in rows]
    assert len(keys) == len(set(keys)), "duplicated attempt"
    # attempts are consecutive per trial: none lost
    per_trial = {}
    for r in rows:
        per_trial.setdefault((r["phase"], r["trial"]), []).append(int(r["attempt"]))
    assert all(a == list(range(1, len(a) + 1)) for a in per_trial.values())
    valid = [r for r in rows if r["phase"] == "testing" and r["valid"] == "true"]
    names = SAMPLES.split(",")
    assert {s: sum(r["sample"] == s for r in valid) for s in names} == {s: 3 for s in names}
    assert sorted(r["sample"] for r in rows if r["phase"] == "demonstration" and r["valid"] == "true") == sorted(names)
    session = read_session(folder)
    assert session["finished_at"] is not None and len(session["resumed_at"]) == 1
    # the stored order covers the attempts from before the kill too, redraw reasons included
    run = session["order"]["demonstration"]["run"] + session["order"]["testing"]["run"]
    assert [(d["trial"], d["attempt"], d["sample"]) for d in run] == \
        [(int(r["trial"]), int(r["attempt"]), r["sample"]) for r in rows if r["phase"] != "familiarization"]
    redraws = session["order"]["demonstration"]["redraws"] + session["order"]["testing"]["redraws"]
    invalid = [r for r in rows if r["phase"] != "familiarization" and r["valid"] == "false"]
    assert len(redraws) == len(invalid) and all(d["reason"] in ("rejected", "saturated", "overpowered", "no_tap")
                                                for d in redraws)
    assert len(list((folder / "traces").glob("*.npz"))) == len(rows)
    assert not list(folder.rglob("*.tmp"))

    # a finished session cannot be resumed again
    assert run_study("--subject", "K01", "--out", tmp_path / "DATA", "--resume") == 2


def test_resume_refuses_a_changed_library(tmp_path, capsys):
    import json

    assert run_study(*quick_args(tmp_path, "L01", 2, "--samples", "wood,hfam_firm", "--repetitions", "1")) == 0
    path = tmp_path / "DATA" / "L01" / "session.json"
    session = json.loads(path.read_text())
    assert run_study("--subject", "L01", "--out", tmp_path / "DATA", "--resume") == 2   # finished: refused
    session["finished_at"] = None                  # pretend it was interrupted ...
    for entry in session["catalog"]:
        if entry["transient"] == "hfam":
            entry["library_sha256"] = "0" * 64     # ... and the library file was rebuilt since
    path.write_text(json.dumps(session))
    rows_before = (tmp_path / "DATA" / "L01" / "trials.csv").read_bytes()
    capsys.readouterr()
    assert run_study("--subject", "L01", "--out", tmp_path / "DATA", "--resume") == 2
    assert "sample 'hfam_firm' changed since the session started" in capsys.readouterr().err
    assert (tmp_path / "DATA" / "L01" / "trials.csv").read_bytes() == rows_before


@pytest.fixture(scope="module")
def interrupted_session(tmp_path_factory):
    """One short finished sim session, marked unfinished: each damaged-session case edits a copy of it."""
    import json

    tmp = tmp_path_factory.mktemp("resume_schema")
    assert run_study(*quick_args(tmp, "R01", 3, "--samples", "wood", "--repetitions", "1")) == 0
    path = tmp / "DATA" / "R01" / "session.json"
    session = json.loads(path.read_text())
    session["finished_at"] = None
    path.write_text(json.dumps(session))
    return tmp / "DATA"


@pytest.mark.parametrize("edit,match", [
    (("del", "device"), "session.json has no 'device' key"),
    (("del", "participant"), "session.json has no 'participant' key"),
    (("del", "protocol"), "session.json has no 'protocol' key"),
    (("del", "seed"), "session.json has no 'seed' key"),
    (("del", "catalog"), "session.json has no 'catalog' key"),
    (("set", "device", "sim"), "device must be an object"),
    (("set", "seed", "7"), "seed must be an integer, got '7'"),
    (("set", "catalog", [5]), "catalog must be a list of sample objects"),
    (("set", "protocol", {"tap_window_s": -1}), "protocol: tap_window_s must be a positive finite number"),
])
def test_resume_of_a_damaged_session_json_names_the_file_and_key(tmp_path, capsys, interrupted_session, edit,
                                                                 match):
    """Audit resume_session_*.txt, resume_protocol_where.txt: a missing or mistyped key was a raw KeyError or
    TypeError (or blamed the command line); now one error line naming session.json and the key, exit 2. The
    command runs in the test's process (tests/support/cli.py): a raw exception would escape ``main`` here."""
    import json
    import shutil

    data = tmp_path / "DATA"
    shutil.copytree(interrupted_session, data)
    path = data / "R01" / "session.json"
    session = json.loads(path.read_text())
    if edit[0] == "del":
        del session[edit[1]]
    else:
        session[edit[1]] = edit[2]
    path.write_text(json.dumps(session))
    before = path.read_bytes()
    res = run_cli(capsys, "study", "run", "--subject", "R01", "--out", data, "--resume", "--quiet")
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr
    assert res.stderr.startswith(f"error: {path}: ") and match in res.stderr, res.stderr
    assert path.read_bytes() == before    # refused before anything was written
