"""A stimulus that can never be rendered ends its trial, not the session: after the protocol's ``max_attempts``
invalid attempts the trial is recorded as not renderable and the session goes on (forced choice, constant and
adaptive, and the rating study); a level beyond the device is refused before the subject folder is made; a kill
at any of these steps resumes to the same files.

Once: a detection level far above the amplifier's limit saturated every tap and its trial was retried for ever
(~2,000 attempts and ~0.9 GB of traces in a minute of sim); a level above the stiffness bound was refused after
the subject folder was made, so that session could never finish; a torn invalid-attempt line made the resumed
session write the next attempt's traces over that attempt's.
"""

from __future__ import annotations

import json
import signal
from pathlib import Path

import pytest

from study.__main__ import main
from tests.support.kills import QUICK, ForcedChoiceKillHarness, forked, read_rows, session_args
from tests.support.files import sha256
from tests.support.study import write

CAPPED = QUICK + "max_attempts = 2\n"
#: 150 N*s/m saturates the sim's amplifier (4 A x 2.35 N/A = 9.4 N) at every tap of a hand that taps at 0.1 m/s
#: or faster (FAST_HAND), though not at the slowest taps a person makes (0.05 m/s: 7.5 N), so it is accepted
#: and every attempt is invalid
SATURATING = CAPPED + """
[experiment]
kind = "detection"
sample = "pulse_firm"
levels = [0.5, 150.0]
trials_per_level = 1
"""
ADAPTIVE = CAPPED + """
[experiment]
kind = "detection"
sample = "pulse_firm"
method = "updown"
order = "fixed"

[experiment.staircases.A]
start = 150.0
step_down = [0.3]
max_trials = 2

[experiment.staircases.B]
start = 0.5
step_down = [0.3]
max_trials = 2
"""


FAST_HAND = "velocity_min_m_s = 0.1\nvelocity_max_m_s = 0.3\n"


def _fast(work: Path) -> tuple:
    """``--participant-config`` of a simulated hand that taps at 0.1-0.3 m/s."""
    work.mkdir(parents=True, exist_ok=True)
    return ("--participant-config", write(work / "fast_hand.toml", FAST_HAND))


def _events(folder: Path, kind: str) -> list:
    return [e for e in map(json.loads, (folder / "schedule.jsonl").read_text().splitlines()) if e["event"] == kind]


@pytest.fixture(scope="module")
def saturating(tmp_path_factory):
    work = tmp_path_factory.mktemp("cap")
    return ForcedChoiceKillHarness(work, SATURATING, extra=_fast(work / "hand"))


def test_a_trial_that_never_renders_is_recorded_and_the_session_goes_on(saturating):
    folder = saturating.work / "ref" / "K"
    rows = read_rows(folder)
    skips = _events(folder, "not_renderable")
    assert [float(r["intensity_physical"]) for r in rows] == [0.5]            # the renderable level's trial
    assert len(skips) == 1 and skips[0]["intensity_physical"] == 150.0
    assert skips[0]["attempts"] == 2 and skips[0]["reasons"] == ["saturated", "saturated"]
    invalid = _events(folder, "invalid_attempt")
    assert [(e["trial"], e["attempt"]) for e in invalid] == [(skips[0]["trial"], 1), (skips[0]["trial"], 2)]
    assert len(list((folder / "traces").glob("*.npz"))) == 2 * (2 + 1)         # two attempts, one valid trial
    session = json.loads((folder / "session.json").read_text())
    assert session["finished_at"] and session["protocol"]["max_attempts"] == 2
    assert not (folder / ".lock").exists()                                    # no stale lock after a clean end


def test_a_kill_around_a_trial_not_renderable_resumes_to_the_same_files(saturating):
    where = [s.split(" ", 1)[1] for s in saturating.steps]
    last_invalid = max(i for i, w in enumerate(where) if w.startswith("event logged: invalid_attempt")) + 1
    skip = where.index("event logged: not_renderable") + 1
    # killed after the trial's last attempt but before it was recorded as not renderable, and just after
    results = [saturating.case(step, i) for i, step in enumerate((last_invalid, skip))]
    assert [r.get("error") for r in results] == [None, None], results
    for r in results:
        skips = _events(r["folder"], "not_renderable")
        assert len(skips) == 1 and skips[0]["trial"] == _events(saturating.work / "ref" / "K",
                                                               "not_renderable")[0]["trial"]
        assert len(_events(r["folder"], "invalid_attempt")) == 2                # never a third attempt


