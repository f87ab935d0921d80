"""numba loop of :func:`devices.identify.record.play` for the simulated device: the same ticks as
``read()``/``command()`` in a Python loop (one servo period of output delay, clamp to the amplifier limit),
in one compiled call."""

from __future__ import annotations

from plumbing.jitcache import njit  # numba.njit; its cache and _nrt=False: plumbing/jitcache.py

from ..sim import kernel as K


@njit(cache=True, _nrt=False)
def play_open(s, p, rs, traj, grip, k0, held, u, limit, pos, acc, g, xs, accs, gs):
    """Play ``u`` (already finite); record the state read before each command into ``xs, accs, gs``.

    ``k0``: trajectory index of the first tick; ``held``: current applied during the first period;
    ``pos, acc, g``: the state currently shown by ``read()``. Returns (held, pos, acc, g, hot, clipped)
    after the last tick, ``clipped`` = 1 if the last command was at the limit."""
    n = u.shape[0]
    hot = 0.0
    clipped = 0
    for k in range(n):
        xs[k] = pos
        accs[k] = acc
        gs[k] = g
        i = u[k]
        clipped = 0
        if i >= limit:
            i = limit
            clipped = 1
        elif i <= -limit:
            i = -limit
            clipped = 1
        applied = held
        held = i
        pos, acc, g, hot = K.tick(s, p, rs, traj, grip, k0 + k, applied)
    return held, pos, acc, g, hot, clipped
