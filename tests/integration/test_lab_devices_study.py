"""A rating session and a psychophysics session through `study run` on the 3-DOF devices' emulators, unchanged:
the study sees each device's vertical view as a 1-DOF device (docs/bringup.md).

Hardware sessions need a person (``--participant keyboard``): a thread plays operator and subject through the
study's HTTP API (confirm each placement; a rating key, or interval 1 of a forced choice) while the emulated
hand taps. Each device runs one kind of session (both kinds go through the same adapter layer); the views'
port is the one the study prints (``--port 0``)."""

import csv
import http.client
import json
import os
import re
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PROTOCOL = ('familiarization_sample = ""\ntap_window_s = 1.5\nfirst_tap_timeout_s = 3.0\nhoming_after_s = 0.2\n'
            "servo_watchdog_s = 0.5\n"
            # a timing check only this shared machine's load could fail is not what this test is about
            "timing_check_s = 0.2\ntiming_p99_us = 1e5\ntiming_p999_us = 1e5\ntiming_max_period_ms = 900\n"
            "timing_link_rtt_p99_ms = 900\ntiming_link_gap_ms = 900\n")
DISCRIMINATION = ('\n[experiment]\nkind = "discrimination"\nsample = "firm"\nreference = 700.0\n'
                  "levels = [500.0, 950.0]\ntrials_per_level = 1\n")


def _play(base: str, stop: threading.Event, seen: dict) -> None:
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
            if sub.get("prompt") in ("rate", "choice"):
                post("/api/key", {"key": "5" if sub["prompt"] == "rate" else "1", "trial_id": sub["trial_id"]})
                seen[sub["prompt"]] += 1
        except (OSError, http.client.HTTPException):
            pass
        time.sleep(0.03)


@pytest.mark.parametrize("spec, kind", [("inverse3:emulator", "rating"), ("falcon:emulator", "psychophysics"),
                                        ("woodenhaptics:emulator", "rating"), ("dhd:emulator", "psychophysics"),
                                        ("touch:Default Device", "rating")])
def test_a_study_session_runs_unchanged_on_the_emulated_device(spec, kind, tmp_path, request):
    env = dict(os.environ)
    if spec.startswith("touch"):
        env["HFAM_OPENHAPTICS_LIB"] = str(request.getfixturevalue("fake_hd"))
    proto = tmp_path / "protocol.toml"
    proto.write_text(PROTOCOL + (DISCRIMINATION if kind == "psychophysics" else ""))
    spec = spec + "?loss_timeout_s=0.02"
    cmd = [sys.executable, "-m", "study", "run", "--device", spec, "--participant", "keyboard", "--subject", "L1",
           "--age", "30", "--gender", "female", "--handedness", "right", "--experience", "few", "--audio", "off",
           "--accept-timing", "--port", "0", "--token", "tok", "--protocol", str(proto), "--seed", "1",
           "--out", str(tmp_path / "data"), "--quiet"]
    if kind == "rating":
        cmd += ["--samples", "pulse_firm", "--repetitions", "1"]
    stop = threading.Event()
    seen = {"confirms": 0, "rate": 0, "choice": 0}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env)
    try:
        for line in proc.stdout:
            m = re.search(r"operator view:\s+(http://[^/\s]+)/", line)
            if m:
                threading.Thread(target=_play, args=(m.group(1), stop, seen), daemon=True).start()
        proc.wait(timeout=240)
    finally:
        stop.set()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = proc.stderr.read()
    assert proc.returncode == 0, err
    session = json.loads((tmp_path / "data" / "L1" / "session.json").read_text())
    assert session["finished_at"] and session["device"]["spec"] == spec
    assert session["device"]["info"]["name"].endswith("(vertical axis)")
    with open(tmp_path / "data" / "L1" / "trials.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert rows and seen["confirms"] >= 2
    if kind == "rating":
        testing = [r for r in rows if r["phase"] == "testing"]
        assert testing[-1]["valid"] == "true" and testing[-1]["rating"] == "5" and seen["rate"] >= 1
    else:
        assert seen["choice"] >= 2 and {r["response"] for r in rows} >= {"1"}
