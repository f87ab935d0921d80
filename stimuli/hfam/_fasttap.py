"""numba loop of :func:`stimuli.hfam.refine.play_on_wall` for the simulated device: the same ticks as its
``read()``/``command()`` loop (the proportional wall, the transient from the tick after the crossing, the
device's input rule and one period of output delay), in one compiled call over the device's fused arrays
(``devices.sim.SimDevice.fused_arrays`` / ``fused_state``). Tested tick for tick against the Python loop."""

from __future__ import annotations

from plumbing.jitcache import njit  # numba.njit; its cache and _nrt=False: plumbing/jitcache.py

from devices.sim import kernel as SK
from devices.sim import layout as L


@njit(cache=True, _nrt=False)
def tap_on_wall(dev, sp, ss, srs, traj, grip, current_A, wall_N_m, kf, limit, hist, acc, hist_acc, cmd):
    """One tap on the wall ``-wall_N_m x`` (x < 0) with ``current_A`` played from the tick after the crossing.

    Parameters
    ----------
    dev : float64 array (N_DEV,)
        The device's Python-side state (``devices.sim.layout.D_*``), read and written.
    sp, ss, srs, traj, grip : arrays of ``devices.sim.kernel.tick``.
    current_A : float64 array (n,)
    wall_N_m, kf : float
        Wall stiffness (N/m) and the device's force per ampere (N/A).
    limit : int
        Ticks at most.
    hist : float64 array (n_hist,)
        Written: a ring of the positions read up to and including the crossing tick.
    acc : float64 array (n,)
        Written: acceleration read after the command of ticks 0..n-1 after the crossing (NaN elsewhere).
    hist_acc : float64 array (n_hist,)
        Written alongside ``hist``: the acceleration read on the same ticks (the approach before impact; the
        HFAM scoring compares windows that start before impact, ``stimuli.hfam.scoring``).
    cmd : float64 array (n,)
        Written: the current commanded (wall + transient, before the amplifier's clamp) on ticks 0..n-1 after
        the crossing, A (section 4.4.3's saturation: whether the command reached the limit).

    Returns
    -------
    k_imp : int
        Tick of the crossing, -1 if none.
    n_pushed : int
        Positions written into ``hist`` (the newest at ``(n_pushed - 1) % n_hist``).
    """
    n = current_A.shape[0]
    n_hist = hist.shape[0]
    k_imp = -1
    pushed = 0
    prev = dev[L.D_POS]
    k = 0
    while k < limit:
        x = dev[L.D_POS]
        if k_imp < 0:
            hist[pushed % n_hist] = x
            hist_acc[pushed % n_hist] = dev[L.D_ACC]
            pushed += 1
            if prev >= 0.0 > x:                         # the renderer: depth -x > 0
                k_imp = k
        i_cmd = (-wall_N_m * x / kf) if x < 0.0 else 0.0
        j = k - k_imp if k_imp >= 0 else -1
        if 1 <= j <= n:
            i_cmd += current_A[j - 1]
        # SimDevice.command(i_cmd): the device's input rule, then one servo period of its physics (written
        # out as in renderer.law.run_sim: one shared inlined helper for both made that loop 20 % slower)
        if 0 <= j < n:
            cmd[j] = i_cmd
        i, status, rejected = SK.command_rule_nb(i_cmd, dev[L.D_LIMIT])
        dev[L.D_REJECTED] += rejected
        dev[L.D_LAST] = i
        applied = dev[L.D_HELD]
        dev[L.D_HELD] = i
        tick = dev[L.D_TICK] + 1.0
        dev[L.D_TICK] = tick
        p, a, g, hot = SK.tick(ss, sp, srs, traj, grip, int(tick - 1.0 - dev[L.D_USER_TICK]), applied)
        dev[L.D_T] = tick * dev[L.D_PERIOD]
        dev[L.D_POS] = p
        dev[L.D_ACC] = a
        dev[L.D_GRIP] = g
        dev[L.D_STATUS] = status | L.HOT_STATUS if hot != 0.0 else status
        if 0 <= j < n:
            acc[j] = a
        if j >= n - 1:
            break
        prev = x
        k += 1
    return k_imp, pushed
