"""Coulomb and viscous friction from slow closed-loop motion (thesis sec. 3.5.1, eq. 3.18; Figure 3.16)."""

from __future__ import annotations

import numpy as np

from .bench import Bench
from .common import StageError
from .experiment import Experiment, ramp_profile


def slow_motion_friction(bench: Bench, speeds_m_s=(0.02, 0.05, 0.1), distance_m: float = 0.02,
                         kp_N_m: float = 10000.0, kd_Ns_m: float = 10.0, grip_N: float = 0.0):
    """Force needed to move the connected masses forward and backward at constant speeds under PD control.

    At constant speed the mean force is ``c + b v`` forward and ``-(c + b v)`` backward; a line through
    the half-differences at several speeds gives the Coulomb level ``c`` (intercept) and the viscous
    coefficient ``b`` (slope).

    Returns
    -------
    c_N, b_Ns_m, rel_err, figure : float, float, float, dict
        ``rel_err``: RMS deviation of the half-differences from the line relative to ``c``.
    """
    fs = bench.info.servo_rate_hz
    kf = bench.info.force_per_amp_N_A
    half, fig = [], {"speed": [], "x": [], "F": []}
    for v in speeds_m_s:
        ref, fwd, bwd = ramp_profile(fs, distance_m, v, dwell_s=0.05)
        tr = bench.run(Experiment(f"slow motion {v} m/s", np.zeros(ref.size), ref, kp_N_m, kd_Ns_m,
                                  grip_N=grip_N))
        force = tr.i_A * kf
        f_fwd, f_bwd = float(force[fwd].mean()), float(force[bwd].mean())
        half.append(0.5 * (f_fwd - f_bwd))
        fig["speed"].append(v)
        fig["x"].append(tr.x_m)
        fig["F"].append(force)
    b, c = np.polyfit(np.asarray(speeds_m_s, float), np.asarray(half), 1)
    if c < -0.01 * max(abs(x) for x in half):
        raise StageError(f"friction: negative Coulomb level {c:.4f} N from slow motion; the controller did not "
                         "track the ramps")
    c = max(float(c), 0.0)
    b = max(float(b), 0.0)
    pred = c + b * np.asarray(speeds_m_s)
    rel = float(np.sqrt(np.mean((pred - half) ** 2)) / max(c, 1e-9))
    fig["half_diff_N"] = half
    return c, b, rel, fig
