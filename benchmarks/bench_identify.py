"""Identification speed: ETFE + automatic fit for a 2 s sweep at 10 kHz with 4 trials (target < 2 s),
and the time to record one such trial on the simulated device."""

from __future__ import annotations

import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from devices.identify.etfe import etfe
from devices.identify.fit import FitOptions, fit_etfes
from devices.identify.record import record_trial
from devices.identify.sweep import SweepConfig
from devices.identify.synthetic import synthetic_recording
from devices.sim import SimDevice


def _synthetic_trials():
    dev = SimDevice.from_spec("lti")
    model = dev.linear_model(2.0, "accel_m_s2")
    pos = dev.linear_model(2.0, "position_m")
    pos = type(pos)(pos.zeros_rad_s, np.where(pos.poles_rad_s == 0, -1.0, pos.poles_rad_s), pos.gain, pos.delay_s,
                    output="position_m")
    sweep = SweepConfig(amplitude_A=0.75, f_start_hz=5.0, f_end_hz=1000.0, duration_s=2.0, fs_hz=10_000.0)
    return [synthetic_recording(model, pos, sweep, polarity=(-1) ** k, accel_noise_m_s2=0.02,
                                accel_lsb_m_s2=0.015, position_lsb_m=dev.info.position_resolution_m, seed=k)
            for k in range(4)]


def main() -> None:
    recs = _synthetic_trials()
    fit_etfes([etfe(recs)], FitOptions())  # warm-up (imports, caches)
    times, etfe_times, orders = [], [], []
    for _ in range(5):
        t0 = time.perf_counter()
        curve = etfe(recs, "accel_m_s2")
        t1 = time.perf_counter()
        res = fit_etfes([curve], FitOptions())
        t2 = time.perf_counter()
        etfe_times.append(t1 - t0)
        times.append(t2 - t0)
        orders.append(res.model.order)
    med = statistics.median(times)
    print(f"   ETFE (4 trials x 2 s at 10 kHz): median {statistics.median(etfe_times) * 1e3:.1f} ms")
    print(f"   ETFE + automatic fit (accel):     median {med:.3f} s  (target < 2 s, ratio {med / 2.0:.2f}); "
          f"order {orders[0]}, RMS {res.metrics['rms_db']:.2f} dB / {res.metrics['rms_phase_deg']:.1f} deg")

    dev = SimDevice.from_spec("lti")
    with dev:
        sweep = SweepConfig(duration_s=2.0, fs_hz=dev.info.servo_rate_hz)
        rec_times = []
        for k in range(3):
            t0 = time.perf_counter()
            record_trial(dev, sweep, grip_N=2.0, trial=k)
            rec_times.append(time.perf_counter() - t0)
    n_ticks = sweep.repetitions * sweep.n_samples
    mt = statistics.median(rec_times)
    print(f"   record one trial on sim:lti ({n_ticks} ticks): median {mt:.3f} s "
          f"({mt / n_ticks * 1e6:.2f} us/tick, {n_ticks / sweep.fs_hz / mt:.0f}x real time)")


    whole_process_grips()


def whole_process_grips(runs: int = 3) -> None:
    """``python -m devices identify`` with the default six grips, whole process (target < 5 s):
    grips in parallel processes (``--workers`` = cores) against one process. Also the CPU time of all its
    processes (user + system): on a machine shared with other work the wall time follows the cores left."""
    for workers in (os.cpu_count() or 1, 1):
        times, cpus = [], []
        for _ in range(runs):
            with tempfile.TemporaryDirectory() as tmp:
                r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
                t0 = time.perf_counter()
                subprocess.run([sys.executable, "-m", "devices", "identify", "--out", f"{tmp}/m", "--workers",
                                str(workers)], check=True, capture_output=True)
                times.append(time.perf_counter() - t0)
                r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
                cpus.append(r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime)
        med = statistics.median(times)
        print(f"   identify, six grips, whole process, {workers} worker(s): median {med:.2f} s "
              f"(target < 5 s, ratio {med / 5:.2f}); min {min(times):.2f} s, CPU {statistics.median(cpus):.2f} s")


if __name__ == "__main__":
    main()
