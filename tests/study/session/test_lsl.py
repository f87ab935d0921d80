"""``study run --lsl``: the device's state, the session's events and every contact as Lab Streaming Layer streams,
received by an inlet on the loopback interface (known peers, no multicast), in order with monotone time stamps,
matching the trace files through the recorded clock offsets; and one warning line when LSL is unavailable."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

import plumbing.lsl as lsl
from study.__main__ import main

from tests.support.kills import QUICK
from tests.support.lsl import Recorder, loopback_config
from tests.support.study import read_rows, read_session, write

MAGNITUDE = QUICK + """
[experiment]
kind = "magnitude"
samples = ["firm"]
levels = [300.0, 600.0, 1200.0]
repetitions = 1
modulus = 600.0
"""


@pytest.fixture(scope="module")
def loopback(tmp_path_factory):
    return loopback_config(tmp_path_factory.mktemp("lsl"))


@pytest.mark.parametrize("servo_process", ["on", "off"])   # the servo process first: see tests/conftest.py
def test_streams_carry_state_events_and_contacts_in_order(tmp_path, loopback, servo_process):
    subject = f"L{servo_process}{os.getpid()}"   # LSL streams are seen machine-wide: another suite's are not ours
    ids = [f"hfam-study-{subject}-{k}" for k in ("state", "markers", "contacts")]
    rec = Recorder(ids)
    rec.start()
    proto = write(tmp_path / "m.toml", MAGNITUDE)
    part = write(tmp_path / "p.toml", "p_reject = 0\np_overpower = 0\n")
    assert main(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject", subject, "--seed", "4",
                 "--out", str(tmp_path / "DATA"), "--protocol", str(proto), "--participant-config", str(part),
                 "--lsl", "--lsl-rate-hz", "1000", "--lsl-wait-s", "30", "--servo-process", servo_process]) == 0
    rec.stop()
    assert rec.error is None and rec.connected.is_set(), rec.error
    folder = tmp_path / "DATA" / subject
    rows, session = read_rows(folder), read_session(folder)
    record = session["lsl"][0]
    assert record["dropped_chunks"] == 0 and {s["source_id"] for s in record["streams"]} == set(ids)
    # the markers: every attempt's events in order, time stamps monotone
    values, stamps = rec.stream(ids[1])
    events = [json.loads(v[0]) for v in values]
    assert np.all(np.diff(stamps) >= 0) and len(events) == record["markers"], " ".join(e["event"] for e in events)
    kinds = [e["event"] for e in events]
    per_attempt = ["attempt_start", "tap_cue", "tap_cue", "question", "answer", "recorded"]
    assert kinds[:6] == per_attempt                                   # the first trial shows the modulus first
    assert kinds.count("attempt_start") == len(rows) and kinds.count("answer") == len(rows)
    answers = [e["answer"] for e in events if e["event"] == "answer"]
    assert [float(a) for a in answers] == [float(r["number"]) for r in rows]
    # the state: 1 kHz samples of every window, monotone, and the traces' positions at the same device times
    state, ts = rec.stream(ids[0])
    state = np.asarray(state)
    assert state.shape[1] == 6 and np.all(np.diff(ts) > 0) and len(ts) == record["samples"]
    pairs = np.asarray(record["clock_offsets"])
    traces = sorted((folder / "traces").glob("*.npz"))
    assert len(pairs) == len(traces)                                  # one clock pair per window
    offset = pairs[-1, 1] - pairs[-1, 0]
    trace = dict(np.load(max(traces, key=lambda p: p.stat().st_mtime)))
    t_dev = ts - offset
    sel = (t_dev >= trace["t_s"][0]) & (t_dev <= trace["t_s"][-1])
    assert sel.sum() > 100
    np.testing.assert_allclose(state[sel, 0], np.interp(t_dev[sel], trace["t_s"], trace["position_m"]), atol=2e-6)
    # the contacts: one per tap of every window, with the traces' incoming velocities
    contacts, cts = rec.stream(ids[2])
    got = [json.loads(v[0]) for v in contacts]
    assert np.all(np.diff(cts) >= 0)
    want = np.concatenate([np.load(p)["event_incoming_velocity_m_s"] for p in traces])
    assert sorted(c["incoming_velocity_m_s"] for c in got) == pytest.approx(sorted(want.tolist()))
    # the inlet's clock correction on one computer: the same clock
    assert all(abs(v) < 0.01 for v in rec.offsets.values()), rec.offsets


def test_without_lsl_the_session_runs_and_says_so_once(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(lsl, "pylsl", None)
    monkeypatch.setattr(lsl, "LSL_MISSING", "ModuleNotFoundError: No module named 'pylsl'")
    proto = write(tmp_path / "m.toml", MAGNITUDE)
    assert main(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject", "N1", "--seed", "4",
                 "--out", str(tmp_path / "DATA"), "--protocol", str(proto), "--lsl"]) == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines == ["warning: --lsl: the session runs without Lab Streaming Layer streams: pylsl is not installed "
                     "or its liblsl cannot load (ModuleNotFoundError: No module named 'pylsl'); install the lsl extra"]
    session = read_session(tmp_path / "DATA" / "N1")
    assert session["finished_at"] and "lsl" not in session and len(read_rows(tmp_path / "DATA" / "N1")) == 3
