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


def grid_steps(fs_hz: float, t_prev_s: float, t_s: float) -> int:
    """Servo periods from the ring's newest slot to a sample.

    Parameters
    ----------
    fs_hz : float
        The servo rate: the ring's spacing is ``1 / fs_hz``.
    t_prev_s : float
        Time of the ring's newest slot (s); NaN before the first sample.
    t_s : float
        The sample's own time (s).

    Returns
    -------
    int
        0 for the sample read again (within half a period of the newest slot), 1 for the next, ``k`` > 1 when
        ``k - 1`` samples were missed (the laws fill the ring's last slots of that gap by a straight line; at
        most 10**9), -1 to restart the grid at ``t_s`` (the first sample, a clock that went back by more than
        half a period, or a time that is NaN).
    """
    dn = (t_s - t_prev_s) * fs_hz
    if dn != dn or dn < -0.5:
        return -1
    if dn < 0.5:
        return 0
    if dn < 1.5:
        return 1
    if dn > 1e9:
        return 1_000_000_000
    return int(dn + 0.5)


def same_sample_limit(cfg, fs_hz: float, nring: int) -> int:
    """Ticks in a row that may read one sample before the laws take each tick as a new sample again.

    Longer than any catch-up after a late tick (``cfg.max_catchup_s``) and than the ring: a sample clock that
    stands still longer is not a device handing over its newest sample but a driver that gives no time (or a
    link holding its last sample), and the laws then fit one position per tick, as without a clock.
    """
    return int(math.ceil(float(cfg.max_catchup_s) * fs_hz)) + int(nring)
