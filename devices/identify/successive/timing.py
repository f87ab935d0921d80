"""Stage 1 of successive isolation: servo-loop timing (thesis sec. 3.5.2, "Servo Loop Timing")."""

from __future__ import annotations

import time

import numpy as np

from .bench import Bench
from .common import ModelBuilder, StageError, StageResult

CONFIG = "assembled"


def identify_timing(bench: Bench, builder: ModelBuilder, duration_s: float = 0.2) -> StageResult:
    """Measure the servo period and its jitter from the device's sample time stamps.

    A simulated device's clock is exact; hardware time stamps show drift, jitter and missed cycles.
    Identifies ``device.servo_rate_hz``.

    Parameters
    ----------
    bench : Bench
        The device under test (configured by this stage).
    builder : ModelBuilder
        The built-up model; the identified values are added to ``builder.values``.
    duration_s : float
        Recording length (s).

    Returns
    -------
    StageResult

    Raises
    ------
    StageError
        If cycles were missed (period steps > 1.5 nominal) or the jitter exceeds 5 % of the period.
    """
    t0 = time.perf_counter()
    dev = bench.dev
    fs = dev.info.servo_rate_hz
    n = int(duration_s * fs)
    ts = np.empty(n)
    for k in range(n):
        ts[k] = dev.read().t_s
        dev.command(0.0)
    dt = np.diff(ts)
    period = float(np.median(dt))
    jitter = float(np.std(dt))
    missed = int(np.sum(dt > 1.5 / fs))
    if missed or jitter > 0.05 * period:
        raise StageError(f"servo timing: {missed} missed cycles, jitter {jitter * 1e6:.2f} us over {n} cycles; "
                         "identification needs a fixed rate (sec. 3.5.2)")
    rate = 1.0 / period
    if abs(rate - fs) <= 1e-6 * fs:
        rate = fs  # the nominal rate, to the clock's resolution
    builder.values["device.servo_rate_hz"] = rate
    return StageResult("timing", CONFIG, {"device.servo_rate_hz": rate},
                       {"device.servo_rate_hz": jitter / period},
                       figure_data={"dt_us": dt * 1e6},
                       notes=[f"period {period * 1e6:.3f} us, jitter {jitter * 1e6:.4f} us rms, {missed} missed "
                              f"cycles in {n}"], elapsed_s=time.perf_counter() - t0)
