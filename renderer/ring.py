"""The time grid of the servo laws' position rings (``renderer.law``, ``renderer.law3``); plain Python, no numba.

The sliding least-squares velocity (:mod:`renderer.velocity`) fits positions one servo period apart. A host
tick is not always a new sample: a device that runs its own servo clock and hands over its newest state (the
Touch's servo thread) gives the same sample twice when the host ticks faster than that clock, or catches up
back to back after a late tick; and a late tick skips samples. Read naively, the repeats fit a standstill and
the skips a jump (a late host tick read a tap at 0 m/s, or at several times its speed). The laws therefore
place each sample on a grid of servo periods by the sample's own time (``DeviceState.t_s``): a sample read
again adds nothing to the ring, samples the host missed are filled in by linear interpolation. On a device
whose samples arrive once per tick (the simulations, the 1-DOF board's frames) nothing changes.
"""

from __future__ import annotations

import math


def advance(w, i_tring: int, i_same: int, fs_hz: float, same_max: float, t_s: float) -> int:
    """Place a sample on the ring's time grid; return the servo periods it is on from the ring's newest slot.

    The laws call this once per tick, then push positions by the result (numba-inlined into them).

    Parameters
    ----------
    w : array of float
        The law's state: ``w[i_tring]`` is the time of the ring's newest slot (s; NaN before the first sample),
        ``w[i_same]`` how many ticks in a row read the same sample. Both are updated.
    i_tring, i_same : int
        Their indices in ``w``.
    fs_hz : float
        The servo rate: the ring's spacing is ``1 / fs_hz``.
    same_max : float
        Ticks in a row that may read one sample (:func:`same_sample_limit`); beyond, each tick is a new sample.
    t_s : float
        The sample's own time (s).

    Returns
    -------
    int
        0 for the sample read again (within half a period of the newest slot): push nothing; 1 for the next: push
        it; ``k`` > 1 when ``k - 1`` samples were missed: fill the ring's last slots of that gap by a straight line,
        then push it (at most 10**9); -1 to restart the grid at ``t_s`` (the first sample, a clock that went back
        by more than half a period, a time that is NaN, or a clock standing still beyond ``same_max``): push it.
    """
    dn = (t_s - w[i_tring]) * fs_hz
    if dn != dn or dn < -0.5:
        steps = -1
    elif dn < 0.5:
        steps = 0
    elif dn < 1.5:
        steps = 1
    elif dn > 1e9:
        steps = 1_000_000_000
    else:
        steps = int(dn + 0.5)
    if steps == 0:
        w[i_same] += 1.0
        if w[i_same] > same_max:   # the sample's clock stands still (longer than any catch-up): a tick is a sample
            steps = -1
    else:
        w[i_same] = 0.0
    if steps != 0:
        w[i_tring] = t_s if steps < 0 else w[i_tring] + steps / fs_hz
    return steps


def grid_steps(fs_hz: float, t_prev_s: float, t_s: float) -> int:
    """Servo periods from a ring's newest slot at ``t_prev_s`` to a sample at ``t_s`` (:func:`advance`'s grid
    alone, without its count of samples read again)."""
    return advance([t_prev_s, 0.0], 0, 1, fs_hz, math.inf, t_s)


def same_sample_limit(cfg, fs_hz: float, nring: int) -> int:
    """Ticks in a row that may read one sample before the laws take each tick as a new sample again.

    Longer than any catch-up after a late tick (``cfg.max_catchup_s``) and than the ring: a sample clock that
    stands still longer is not a device handing over its newest sample but a driver that gives no time (or a
    link holding its last sample), and the laws then fit one position per tick, as without a clock.
    """
    return int(math.ceil(float(cfg.max_catchup_s) * fs_hz)) + int(nring)
