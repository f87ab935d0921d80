"""Stage 2: the current amplifier with the motor locked: gain, offset, bandwidth, saturation (sec. 3.5.2,
"Current Amplifier", eq. 3.17)."""

from __future__ import annotations

import math
import time

import numpy as np

from .bench import Bench
from .common import ModelBuilder, StageError, StageResult
from .experiment import Experiment, chirp

CONFIG = "motor_locked"
# a first-order corner above this fraction of the servo rate is indistinguishable from an ideal amplifier
IDEAL_ABOVE_FRACTION = 0.5


def identify_amplifier(bench: Bench, builder: ModelBuilder, sweep_amplitude_A: float = 0.5) -> StageResult:
    """DC steps for gain and offset, steps past the rated limit for saturation, a swept sine for bandwidth.

    The amplifier output is measured by the device's current sense (the sim's true amplifier current). The
    first-order model ``i[k] = beta i[k-1] + (1 - beta) u[k-1]`` is fitted by linear least squares;
    ``beta = exp(-2 pi f_c T)``. Identifies ``device.current_amplifier_A``, ``amplifier.kind`` (ideal or
    lowpass), ``amplifier.bandwidth_hz``, and the calibration ``amplifier.gain``, ``amplifier.offset_A``.

    Parameters
    ----------
    bench : Bench
        The device under test (configured by this stage).
    builder : ModelBuilder
        The built-up model; the identified values are added to ``builder.values``.
    sweep_amplitude_A : float
        Amplitude of the bandwidth sweep (A).

    Returns
    -------
    StageResult

    Raises
    ------
    StageError
        Without a current measurement (hardware without a sense channel), or if the motor moved (not locked).
    """
    t0 = time.perf_counter()
    bench.configure(CONFIG)
    info = bench.info
    fs = info.servo_rate_hz
    n = int(0.02 * fs)
    levels = np.array([-1.0, -0.5, 0.0, 0.5, 1.0]) * info.current_continuous_A
    over = info.current_amplifier_A * np.array([0.9, 1.1, 1.25])
    seq = np.concatenate([levels, over, -over])
    ff = np.repeat(seq, n)
    tr = bench.run(Experiment("dc steps", ff), measure_current=True, allow_saturation=True)
    if tr.iamp_A is None:
        return _amplifier_by_ammeter(bench, builder, t0)
    if np.ptp(tr.x_m) > 2 * info.position_resolution_m:
        raise StageError(f"amplifier stage: the motor moved {np.ptp(tr.x_m) * 1e3:.3f} mm; lock the motor")
    means = np.array([tr.iamp_A[k * n + n // 2:(k + 1) * n].mean() for k in range(seq.size)])
    nl = levels.size
    gain, offset = np.polyfit(levels, means[:nl], 1)
    sat = float(np.max(np.abs(means[nl:])))
    if abs(sat - info.current_amplifier_A) <= 5e-3 * info.current_amplifier_A:
        sat = float(info.current_amplifier_A)  # the rated limit, to the measurement's resolution
    elif sat < info.current_peak_A:
        raise StageError(f"amplifier stage: the amplifier saturates at {sat:.3f} A, below the device's rated peak "
                         f"{info.current_peak_A:g} A; check the supply and the amplifier's current limit")
    # bandwidth: swept sine, regression of the first-order model on the sampled amplifier output
    u = chirp(fs, sweep_amplitude_A, 10.0, 0.45 * fs, 0.5)
    tr2 = bench.run(Experiment("bandwidth sweep", u), measure_current=True)
    cmd, cur = tr2.i_A, tr2.iamp_A
    y = cur[1:] - cmd[:-1]
    z = cur[:-1] - cmd[:-1]
    beta = float(np.dot(y, z) / np.dot(z, z)) if np.dot(z, z) > 0 else 0.0
    period = 1.0 / fs
    if beta <= 1e-6:
        fc = math.inf
    else:
        fc = -math.log(min(beta, 1 - 1e-12)) / (2 * math.pi * period)
    ideal = fc > IDEAL_ABOVE_FRACTION * fs
    vals = {"device.current_amplifier_A": sat, "amplifier.gain": float(gain), "amplifier.offset_A": float(offset),
            "amplifier.bandwidth_hz": float(fc) if not ideal else 2000.0}
    builder.base["amplifier"]["kind"] = "ideal" if ideal else "lowpass"
    builder.values["device.current_amplifier_A"] = sat
    bench.saturation_A = sat
    if not ideal:
        builder.values["amplifier.bandwidth_hz"] = float(fc)
    pred = np.empty_like(cur)
    pred[0] = cur[0]
    b = 0.0 if ideal else beta
    pred[1:] = b * cur[:-1] + (1 - b) * cmd[:-1]
    resid = float(np.linalg.norm(cur - pred) / (np.linalg.norm(cur - cur.mean()) or 1.0))
    notes = [f"gain {gain:.4f} A/A, offset {offset * 1e3:.3f} mA, saturation {sat:.3f} A, "
             + ("ideal (no measurable low-pass below Nyquist)" if ideal else f"first-order low-pass {fc:.0f} Hz")]
    fig = {"levels_A": levels, "measured_A": means[:nl], "cmd_A": cmd, "iamp_A": cur, "fs_hz": fs,
           "sat_cmd_A": np.concatenate([over, -over]), "sat_meas_A": means[nl:]}
    return StageResult("amplifier", CONFIG, vals,
                       {"device.current_amplifier_A": 0.0, "amplifier.gain": resid, "amplifier.offset_A": resid,
                        "amplifier.bandwidth_hz": resid},
                       figure_data=fig, notes=notes, elapsed_s=time.perf_counter() - t0)


def _amplifier_by_ammeter(bench: Bench, builder: ModelBuilder, t0: float) -> StageResult:
    """No current sense (hardware): the operator reads an ammeter in series with the locked motor at two DC
    commands (sec. 3.5.2: gain and offset calibrated with a precision ammeter); the bandwidth cannot be
    measured this way and the amplifier is taken as ideal (noted in the result)."""
    info = bench.info
    fs = info.servo_rate_hz
    levels = (0.5 * info.current_continuous_A, -0.5 * info.current_continuous_A)
    readings = []
    for level in levels:
        n = int(3.0 * fs)  # hold the command while the operator reads the meter
        bench.dev.command(0.0)
        answer = bench.prompt(f"\n>>> The motor is locked; {level:+.3f} A will be commanded for 3 s. Read the "
                              "ammeter, then type the reading in A: ")
        bench.run(Experiment(f"dc {level:+.3f} A", np.full(n, level)))
        try:
            readings.append(float(answer))
        except ValueError:
            raise StageError(f"amplifier stage: ammeter reading {answer!r} is not a number") from None
    gain = (readings[0] - readings[1]) / (levels[0] - levels[1])
    offset = readings[0] - gain * levels[0]
    if not 0.5 < gain < 2.0:
        raise StageError(f"amplifier stage: implausible gain {gain:.3f} A/A from the ammeter readings {readings}")
    sat = float(info.current_amplifier_A)
    builder.base["amplifier"]["kind"] = "ideal"
    vals = {"device.current_amplifier_A": sat, "amplifier.gain": float(gain), "amplifier.offset_A": float(offset)}
    return StageResult("amplifier", CONFIG, vals, {k: 0.0 for k in vals},
                       notes=[f"gain {gain:.4f} A/A, offset {offset * 1e3:.3f} mA by ammeter; no current sense: "
                              "bandwidth not measured, amplifier taken as ideal, saturation from the device info"],
                       elapsed_s=time.perf_counter() - t0)
