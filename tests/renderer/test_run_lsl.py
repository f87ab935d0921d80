"""``renderer run --lsl``: the servo's state at the decimated rate, its contacts and the run's start and end,
received on the loopback interface (known peers, no multicast), monotone, equal to the run's own log; and a run
without ``--lsl`` never loads pylsl."""

from __future__ import annotations

import argparse
import ast
import csv
import json
import os
from pathlib import Path

import numpy as np

from renderer import cli_run
from renderer.__main__ import main
from renderer.cli_run_parser import register

from tests.support.lsl import Recorder, loopback_config


def test_a_run_streams_its_log_contacts_and_markers(tmp_path):
    loopback_config(tmp_path)
    name = f"RUN{os.getpid()}"   # the streams' source id; LSL streams are seen machine-wide: another suite's are not ours
    ids = [f"hfam-renderer-{name}-{k}" for k in ("state", "markers", "contacts")]
    rec = Recorder(ids)
    rec.start()
    # the outlets exist only while the run does: a 3 s wall-clock run gives the recorder time to connect
    assert main(["run", "--device", "sim", "--transient", "pulse", "--taps", "4", "--realtime", "--no-figure",
                 "--out", str(tmp_path / name), "--lsl", "--lsl-rate-hz", "500"]) == 0
    rec.stop()
    assert rec.error is None, rec.error
    run = json.loads((tmp_path / name / "run.json").read_text())
    log = np.load(tmp_path / name / "log.npz")
    state, ts = rec.stream(ids[0])
    state = np.asarray(state)
    assert run["lsl"]["samples"] == run["ticks"] // 20 + (run["ticks"] % 20 > 0) and run["lsl"]["dropped_chunks"] == 0
    assert np.all(np.diff(ts) > 0)
    # what arrived (from the moment the recorder connected) is the log every 20th tick, in order
    pos = log["position_m"][::20]
    k = int(np.argmin(np.abs(pos - state[0, 0]) + np.abs(log["velocity_m_s"][::20] - state[0, 1])))
    np.testing.assert_allclose(state[:, 0], pos[k:k + len(state)], rtol=0, atol=1e-12)
    markers = [json.loads(v[0])["event"] for v in rec.stream(ids[1])[0]]
    assert markers[-1] == "run_end"
    contacts = [json.loads(v[0]) for v in rec.stream(ids[2])[0]]
    with open(tmp_path / name / "events.csv", newline="") as fh:
        events = [float(r["incoming_velocity_m_s"]) for r in csv.DictReader(fh)]
    assert len(events) == 4 and contacts and [c["incoming_velocity_m_s"] for c in contacts] == events[-len(contacts):]


def test_only_lsl_chooses_the_body_that_loads_pylsl():
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    plain = parser.parse_args(["run", "--device", "sim", "--out", "R"])
    streamed = parser.parse_args(["run", "--device", "sim", "--out", "R", "--lsl"])
    assert (plain.func.module, plain.fast_exit, plain.lsl) == ("renderer.cli_run", True, False)
    assert (streamed.func.module, streamed.fast_exit, streamed.lsl) == ("renderer.cli_run_lsl", False, True)
    # the plain body imports nothing of LSL (its module's imports, read)
    tree = ast.parse(Path(cli_run.__file__).read_text())
    names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names} | {
        n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert not any("lsl" in (m or "") for m in names), names