def test_a_torn_invalid_attempt_line_is_set_aside_and_its_traces_kept(tmp_path):
    harness = ForcedChoiceKillHarness(tmp_path, SATURATING.replace("max_attempts = 2", "max_attempts = 3"),
                                      extra=_fast(tmp_path / "hand"))
    where = [s.split(" ", 1)[1] for s in harness.steps]
    first = where.index("event logged: invalid_attempt") + 1
    out = tmp_path / "torn"
    assert forked(session_args(harness.protocol, out, "K", harness.seed, False, *harness.extra),
                  {"STUDY_CRASH_AT": str(first)}) == -signal.SIGKILL
    folder = out / "K"
    schedule = folder / "schedule.jsonl"
    data = schedule.read_bytes()
    head = data[:data[:-1].rfind(b"\n") + 1]
    event = json.loads(data[len(head):])
    assert event["event"] == "invalid_attempt" and event["attempt"] == 1
    schedule.write_bytes(head + data[len(head):len(head) + 50])               # the line torn after 50 bytes
    traces = {p.name: sha256(p) for p in (folder / "traces").glob(f"interval*_t{event['trial']:03d}_a01.npz")}
    assert len(traces) == 2
    assert forked(session_args(harness.protocol, out, "K", harness.seed, resume=True), {}) == 0
    assert (folder / "schedule.jsonl.torn").read_bytes() == data[len(head):len(head) + 50] + b"\n"
    kept = {p.name: sha256(p) for p in (folder / "traces" / "interrupted").glob("*.npz")}
    assert kept == traces                                                     # the torn attempt's traces, unchanged
    invalid = [(e["trial"], e["attempt"]) for e in _events(folder, "invalid_attempt")]
    assert invalid == [(event["trial"], 1), (event["trial"], 2), (event["trial"], 3)]   # attempt 1 ran again
    assert json.loads((folder / "session.json").read_text())["finished_at"]


def test_a_staircase_whose_level_never_renders_stops_and_the_others_go_on(tmp_path):
    harness = ForcedChoiceKillHarness(tmp_path, ADAPTIVE, extra=_fast(tmp_path / "hand"))
    folder = tmp_path / "ref" / "K"
    rows = read_rows(folder)
    skips = _events(folder, "not_renderable")
    assert [s["staircase"] for s in skips] == ["A"] and skips[0]["intensity_physical"] == 150.0
    assert [r["staircase"] for r in rows] == ["B", "B"]                      # B ran its two trials
    assert [int(r["trial"]) for r in rows] == [2, 3]                         # trial 1 was A's, not renderable
    states = [json.loads(ln) for ln in (folder / "staircase_state.jsonl").read_text().splitlines()]
    assert [s["trial"] for s in states] == [2, 3] and states[-1]["finished"] is True
    where = [s.split(" ", 1)[1] for s in harness.steps]
    skip = where.index("event logged: not_renderable") + 1
    rows_written = [i + 1 for i, w in enumerate(where) if w.startswith("row written")]
    results = [harness.case(step, i) for i, step in enumerate((skip - 1, skip, rows_written[0]))]
    assert [r.get("error") for r in results] == [None] * 3, results          # the staircases replay the skip


def _rating_args(tmp_path: Path, out: Path) -> list:
    proto = write(tmp_path / "p.toml", "tap_window_s = 0.4\nfamiliarization_window_s = 0.4\n"
                                       "familiarization_max_windows = 1\nhoming_after_s = 0.3\n"
                                       "homing_before_max_s = 0.1\nmax_attempts = 2\n")
    rejecting = write(tmp_path / "rejecting.toml", "p_reject = 1.0\n")
    return ["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject", "R1", "--seed", "3",
            "--out", str(out), "--protocol", str(proto), "--samples", "wood,firm", "--repetitions", "1",
            "--participant-config", str(rejecting)]


