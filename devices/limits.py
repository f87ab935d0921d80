"""Plausibility of a user's numbers against the device's own limits.

A grip outside what the grip sensor measures, a tap faster than the device is rated for, or a wall so stiff
that one encoder count already commands the whole continuous force are not experiments the device can run:
they are refused (ValueError naming the flag, the value and the limit: the dispatcher prints one ``error:``
line) or, where the run still means something, warned about (RuntimeWarning, printed as a ``warning:`` line).
"""

from __future__ import annotations

import math
import warnings
from typing import Iterable

from .base import DeviceInfo

# the encoder and firmware are rated to count every edge up to this tap speed (devices/firmware/README.md:
# the simulated MCU first drops counts above it); the thesis's taps are 0.05-0.3 m/s (section 4.5)
RATED_TAP_SPEED_M_S = 0.5
# beyond this many times the rated speed a "tap" is not a hand's (5 m/s gave a 6.2 m/s tap 57.5 mm deep)
IMPLAUSIBLE_SPEED_FACTOR = 4.0
# a wall this many times stiffer than the one-count stiffness is refused; between 1x and this, warned
IMPLAUSIBLE_STIFFNESS_FACTOR = 100.0


def check_grips(info: DeviceInfo, grips_N: Iterable[float], flag: str = "--grips-N") -> tuple[float, ...]:
    """Refuse grips outside the device's grip sensor range ``info.grip_range_N`` (N).

    Parameters
    ----------
    info : DeviceInfo
    grips_N : iterable of float
        Requested grip forces (N).
    flag : str
        The command-line flag they came from, named in the error.

    Returns
    -------
    tuple of float
        The grips, unchanged.

    Raises
    ------
    ValueError
        A grip that is not finite or lies outside ``info.grip_range_N``.
    """
    lo, hi = (float(v) for v in info.grip_range_N)
    grips = tuple(float(g) for g in grips_N)
    bad = [g for g in grips if not (math.isfinite(g) and lo <= g <= hi)]
    if bad:
        raise ValueError(f"{flag} {', '.join(f'{g:g}' for g in bad)} N: outside the grip range of {info.name}, "
                         f"{lo:g}-{hi:g} N (what its grip sensor measures); choose grips within it")
    return grips


def check_tap_speeds(speeds_m_s: Iterable[float], flag: str = "--velocities-m-s",
                     rated_m_s: float = RATED_TAP_SPEED_M_S) -> tuple[float, ...]:
    """Refuse tap speeds a hand does not make on this device; warn above its rated speed.

    Above ``IMPLAUSIBLE_SPEED_FACTOR x rated_m_s``: ValueError. Above ``rated_m_s``: RuntimeWarning (the
    encoder may drop counts on hardware, the accelerometer may saturate, and no HFAM library covers it).

    Parameters
    ----------
    speeds_m_s : iterable of float
        Incoming tap speeds (m/s, > 0).
    flag : str
        The flag they came from.
    rated_m_s : float
        The device's rated tap speed (m/s).

    Returns
    -------
    tuple of float
    """
    speeds = tuple(float(v) for v in speeds_m_s)
    bad = [v for v in speeds if not (math.isfinite(v) and 0.0 < v <= IMPLAUSIBLE_SPEED_FACTOR * rated_m_s)]
    if bad:
        raise ValueError(f"{flag} {', '.join(f'{v:g}' for v in bad)} m/s: not a tap speed of a hand on this "
                         f"device (rated to {rated_m_s:g} m/s; refused above "
                         f"{IMPLAUSIBLE_SPEED_FACTOR * rated_m_s:g} m/s, must be > 0)")
    fast = [v for v in speeds if v > rated_m_s]
    if fast:
        warnings.warn(f"{flag} {', '.join(f'{v:g}' for v in fast)} m/s is above the device's rated tap speed "
                      f"{rated_m_s:g} m/s: on hardware the encoder may drop counts and the accelerometer "
                      "saturate", RuntimeWarning, stacklevel=2)
    return speeds


def one_count_stiffness_N_m(info: DeviceInfo, continuous_A: float | None = None) -> float:
    """The stiffness (N/m) at which one encoder count of penetration commands the continuous force limit.

    ``continuous_A x force_per_amp / position_resolution``: a stiffer wall is a switch between 0 and the
    limit (it chatters; Colgate & Schenkel 1997 on quantisation), not a spring.
    """
    ic = info.current_continuous_A if continuous_A is None else float(continuous_A)
    return ic * info.force_per_amp_N_A / info.position_resolution_m


def check_stiffness(info: DeviceInfo, stiffness_N_m: float, continuous_A: float | None = None,
                    name: str = "stiffness_N_m") -> float:
    """Refuse a wall far stiffer than the device can render; warn when it saturates within one count.

    Parameters
    ----------
    info : DeviceInfo
    stiffness_N_m : float
        The wall's stiffness (N/m).
    continuous_A : float or None
        The run's continuous current limit (default the device's).
    name : str
        What to call it in the messages (``--stiffness-N-m`` or the config key).

    Returns
    -------
    float
        The stiffness, unchanged.
    """
    k1 = one_count_stiffness_N_m(info, continuous_A)
    k = float(stiffness_N_m)
    why = (f"one encoder count ({info.position_resolution_m * 1e6:.1f} um) already commands the continuous "
           f"force limit at {k1:.3g} N/m on {info.name}")
    if k > IMPLAUSIBLE_STIFFNESS_FACTOR * k1:
        raise ValueError(f"{name}={k:g} N/m: far beyond what the device can render ({why}); a wall this stiff "
                         "only chatters between zero and the limit. Use at most a few times that")
    if k > k1:
        warnings.warn(f"{name}={k:g} N/m: {why}: beyond it the wall is a switch between zero and the limit, not "
                      "a spring; if it chatters the passivity observer stops the run ('unstable')", RuntimeWarning,
                      stacklevel=2)
    return k
