"""numba loop of :func:`devices.identify.successive.experiment.run_on_sim_fast` and ``run_on_sim_device``: the
PD/feedforward law of :func:`~devices.identify.successive.experiment.run_on_device` around the sim kernel's
``tick``."""

from __future__ import annotations

import math

from plumbing.jitcache import njit  # numba.njit; its cache and _nrt=False: plumbing/jitcache.py

from ...sim import kernel as K


@njit(cache=True, _nrt=False)
def run_pd(s, p, rs, traj, grip, ff, ref, closed, kp, kd, va, fs, limit, held, xs, acc, cmd, cur):
    """Run one experiment; fills ``xs, acc, cmd, cur`` (encoder position, accel, command, amplifier
    current per tick) and returns the current still held for the next period. Gains in A/m, A s/m."""
    n = ff.shape[0]
    res = p[K.P_ENC_RES]
    pos = res * math.floor(s[K.S_XM] / res)
    a_read = 0.0
    x0 = pos
    x_prev = 0.0
    v = 0.0
    for k in range(n):
        x = pos - x0
        xs[k] = x
        acc[k] = a_read
        i = ff[k]
        if closed:
            v += va * ((x - x_prev) * fs - v)
            i += kp * (ref[k] - x) - kd * v
        x_prev = x
        if i != i:
            i = 0.0
        if i > limit:
            i = limit
        elif i < -limit:
            i = -limit
        cmd[k] = i
        applied = held
        held = i
        pos, a_read, g, hot = K.tick(s, p, rs, traj, grip, k, applied)
        cur[k] = s[K.S_IAMP]
    return held