def _without_times(events: list) -> list:
    return [{k: v for k, v in e.items() if k != "at"} for e in events]


def test_the_rating_study_caps_attempts_too(tmp_path):
    log = tmp_path / "steps.log"
    assert forked(_rating_args(tmp_path, tmp_path / "DATA"), {"STUDY_CRASH_LOG": str(log)}) == 0
    folder = tmp_path / "DATA" / "R1"
    rows = [r for r in read_rows(folder) if r["phase"] != "familiarization"]
    assert len(rows) == 2 * 2 * 2 and all(r["valid"] == "false" and r["rejected"] == "true" for r in rows)
    skips = _events(folder, "not_renderable")
    assert sorted((s["phase"], s["sample"], s["attempts"]) for s in skips) == [
        ("demonstration", "firm", 2), ("demonstration", "wood", 2), ("testing", "firm", 2), ("testing", "wood", 2)]
    assert json.loads((folder / "session.json").read_text())["finished_at"]
    # killed between a trial's last invalid attempt (its row) and its not_renderable event: --resume logs it
    steps = log.read_text().splitlines()
    step = next(i for i, s in enumerate(steps, start=1) if s.split(" ", 1)[1] == "event logged: not_renderable") - 1
    assert steps[step - 1].split(" ", 1)[1].startswith("row written")
    out = tmp_path / "KILLED"
    assert forked(_rating_args(tmp_path, out), {"STUDY_CRASH_AT": str(step)}) == -signal.SIGKILL
    assert _events(out / "R1", "not_renderable") == []
    assert forked(["run", "--quiet", "--subject", "R1", "--out", str(out), "--resume"], {}) == 0
    assert _without_times(_events(out / "R1", "not_renderable")) == _without_times(skips)
    keys = ("phase", "trial", "attempt", "sample", "rejected", "valid")
    assert [[r[k] for k in keys] for r in read_rows(out / "R1")] == [[r[k] for k in keys] for r in read_rows(folder)]


@pytest.mark.parametrize("table, says", [
    ('kind = "detection"\nsample = "pulse_firm"\nlevels = [0.5, 500.0]',
     "[experiment] levels = 500: a pulse of amplitude 500 N*s/m asks 25 N even at a slow tap (0.05 m/s), beyond "
     "the 9.4 N of "),
    ('kind = "detection"\nsample = "pulse_firm"\nmethod = "updown"\n[experiment.staircases.A]\nstart = 500.0\n'
     'step_down = [0.3]\nmax_trials = 3', "[experiment] staircases.A (its first intensity) = 500: a pulse"),
    ('kind = "detection"\nsample = "pulse_firm"\nmethod = "updown"\n[experiment.staircases.A]\nstart = 5.0\n'
     'max_intensity = 400.0\nstep_down = [0.3]\nmax_trials = 3', "[experiment] staircases.A.max_intensity = 400"),
    ('kind = "discrimination"\nsample = "firm"\nreference = 700.0\nmethod = "updown"\n[experiment.staircases.S]\n'
     'start = 1e9\nstep_down = [0.1]\nmax_trials = 3',
     "[experiment] staircases.S (its first intensity) = 1e+09: stiffness 1e+09 N/m is beyond what"),
    ('kind = "discrimination"\nsample = "firm"\nreference = 700.0\nlevels = [500.0, 1e9]', "1e+09 N/m"),
])
def test_a_level_beyond_the_device_is_refused_before_the_subject_folder(tmp_path, capsys, table, says):
    proto = write(tmp_path / "p.toml", QUICK + "[experiment]\n" + table + "\n")
    assert main(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject", "X1",
                 "--out", str(tmp_path / "DATA"), "--protocol", str(proto)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and says in err and "Traceback" not in err, err
    assert list((tmp_path / "DATA").iterdir()) == []                         # no subject folder, no debris
