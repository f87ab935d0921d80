"""Psychophysics sessions (issue 34): experiment kinds in the study runner, end to end on the sim device.

Short sessions (a few trials, 0.6-1 s tapping windows); the long ones (JND recovery, every-trial kills) are
``python -m benchmarks psy_session``.
"""

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from http.client import HTTPException
from pathlib import Path

import numpy as np
import pytest
from scipy import signal as sps

from tests.support.kills import ADAPTIVE_DETECTION, QUICK, REAL_VIRTUAL, ForcedChoiceKillHarness, forked, session_args
from devices.sim import SimDevice
from study.__main__ import main
from stimuli import load_catalog
from study.forcedchoice.experiment import ExperimentConfig, load_protocol_file, plan_trials, stimulus_catalog
from study.session.participants import SimParticipantConfig
from study.forcedchoice.perception import Z75_SQRT2, choose, sigma_of_jnd, stiffness_weber_fraction, tap_stiffness_N_m
from study.session.uistate import UiState

from tests.support.needs import need
from tests.support.study import read_rows, read_session, write
from tests.support.audio import espeak_reference, find_cue

ROOT = Path(__file__).resolve().parents[3]
CONTRACT_COLUMNS = ("trial", "condition", "staircase", "intensity", "correct", "is_catch", "response",
                    "target_interval")
DISCRIMINATION = QUICK + """
[experiment]
kind = "discrimination"
sample = "firm"
reference = 700.0
levels = [500.0, 700.0, 950.0]
trials_per_level = 2
"""
DETECTION = QUICK + """
[experiment]
kind = "detection"
sample = "pulse_firm"
levels = [0.2, 4.55]
trials_per_level = 2
intensity_scale = "log10"
"""


def run(tmp: Path, subject: str, protocol: str, *extra, seed: int = 2) -> int:
    proto = write(tmp / f"{subject}.toml", protocol)
    return main(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject", subject,
                 "--seed", str(seed), "--out", str(tmp / "DATA"), "--protocol", str(proto), *map(str, extra)])


