"""A short `study run` over the emulated serial port, streaming and on-device (issue 8).

Hardware sessions need a person (`--participant keyboard`); here a thread plays operator and
subject through the study's own HTTP API (confirm each placement, press a rating key), while the
emulator's simulated hand taps. The session must complete and write its trials.
"""

import csv
import http.client
import json
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest

from devices.firmware.emulator import start_emulator

ROOT = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _play_operator_and_subject(base: str, stop: threading.Event, seen: dict) -> None:
    def post(path, body):
        req = urllib.request.Request(base + path, data=json.dumps(body).encode(), method="POST",
                                     headers={"Content-Type": "application/json"})
        urllib.request.urlopen(req, timeout=2).read()

    while not stop.is_set():
        try:
            op = json.load(urllib.request.urlopen(base + "/api/operator?token=tok", timeout=2))
            if op.get("awaiting_confirm"):
                post("/api/operator/confirm?token=tok", {})
                seen["confirms"] += 1
            sub = json.load(urllib.request.urlopen(base + "/api/subject", timeout=2))
            if sub.get("prompt") == "rate":
                post("/api/key", {"key": "5", "trial_id": sub["trial_id"]})
                seen["ratings"] += 1
        except (OSError, http.client.HTTPException):  # server not up yet, or gone at the end (mid-reply:
            pass                                        # IncompleteRead when the study process exits)
        time.sleep(0.03)


@pytest.mark.parametrize("mode, faults", [("streaming", None), ("on-device", None),
                                          # issue 38: a CRC-valid STATE one byte too long, every 200th frame
                                          # (before: a traceback and exit 1 at the first one)
                                          ("streaming", "bad_length_every=200")])
def test_short_study_run_over_the_emulated_serial_port(mode, faults, tmp_path):
    port, handle = start_emulator(mode, faults, process=True)
    web_port = _free_port()
    proto = tmp_path / "protocol.toml"
    # servo_watchdog_s: this shared machine stalls the servo process for tens of ms at times (load 10 on 2 cores
    # was seen), which the host's 20 ms watchdog rightly stops, three times in a row; the test is about the link
    proto.write_text('familiarization_sample = ""\ntap_window_s = 1.5\nfirst_tap_timeout_s = 3.0\n'
                     "homing_after_s = 0.2\nservo_watchdog_s = 0.5\n")
    # loaded machine: a reply later than 20 ms (not the 5 ms default) counts as lost
    spec = f"serial:{port}" + ("?mode=on-device" if mode == "on-device" else "?loss_timeout_s=0.02")
    cmd = [sys.executable, "-m", "study", "run", "--device", spec, "--participant", "keyboard", "--subject", "HW1",
           "--age", "30", "--gender", "female", "--handedness", "right", "--experience", "few", "--audio", "off",
           "--accept-timing", "--port", str(web_port), "--token", "tok", "--samples", "pulse_firm", "--repetitions", "1",
           "--protocol", str(proto), "--seed", "1", "--out", str(tmp_path / "data"), "--quiet"]
    stop = threading.Event()
    seen = {"confirms": 0, "ratings": 0}
    driver = threading.Thread(target=_play_operator_and_subject, args=(f"http://127.0.0.1:{web_port}", stop, seen),
                              daemon=True)
    driver.start()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=180, cwd=ROOT)
        for _ in range(2):
            # the host servo loop's own 20 ms overrun watchdog can fire when this shared machine stalls
            # the servo process (streaming mode); the study then stops with the data so far, and a
            # hardware session continues with --resume, as an operator would do
            if r.returncode == 0 or "continue with --resume" not in r.stderr:
                break
            resume = cmd + ["--resume"]  # same seed: the session's own
            r = subprocess.run(resume, capture_output=True, text=True, timeout=180, cwd=ROOT)
    finally:
        stop.set()
        handle.stop()
    assert r.returncode == 0, r.stdout + r.stderr
    session = json.loads((tmp_path / "data" / "HW1" / "session.json").read_text())
    assert session["device"]["spec"] == spec and session["finished_at"]
    assert session["device"]["info"]["name"] == "hfam-emulator(sim-joystick)"
    with open(tmp_path / "data" / "HW1" / "trials.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert {row["phase"] for row in rows} >= {"testing"}
    testing = [row for row in rows if row["phase"] == "testing"]
    assert testing[-1]["valid"] == "true" and testing[-1]["rating"] == "5"
    v = [float(x) for x in testing[-1]["incoming_velocities_m_s"].split(";")]
    # the emulated hand's taps (0.05, 0.1, 0.2 m/s, pushed about by the study's homing) over the serial link
    assert all(0.0 < x < 0.3 for x in v) and any(0.03 < x for x in v)
    assert seen["ratings"] >= len(testing)


#: a timing check before the session that only this machine's load could fail is not what these tests are about:
#: short, with thresholds no stall of a loaded machine reaches (issue 40's check is tested in
#: tests/integration/test_study_timing_check.py)
LOOSE_TIMING_CHECK = ("timing_check_s = 0.2\ntiming_p99_us = 1e5\ntiming_p999_us = 1e5\ntiming_max_period_ms = 900\n"
                      "timing_link_rtt_p99_ms = 900\ntiming_link_gap_ms = 900\n")


def _fault_session(faults, tmp_path, protocol_text, loss_timeout_s=0.02):
    port, handle = start_emulator("streaming", faults, process=True)
    proto = tmp_path / "protocol.toml"
    proto.write_text(protocol_text)
    cmd = [sys.executable, "-m", "study", "run", "--device", f"serial:{port}?loss_timeout_s={loss_timeout_s}",
           "--participant", "keyboard", "--subject", "HW2", "--age", "30", "--gender", "female", "--handedness", "right",
           "--experience", "few", "--audio", "off", "--token", "tok", "--samples", "pulse_firm", "--repetitions", "1",
           "--protocol", str(proto), "--seed", "1", "--out", str(tmp_path / "data"), "--quiet"]
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=180, cwd=ROOT)
    finally:
        handle.stop()


