"""Step 1 of the HFAM build: selection of recorded taps (section 4.4.1, "Selection").

Taps with high pre-impact acceleration and atypical taps (low correlation with
their velocity neighbours) are dropped, then a nicely spaced subset over
incoming velocity is picked.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..recordings import Tap
from .settings import BuildSettings


@dataclass
class Selection:
    """Result of tap selection: the chosen taps (increasing velocity) and the dropped ones with reasons."""

    selected: list[Tap]
    dropped: list[tuple[Tap, str]] = field(default_factory=list)


# ---------------------------------------------------------------------------- selection
def _post_impact(tap: Tap, n: int) -> np.ndarray:
    a = tap.accel_m_s2[tap.t_s > 0]
    return a[:n]


def _peak_corr(x: np.ndarray, y: np.ndarray, max_lag: int) -> float:
    """Largest normalised cross-correlation of x and y over lags |l| <= max_lag."""
    n = min(x.size, y.size)
    x = x[:n]
    y = y[:n]
    nx = np.linalg.norm(x)
    ny = np.linalg.norm(y)
    if nx == 0 or ny == 0:
        return 0.0
    best = -1.0
    for lag in range(-max_lag, max_lag + 1):
        if lag >= 0:
            c = float(np.dot(x[lag:], y[: n - lag]))
        else:
            c = float(np.dot(x[: n + lag], y[-lag:]))
        best = max(best, c)
    return best / (nx * ny)


def select_taps(taps: Sequence[Tap], fs_hz: float, settings: BuildSettings) -> Selection:
    """Choose a nicely spaced subset of usable taps over incoming velocity (section 4.4.1).

    Taps are dropped for (in this order): no acceleration after impact; high
    pre-impact acceleration (peak before impact > ``max_pre_impact_ratio`` of
    the peak after); being atypical (median peak correlation, within +/-0.5 ms
    of lag, with up to four neighbours in velocity below
    ``min_neighbour_corr``; needs >= 3 usable taps); a repeated velocity (the
    more typical one is kept); not being nearest to one of ``n_velocities``
    evenly spaced target velocities. With ``settings.taps`` the listed taps
    are used as they are (only the first two checks apply).

    Returns
    -------
    Selection
        ``selected`` in strictly increasing velocity.

    Raises
    ------
    ValueError
        If fewer than two distinct velocities survive, or a requested tap id is missing.
    """
    n_t = max(1, int(round(settings.duration_s * fs_hz)))
    dropped: list[tuple[Tap, str]] = []
    pool = list(taps)
    if settings.taps is not None:
        by_id = {tp.tap: tp for tp in pool}
        missing = [i for i in settings.taps if i not in by_id]
        if missing:
            raise ValueError(f"requested tap id(s) {missing} are not in the recording (ids {sorted(by_id)})")
        dropped = [(tp, "not in the requested --taps list") for tp in pool if tp.tap not in settings.taps]
        pool = [by_id[i] for i in settings.taps]
    usable = []
    for tp in pool:
        post = _post_impact(tp, n_t)
        # before the impact only: the sample at t = 0 is the first in contact, already part of the impact (a stiff
        # contact's first tick can hold a third of its peak)
        pre = tp.accel_m_s2[tp.t_s < 0]
        post_peak = float(np.max(np.abs(post))) if post.size else 0.0
        pre_peak = float(np.max(np.abs(pre))) if pre.size else 0.0
        if post_peak == 0.0:
            dropped.append((tp, "no acceleration after impact"))
        elif pre_peak > settings.max_pre_impact_ratio * post_peak:
            dropped.append((tp, f"high pre-impact acceleration: {pre_peak:.3g} m/s^2 is "
                                f"{100 * pre_peak / post_peak:.0f}% of the impact peak (limit "
                                f"{100 * settings.max_pre_impact_ratio:.0f}%)"))
        else:
            usable.append(tp)
    usable.sort(key=lambda tp: tp.v_in_m_s)
    corr = {id(tp): 1.0 for tp in usable}
    if len(usable) >= 3 and settings.taps is None:  # a hand-made selection is trusted as typical
        shapes = [_post_impact(tp, n_t) for tp in usable]
        max_lag = max(1, int(round(0.5e-3 * fs_hz)))
        typical = []
        for i, tp in enumerate(usable):
            neighbours = [j for j in range(max(0, i - 2), min(len(usable), i + 3)) if j != i]
            c = float(np.median([_peak_corr(shapes[i], shapes[j], max_lag) for j in neighbours]))
            corr[id(tp)] = c
            if c < settings.min_neighbour_corr:
                dropped.append((tp, f"atypical: correlation {c:.2f} with its velocity neighbours "
                                    f"(min {settings.min_neighbour_corr:.2f})"))
            else:
                typical.append(tp)
        usable = typical
    # one tap per velocity: keep the most typical
    unique: dict[float, Tap] = {}
    for tp in usable:
        other = unique.get(tp.v_in_m_s)
        if other is None:
            unique[tp.v_in_m_s] = tp
        else:
            keep, drop = (tp, other) if corr[id(tp)] > corr[id(other)] else (other, tp)
            unique[tp.v_in_m_s] = keep
            dropped.append((drop, f"same velocity as tap {keep.tap} (kept the more typical one)"))
    candidates = sorted(unique.values(), key=lambda tp: tp.v_in_m_s)
    if settings.taps is None and len(candidates) > settings.n_velocities:
        targets = np.linspace(candidates[0].v_in_m_s, candidates[-1].v_in_m_s, settings.n_velocities)
        chosen: list[Tap] = []
        free = list(candidates)
        for target in targets:
            best = min(free, key=lambda tp: abs(tp.v_in_m_s - target))
            chosen.append(best)
            free.remove(best)
        for tp in free:
            dropped.append((tp, f"not needed for {settings.n_velocities} evenly spaced velocities"))
        candidates = sorted(chosen, key=lambda tp: tp.v_in_m_s)
    if len(candidates) < 2:
        reasons = "; ".join(f"tap {tp.tap} ({tp.v_in_m_s} m/s): {why}" for tp, why in dropped) or "none dropped"
        raise ValueError(f"fewer than two distinct incoming velocities left after selection ({reasons})")
    return Selection(candidates, dropped)
