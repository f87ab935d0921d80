"""Study runner benchmark: a full simulated session (target: < 30 s wall on this machine).

Default protocol: familiarization on wood, 12 demonstration and 36 testing
attempts plus redraws, 5 s of tapping from the first impact each, on the
nonlinear sim device at 10 kHz with the simulated participant and synthetic
rater, all data written and fsynced. Prints wall and CPU time (the machine is
shared: CPU time shows the work, wall time what a user waits), simulated time
and attempts.
"""

from __future__ import annotations

import contextlib
import csv
import io
import statistics
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np

from devices.sim import SimDevice
from stimuli import load_catalog
from study.__main__ import main as study_main
from study.session.apparatus import Apparatus
from study.session.audio import MaskingAudio
from study.session.config import ProtocolConfig
from study.session.isolated import IsolatedApparatus
from study.session.participants import SimulatedParticipant
from study.session.uistate import UiState
from study.session.webui import WebUI


def one_session(seed: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        wall0, cpu0 = time.perf_counter(), time.process_time()
        with contextlib.redirect_stdout(io.StringIO()):
            code = study_main(["run", "--device", "sim", "--participant", "simulated", "--subject", f"B{seed}",
                         "--seed", str(seed), "--out", tmp, "--quiet"])
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        if code != 0:
            raise RuntimeError(f"session failed with exit code {code}")
        with open(Path(tmp) / f"B{seed}" / "trials.csv", newline="") as fh:
            rows = list(csv.DictReader(fh))
        sim_s = sum(float(r["duration_s"]) for r in rows)
        size = sum(p.stat().st_size for p in (Path(tmp) / f"B{seed}").rglob("*") if p.is_file())
    phases = {p: sum(r["phase"] == p for r in rows) for p in ("familiarization", "demonstration", "testing")}
    return {"wall_s": wall, "cpu_s": cpu, "sim_s": sim_s, "attempts": len(rows), "phases": phases,
            "data_MB": size / 1e6}


def main() -> None:
    one_session(0)  # warm-up: numba compilation and imports, not part of a session's cost
    runs = [one_session(seed) for seed in (1, 2, 3)]
    for r in runs:
        print(f"   session: {r['attempts']} attempts {r['phases']}, {r['sim_s']:.0f} s device time, "
              f"wall {r['wall_s']:.1f} s, cpu {r['cpu_s']:.1f} s, data {r['data_MB']:.0f} MB")
    wall = statistics.median(r["wall_s"] for r in runs)
    cpu = statistics.median(r["cpu_s"] for r in runs)
    sim = statistics.median(r["sim_s"] for r in runs)
    print(f"   full simulated session: median wall {wall:.1f} s (target < 30 s), median cpu {cpu:.1f} s, "
          f"device time / wall = {sim / wall:.1f}x real time")
    timing_main()


def servo_timing(isolated: bool, load: bool, window_s: float = 2.0) -> dict:
    """Period statistics of a wall-clock-paced tapping window while the views and the audio callback run.

    This machine has no clocked sound device, so the PortAudio callback is
    driven by a thread at its real cadence (1024 frames at 44.1 kHz); the
    views are polled by an HTTP client at 10 Hz per page, like the browsers do.
    """
    catalog = [s for s in load_catalog() if s.name == "pulse_firm"]
    protocol = ProtocolConfig()
    sp = SimulatedParticipant("T", "few", 1)
    plan = sp.plan("testing", 1, 1, window_s)
    stop = threading.Event()
    threads = []
    web = None
    if load:
        ui = UiState()
        web = WebUI(ui, token="t").start()
        audio = MaskingAudio(fs_hz=44100.0, seed=1)
        out = np.zeros((1024, 1), np.float32)

        def audio_cadence():
            period = 1024 / 44100.0
            nxt = time.perf_counter()
            while not stop.is_set():
                audio._callback(out, 1024, None, None)
                nxt += period
                time.sleep(max(0.0, nxt - time.perf_counter()))

        def poll():
            while not stop.is_set():
                for path in ("/api/subject", "/api/operator?token=t", "/"):
                    urllib.request.urlopen(f"http://127.0.0.1:{web.port}{path}").read()
                time.sleep(0.1)

        threads = [threading.Thread(target=f, daemon=True) for f in (audio_cadence, poll)]
        for t in threads:
            t.start()
    try:
        if isolated:
            app = IsolatedApparatus("sim", {"seed": 1}, catalog, protocol, None, sp, realtime=True)
        else:
            app = Apparatus(SimDevice(seed=1).open(), catalog, protocol, sim_participant=sp, realtime=True)
        app.set_sample("pulse_firm")
        app.start_hand(plan, window_s)
        tap = app.tap_window(window_s, 5.0)
        if isolated:
            app.close()
    finally:
        stop.set()
        for t in threads:
            t.join()
        if web is not None:
            web.stop()
    return tap.timing


def timing_main(repeats: int = 3) -> None:
    """Interleaved repeats of each case (the machine is shared), medians of the per-window statistics."""
    cases = ((False, False, "in-process, nothing else running"),
             (False, True, "in-process, views + audio callback"),
             (True, True, "servo process, views + audio callback"))
    stats = {label: [] for _, _, label in cases}
    for _ in range(repeats):
        for isolated, load, label in cases:
            stats[label].append(servo_timing(isolated, load))
    for _, _, label in cases:
        med = {k: statistics.median(t[k] for t in stats[label])
               for k in ("period_p50_us", "period_p99_us", "period_max_us", "overruns")}
        print(f"   10 kHz paced 2 s window, {label:38s}: median of {repeats}: period p50 {med['period_p50_us']:.0f} us, "
              f"p99 {med['period_p99_us']:.0f} us, max {med['period_max_us']:.0f} us, overruns {med['overruns']:.0f}")

if __name__ == "__main__":
    main()