# -- the protocol file ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("table, message", [
    ('kind = "discrimination"\nsample = "firm"\nreference = 700.0\nlevles = [1.0, 2.0]',
     "unknown [experiment] key(s) ['levles']"),
    ('kind = "staircase"', "[experiment] kind must be one of ['real-virtual-2afc', 'discrimination', 'detection']"),
    ('kind = "detection"\nsample = "pulse_firm"\nlevels = [1.0, 2.0]\nmethod = "quest+"',
     "[experiment] levels are for method \"constant\"; method 'quest+' chooses the intensities"),
    ('kind = "detection"\nsample = "pulse_firm"\nmethod = "updown"',
     "[experiment] method 'updown' needs at least one staircase table"),
    ('kind = "detection"\nsample = "pulse_firm"\nmethod = "updown"\n[experiment.staircases.A]\nstart = 2.0\n'
     'step_down = [0.1]\nmax_trial = 30', "[experiment] staircases.A.max_trial is not a parameter of method 'updown'"),
    ('kind = "real-virtual-2afc"\nrenderings = ["firm"]\nmethod = "psi"',
     "[experiment] method 'psi': real-virtual-2afc varies no intensity"),
    ('kind = "discrimination"\nsample = "firm"\nlevels = [600.0, 800.0]',
     "[experiment] reference (the reference's stiffness_N_m) is required"),
    ('kind = "discrimination"\nsample = "firm"\nreference = 700.0\nlevels = [600.0, -800.0]',
     "[experiment] levels must be > 0"),
    ('kind = "detection"\nsample = "nope"\nlevels = [1.0, 2.0]', "[experiment] sample = 'nope' is not in the catalog"),
    ('kind = "detection"\nsample = "firm"\nlevels = [1.0, 2.0]',
     "vary = \"amplitude_Ns_m\" needs a pulse or sinusoid transient; sample 'firm' has 'none'"),
    ('kind = "real-virtual-2afc"\nreal_sample = "firm"\nrenderings = ["soft"]',
     "[experiment] real_sample = 'firm' is a virtual sample, not a real one"),
    ('kind = "real-virtual-2afc"\nrenderings = ["firm"]\ntrials_per_level = 0', "trials_per_level must be"),
])
def test_a_bad_experiment_table_is_one_error_naming_the_file_and_key(tmp_path, capsys, table, message):
    proto = write(tmp_path / "psy.toml", QUICK + "[experiment]\n" + table + "\n")
    assert main(["run", "--subject", "E1", "--seed", "1", "--out", str(tmp_path / "DATA"),
                 "--protocol", str(proto)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {proto}") and message in err and "Traceback" not in err, err
    assert not (tmp_path / "DATA" / "E1").exists()


def test_samples_and_a_lapse_of_one_half_are_refused(tmp_path, capsys):
    proto = write(tmp_path / "psy.toml", DISCRIMINATION)
    assert main(["run", "--subject", "E2", "--out", str(tmp_path / "DATA"), "--protocol", str(proto),
                 "--samples", "firm"]) == 2
    assert "--samples: a psychophysics session presents the samples its protocol's [experiment] names" \
        in capsys.readouterr().err
    part = write(tmp_path / "observer.toml", "lapse = 0.5\n")
    assert main(["run", "--subject", "E3", "--out", str(tmp_path / "DATA"), "--protocol", str(proto),
                 "--participant-config", str(part)]) == 2
    err = capsys.readouterr().err
    assert f"error: {part}: participant.lapse must be below 0.5" in err, err


# -- the plan -------------------------------------------------------------------------------------------------

def test_constant_stimuli_plan_is_balanced_seeded_and_per_subject():
    exp = ExperimentConfig(kind="discrimination", sample="firm", reference=700.0, levels=[500.0, 700.0, 900.0],
                           trials_per_level=7)
    plan = plan_trials(exp, 11, "S1")
    assert [t.trial for t in plan] == list(range(1, 22))
    for level in (500.0, 700.0, 900.0):
        targets = [t.target_interval for t in plan if t.intensity_physical == level]
        assert len(targets) == 7 and sorted(targets)[:3] == [1, 1, 1] and sorted(targets)[-3:] == [2, 2, 2]
    for t in plan:   # the comparison is in the target interval, the reference in the other
        assert t.samples[t.target_interval - 1] == f"firm@stiffness_N_m={t.intensity_physical:g}"
        assert t.samples[2 - t.target_interval] == "firm@stiffness_N_m=700"
    assert plan_trials(exp, 11, "S1") == plan
    assert plan_trials(exp, 11, "S2") != plan and plan_trials(exp, 12, "S1") != plan


# -- the simulated participant's noise ------------------------------------------------------------------------

def test_stiffness_percepts_give_the_participants_weber_fraction():
    cfg = SimParticipantConfig(lapse=0.0)
    w = stiffness_weber_fraction(cfg.jnd_force_frac, cfg.jnd_compliance_frac)
    # force 7 % and compliance 15 % JNDs: log-SDs 0.0709 and 0.1465, in quadrature 0.1628 -> W = 16.8 %
    assert sigma_of_jnd(0.07) == pytest.approx(math.log(1.07) / Z75_SQRT2)
    assert w == pytest.approx(math.expm1(Z75_SQRT2 * math.hypot(math.log(1.07), math.log(1.15)) / Z75_SQRT2))
    assert 0.166 < w < 0.170
    rng = np.random.default_rng(3)
    n = 20000
    at_jnd = sum(choose("discrimination", "stiffness_N_m", (700.0, 700.0 * (1 + w)), cfg, rng)[0] == 2
                 for _ in range(n)) / n
    at_pse = sum(choose("discrimination", "stiffness_N_m", (700.0, 700.0), cfg, rng)[0] == 2 for _ in range(n)) / n
    assert abs(at_jnd - 0.75) < 0.012 and abs(at_pse - 0.5) < 0.012, (at_jnd, at_pse)
    lapsing = SimParticipantConfig(lapse=0.2)
    # a lapse is a coin flip: a huge difference is then answered right 1 - 0.2 / 2 of the time
    sure = sum(choose("discrimination", "stiffness_N_m", (700.0, 7000.0), lapsing, rng)[0] == 2
               for _ in range(n)) / n
    assert abs(sure - 0.9) < 0.012, sure


# -- whole sessions -------------------------------------------------------------------------------------------

def test_discrimination_session_follows_the_contract_and_stays_blind(tmp_path, monkeypatch):
    shown = []
    original = UiState.set_subject
    monkeypatch.setattr(UiState, "set_subject", lambda self, m, p: (shown.append(m), original(self, m, p))[1])
    no_lapse = write(tmp_path / "observer.toml", "lapse = 0.0\n")
    assert run(tmp_path, "D1", DISCRIMINATION, "--serve", "--participant-config", no_lapse) == 0
    folder = tmp_path / "DATA" / "D1"
    rows = read_rows(folder)
    assert set(CONTRACT_COLUMNS) <= set(rows[0]) and [int(r["trial"]) for r in rows] == list(range(1, 7))
    session = read_session(folder)
    exp = session["experiment"]
    assert {k: exp[k] for k in ("kind", "alternatives", "method", "intensity_scale", "reference")} == \
        {"kind": "discrimination", "alternatives": 2, "method": "constant", "intensity_scale": "linear",
         "reference": 700.0}
    assert exp["guess_rate"] == 0.0 and session["finished_at"] is not None
    plan = plan_trials(ExperimentConfig(**exp["config"]), session["seed"], "D1")
    info = SimDevice().info
    for r, t in zip(rows, plan):
        assert (r["condition"], float(r["intensity"]), int(r["target_interval"]), r["sample_1"], r["sample_2"]) \
            == (t.condition, t.intensity_physical, t.target_interval, *t.samples)
        assert r["staircase"] == "" and r["is_catch"] == "0" and r["response"] in ("1", "2")
        assert int(r["correct"]) == int(r["response"] == r["target_interval"])
        for k in (1, 2):
            # what the participant judged: the stiffness the device rendered, from its own taps' force and depth
            name = f"interval{k}_t{int(r['trial']):03d}_a{int(r['attempt']):02d}.npz"
            trace = dict(np.load(folder / "traces" / name))
            rendered = float(r[f"sample_{k}"].split("=")[1])
            k_taps = tap_stiffness_N_m(trace, info.force_per_amp_N_A)
            assert len(k_taps) == int(r[f"n_taps_{k}"]) >= 1
            np.testing.assert_allclose(k_taps, rendered, rtol=0.01)
            # the percept is that stiffness with Weber noise: within 5 SDs of it
            assert abs(math.log(float(r[f"sim_percept_{k}"]) / rendered)) < 5 * 0.163
        # without lapses the answer is the interval whose percept was larger
        percepts = [float(r["sim_percept_1"]), float(r["sim_percept_2"])]
        assert r["response"] == str(1 + int(percepts[1] > percepts[0]))
    # blind: the subject view never names a sample or a stiffness
    assert shown and not any(s in m for m in shown for s in ("firm", "700", "500", "950", "N/m"))
    assert any(m.startswith("Which surface was harder?") for m in shown)


def test_detection_session_writes_log10_intensities(tmp_path):
    assert run(tmp_path, "T1", DETECTION) == 0
    rows = read_rows(tmp_path / "DATA" / "T1")
    assert len(rows) == 4
    for r in rows:
        assert float(r["intensity"]) == pytest.approx(math.log10(float(r["intensity_physical"])))
        target = r[f"sample_{r['target_interval']}"]
        other = r[f"sample_{3 - int(r['target_interval'])}"]
        assert target == f"pulse_firm@amplitude_Ns_m={float(r['intensity_physical']):g}"
        assert other == "pulse_firm@amplitude_Ns_m=none"
    exp = read_session(tmp_path / "DATA" / "T1")["experiment"]
    assert exp["guess_rate"] == 0.5 and exp["intensity_unit"] == "N*s/m" and exp["intensity_scale"] == "log10"
    # the full-amplitude pulse adds far more than one vibration JND: the click is found every time
    assert [r["correct"] for r in rows if r["intensity_physical"] == "4.55"] == ["1", "1"]


def test_real_virtual_session_is_masked_with_spoken_cues(tmp_path):
    need("portaudio")
    need("espeak-ng")
    raw = tmp_path / "played.raw"
    conf = write(tmp_path / "asound.conf", f'</usr/share/alsa/alsa.conf>\npcm.!default {{ type file slave.pcm '
                                           f'"null" file "{raw}" format "raw" }}\n')
    proto = write(tmp_path / "rv.toml", REAL_VIRTUAL.format(n=1))
    out = subprocess.run([sys.executable, "-m", "study", "run", "--device", "sim", "--participant", "simulated",
                          "--subject", "M1", "--seed", "3", "--out", str(tmp_path / "DATA"), "--protocol",
                          str(proto), "--audio", "on", "--masking-level-dbfs", "-30", "--cue-level-db", "6",
                          "--quiet"], cwd=ROOT, env=dict(os.environ, ALSA_CONFIG_PATH=str(conf)),
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    session = read_session(tmp_path / "DATA" / "M1")
    assert session["audio"]["cue_spoken"] is True and session["audio"]["level_dbfs"] == -30.0
    assert session["experiment"]["kind"] == "real-virtual-2afc"
    x = np.fromfile(raw, dtype=np.float32).astype(np.float64)
    x = x[np.flatnonzero(x)[0]:]
    # masking noise at its level: the median 50 ms RMS (cues are short) is -30 dBFS within 1 dB
    n = int(0.05 * 44100)
    rms = np.sqrt(np.mean(x[:len(x) // n * n].reshape(-1, n) ** 2, axis=1))
    assert abs(20 * np.log10(np.median(rms)) + 30.0) < 1.0
    rho = find_cue(x, espeak_reference("Tap now."))
    peaks, _ = sps.find_peaks(rho, height=0.5, distance=int(0.7 * 44100))
    # 2 trials x 2 intervals ask for 4 "Tap now."; the null sink has no clock (see test_audio): at least one
    # clean one, never more than asked for
    assert rho.max() > 0.8 and 1 <= len(peaks) <= 4
    # the question's cue after each trial's second interval is "Stop. Which one?", not the rating prompt
    assert find_cue(x, espeak_reference("Stop. Which one?")).max() > 0.7
    assert find_cue(x, espeak_reference("Stop. Please rate.")).max() < 0.5


def test_sigkill_at_every_trial_then_resume_loses_nothing(tmp_path):
    harness = ForcedChoiceKillHarness(tmp_path, REAL_VIRTUAL.format(n=2))
    assert len(harness.reference) == 4
    where = [s.split(" ", 1)[1] for s in harness.steps]
    rows = [i + 1 for i, w in enumerate(where) if w.startswith("row written: trial")]
    traces = [i + 1 for i, w in enumerate(where) if w.startswith("trace written: interval2")]
    assert len(rows) == 4
    # after each row (the next trial not started), and mid-trial (the first interval's trace on disk, no row)
    picks = rows[:3] + [traces[1] - 1, traces[3]]
    results = [harness.case(step, i) for i, step in enumerate(picks)]
    assert [r.get("error") for r in results] == [None] * len(picks), results
    assert all(r["killed"] == -signal.SIGKILL for r in results)
    assert [r["rows_before"] for r in results] == [1, 2, 3, 1, 3]
    for r in results:
        folder = r["folder"]
        assert len(list((folder / "traces").glob("*.npz"))) == 2 * 4
        events = [json.loads(ln) for ln in (folder / "schedule.jsonl").read_text().splitlines()]
        assert [e["event"] for e in events].count("resume") == 1
        assert read_session(folder)["finished_at"] is not None


@pytest.mark.parametrize("name, kind, n_samples, n_trials", [
    ("psy_real_virtual.toml", "real-virtual-2afc", 5, 80),
    ("psy_discrimination.toml", "discrimination", 7, 140),
    ("psy_detection.toml", "detection", 8, 140),
    ("psy_detection_quest.toml", "detection", 1, 0),
    ("psy_discrimination_staircase.toml", "discrimination", 1, 0),
])
def test_the_examples_load_and_plan(name, kind, n_samples, n_trials):
    protocol, exp = load_protocol_file(ROOT / "examples" / name)
    assert exp.kind == kind and protocol.familiarization_sample == "" and protocol.tap_window_s == 3.0
    assert len(stimulus_catalog(load_catalog(None), exp)) == n_samples
    if exp.adaptive and exp.method == "quest+":   # the first trial, at QUEST+'s most informative intensity
        assert 0.1 <= exp.handler(1).next_trial().intensity <= 10.0
    elif exp.adaptive:   # the stiffness JND: one track settling above the reference, one below, in N/m
        methods = exp.handler(1).methods
        assert exp.method == "updown" and exp.vary == "stiffness_N_m" and exp.intensity_scale == "log10"
        assert methods["A"].target_probability() == pytest.approx(2 ** -0.5)
        assert methods["B"].target_probability() == pytest.approx(1 - 2 ** -0.5)
        assert methods["A"].intensities == [] and methods["A"].next_intensity() == 950.0 > exp.reference
        assert methods["B"].next_intensity() == 480.0 < exp.reference
    else:
        assert len(plan_trials(exp, 1, "S01")) == n_trials


def test_adaptive_session_killed_at_any_trial_resumes_the_staircases_exactly(tmp_path):
    harness = ForcedChoiceKillHarness(tmp_path, ADAPTIVE_DETECTION.format(n=3))
    ref = read_rows(tmp_path / "ref" / "K")
    states = harness.reference_states
    # two staircases of 3 trials each, catch trials between them: every trial's row and state line
    assert sum(r["is_catch"] == "0" for r in ref) == 6 and len(states) == len(ref)
    assert {r["staircase"] for r in ref} == {"A", "B"}
    first = {lb: next(float(r["intensity_physical"]) for r in ref if r["staircase"] == lb and r["is_catch"] == "0")
             for lb in "AB"}
    assert first == {"A": 4.0, "B": 0.5}                     # the first intensity is recorded
    for r, st in zip(ref, states):
        assert (st["trial"], st["staircase"], int(st["is_catch"])) == (int(r["trial"]), r["staircase"],
                                                                       int(r["is_catch"]))
        if r["is_catch"] == "1":                              # a catch trial: no click in either interval
            # a blank has no log10 intensity: the cell is empty (a 0 would read as 1 N*s/m)
            assert r["intensity"] == "" and float(r["intensity_physical"]) == 0.0
            assert r["sample_1"] == r["sample_2"] == "pulse_firm@amplitude_Ns_m=none"
        else:
            assert st["state"]["history"][-1] == [float(r["intensity_physical"]), r["correct"] == "1"]
            assert float(r["intensity"]) == pytest.approx(math.log10(float(r["intensity_physical"])))
    where = [s.split(" ", 1)[1] for s in harness.steps]
    rows = [i + 1 for i, w in enumerate(where) if w.startswith("row written")]
    # killed after a row but before its state line, after a state line, and mid-trial
    picks = [rows[1], rows[2] + 1, rows[3] - 1]
    results = [harness.case(step, i) for i, step in enumerate(picks)]
    assert [r.get("error") for r in results] == [None] * 3, results
    assert [r["rows_before"] for r in results] == [2, 3, 3]


def _http(method: str, url: str, body=None, headers=None):
    req = urllib.request.Request(url, method=method, headers=headers or {},
                                 data=None if body is None else json.dumps(body).encode())
    with urllib.request.urlopen(req, timeout=10) as r:
        return json.loads(r.read())


def test_a_person_answers_through_the_subject_view_and_the_operator_places_every_interval(tmp_path):
    proto = write(tmp_path / "p.toml", DISCRIMINATION.replace("levels = [500.0, 700.0, 950.0]",
                                                              "levels = [500.0, 950.0]")
                  .replace("trials_per_level = 2", "trials_per_level = 1"))
    cmd = [sys.executable, "-m", "study", "run", "--device", "sim", "--participant", "keyboard", "--subject", "P1",
           "--seed", "4", "--out", str(tmp_path / "DATA"), "--protocol", str(proto), "--age", "30", "--gender",
           "female", "--handedness", "left", "--experience", "none", "--token", "tok"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    hdr = {"X-Study-Token": "tok", "Content-Type": "application/json"}
    keys, sent, places, messages, hints = iter("3x21"), [], [], set(), []
    try:
        port = None
        while port is None:
            line = proc.stdout.readline()
            assert line, proc.stderr.read()
            port = (m := re.match(r"operator view:\s+http://127.0.0.1:(\d+)/", line)) and int(m.group(1))
        api = f"http://127.0.0.1:{port}"
        while proc.poll() is None:
            try:
                op = _http("GET", api + "/api/operator", headers=hdr)
                subj = _http("GET", api + "/api/subject")
                messages.add(subj["message"])
                if op["awaiting_confirm"]:
                    places.append(op["place"])
                    _http("POST", api + "/api/operator/confirm", {}, hdr)
                elif subj["prompt"] == "choice":
                    key = next(keys)
                    answer = _http("POST", api + "/api/key", {"key": key, "trial_id": subj["trial_id"]},
                                   {"Content-Type": "application/json"})
                    sent.append((key, answer["accepted"]))
                    hints.append(answer["hint"])
                time.sleep(0.02)   # polling, as the views do (the session waits for us, not for time)
            except (urllib.error.URLError, ConnectionError, HTTPException):  # the session ended:
                # its server is gone, or the process exited while a response was being sent
                break   # the session ended and stopped its server
        assert proc.wait(timeout=60) == 0, proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
    assert sent == [("3", False), ("x", True), ("2", True), ("1", True)]
    assert hints[0] == "Please press 1 for the first interval or 2 for the second, or x to reject this trial."
    folder = tmp_path / "DATA" / "P1"
    rows = read_rows(folder)
    assert [(r["trial"], r["attempt"], r["response"]) for r in rows] == [("1", "2", "2"), ("2", "1", "1")]
    assert all(int(r["correct"]) == int(r["response"] == r["target_interval"]) for r in rows)
    events = [json.loads(ln) for ln in (folder / "schedule.jsonl").read_text().splitlines()]
    assert [(e["trial"], e["attempt"], e["reason"]) for e in events if e["event"] == "invalid_attempt"] == \
        [(1, 1, "rejected")]
    # the operator placed an item for every interval (3 attempts x 2), alternating placeholders
    assert places == ["placeholder A", "placeholder B"] * 3
    assert "Which surface was harder?\nPress 1 for the first interval, 2 for the second, or x to reject the " \
           "trial." in messages
    assert not any(s in m for m in messages for s in ("firm", "700", "500", "950"))


def test_adaptive_discrimination_in_the_servo_process(tmp_path):
    """On hardware the device and servo loops run in their own process: a staircase's new stimuli are made
    there (``IsolatedApparatus.add_sample``) as it asks for them."""
    protocol = QUICK + """
[experiment]
kind = "discrimination"
sample = "firm"
reference = 700.0
method = "updown"

[experiment.staircases.S]
start = 1000.0
step_down = [0.1]
n_down = 1
max_trials = 4
"""
    assert run(tmp_path, "I1", protocol, "--servo-process", "on") == 0
    folder = tmp_path / "DATA" / "I1"
    rows = read_rows(folder)
    states = [json.loads(ln) for ln in (folder / "staircase_state.jsonl").read_text().splitlines()]
    assert len(rows) == len(states) == 4 and read_session(folder)["device"]["servo_process"] is True
    # 1-up-1-down in 0.1 log10 steps from 1000 N/m: each next stiffness follows the previous answer
    x = [float(r["intensity_physical"]) for r in rows]
    assert x[0] == 1000.0
    for a, b, r in zip(x, x[1:], rows):
        assert b == pytest.approx(a * 10 ** (-0.1 if r["correct"] == "1" else 0.1))
    for r in rows:   # the comparison the staircase asked for was rendered (the sim's force over penetration)
        k = 1 + (r["sample_2"] != "firm@stiffness_N_m=700")
        trace = dict(np.load(folder / "traces" / f"interval{k}_t{int(r['trial']):03d}_a{int(r['attempt']):02d}.npz"))
        np.testing.assert_allclose(tap_stiffness_N_m(trace, SimDevice().info.force_per_amp_N_A),
                                   float(r["intensity_physical"]), rtol=0.01)


def test_a_torn_state_line_is_kept_aside_and_written_again(tmp_path, capsys):
    """The kill's torn last state line goes to staircase_state.jsonl.torn; the replay writes it again."""
    harness = ForcedChoiceKillHarness(tmp_path, ADAPTIVE_DETECTION.format(n=2))
    where = [s.split(" ", 1)[1] for s in harness.steps]
    third = where.index("staircase state written: trial 3") + 1
    # a session killed just after trial 3's state line, which is then torn by hand (a kill mid-write)
    out = tmp_path / "torn"
    assert forked(session_args(harness.protocol, out, "K", harness.seed), {"STUDY_CRASH_AT": str(third)}) \
        == -signal.SIGKILL
    states = out / "K" / "staircase_state.jsonl"
    data = states.read_bytes()
    whole = data[:data[:-1].rfind(b"\n") + 1]
    states.write_bytes(whole + data[len(whole):len(whole) + 40])      # the third line, torn after 40 bytes
    assert forked(session_args(harness.protocol, out, "K", harness.seed, resume=True), {}) == 0
    assert (out / "K" / "staircase_state.jsonl.torn").read_bytes() == data[len(whole):len(whole) + 40] + b"\n"
    lines = [json.loads(ln) for ln in states.read_text().splitlines()]
    assert lines == harness.reference_states


def test_summary_lines_print_an_intensity_only_where_one_is_varied(capsys):
    """Real vs virtual varies no intensity: its lines name the rendering, its trials and proportion correct."""
    from types import SimpleNamespace
    from study.forcedchoice.kind import ForcedChoice
    rows = [{"condition": "firm", "intensity_physical": 1.0, "correct": k % 4 != 0} for k in range(20)]
    store = SimpleNamespace(subject="S01", dir="DATA/S01")
    lines = []
    for kind, unit in (("real-virtual-2afc", "1"), ("discrimination", "N/m")):
        fake = SimpleNamespace(exp=SimpleNamespace(kind=kind, unit=unit), handler=None)
        ForcedChoice.summary(fake, rows, store, lines.append)
    assert lines[0].split() == ["firm", "trials", "20", "correct", "0.75"]
    assert lines[1].split() == ["firm", "1", "N/m", "trials", "20", "comparison", "harder", "0.75"]