def test_a_device_clock_fault_in_the_timing_check_refuses_the_session(tmp_path):
    """Issue 40 with issue 38: the timing check before a hardware session meets a frozen device clock and the
    session is refused before anything is written (exit 2, one line)."""
    r = _fault_session("clock_freeze_at=50", tmp_path, 'familiarization_sample = ""\nservo_watchdog_s = 1.0\n')
    assert r.returncode == 2 and "servo timing check failed" in r.stderr and "device fault: its clock" in r.stderr, \
        r.stdout + r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "data" / "HW2").exists()


@pytest.mark.parametrize("faults", ["clock_freeze_at=2000", "clock_back_at=2000"])
def test_a_device_fault_ends_the_study_with_exit_4_and_one_line(faults, tmp_path):
    """Issue 38: a device clock that freezes or runs backwards stops the session as a device fault (exit 4,
    output zero, one error line). The servo process meets it while it keeps homing between the runner's
    requests or inside one; before, a stop between requests ended the runner with exit 1 and no message (its
    next request found the servo process gone: BrokenPipeError). The fault comes after the (short) timing check."""
    # a loaded machine can stall the servo process for tens of ms: widen the host's own watchdog, so the
    # device fault (not the scheduler) is what stops the session; and the emulator's process too: 10 replies in a
    # row later than 20 ms ended homing as a lost device (two suites on 2 cores), so a reply may take 100 ms
    r = _fault_session(faults, tmp_path, 'familiarization_sample = ""\nservo_watchdog_s = 1.0\n' + LOOSE_TIMING_CHECK,
                       loss_timeout_s=0.1)
    assert r.returncode == 4, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and "device fault: its clock" in r.stderr, r.stderr
    assert "continue with --resume" in r.stderr
    session = json.loads((tmp_path / "data" / "HW2" / "session.json").read_text())
    assert session["finished_at"] is None
