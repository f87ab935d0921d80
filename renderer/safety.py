"""The servo safety path every servo law runs through: sensor plausibility, current limits, winding heat.

One source for the bounds and the rules that :class:`renderer.loop.ServoLoop` (the wall and
transient law, inlined per tick for speed) and :class:`renderer.homing.HomingController`
(the homing PD law) apply each tick:

* a position, acceleration or grip outside its plausible range (or NaN) is replaced by the last
  good value and counted; ``max_bad_samples`` in a row stop the law with zero output;
* a device status of "disconnected" stops it with zero output;
* the commanded current is clamped (the continuous, thermally safe limit for steady forces) and a
  NaN becomes 0 A;
* the winding temperature rise is stepped every tick (section 4.4.2, :mod:`renderer.thermal`);
* on hardware, a servo period longer than one period plus ``watchdog_overrun_s`` stops it;
* the wall law's passivity observer (:mod:`renderer.passivity`) stops an unstable wall loop.
"""

from __future__ import annotations

from dataclasses import dataclass

from .config import RendererConfig
from .thermal import safe_continuous_current, step_coefficients

#: ``DeviceState.status`` bits (devices.base)
STATUS_SENSOR_INVALID, STATUS_DISCONNECTED = 16, 32


@dataclass(frozen=True)
class SafetyBounds:
    """Per-tick safety constants of one device at one servo rate (see module doc).

    Attributes
    ----------
    position_limit_m, accel_limit_m_s2 : float
        Plausible |position| (m) and |acceleration| (m/s^2).
    grip_min_N, grip_max_N : float
        Plausible grip range (N).
    max_bad_samples : int
        Implausible samples in a row that stop the law.
    continuous_safe_A : float
        Current limit for steady forces (A): the continuous limit, lowered so steady contact alone
        can never overheat the winding (:func:`renderer.thermal.safe_continuous_current`).
    heat_K_A2, alpha : float
        Thermal step: steady rise per A^2 (K/A^2) and the per-tick blend ``1 - exp(-dt/tau)``.
    t_attenuate_K, t_end_K : float
        Temperature rises (K) where transients start to fade and end.
    watchdog_period_ns : int or None
        Longest tolerated servo period on hardware (ns); None for simulated devices.
    """

    position_limit_m: float
    accel_limit_m_s2: float
    grip_min_N: float
    grip_max_N: float
    max_bad_samples: int
    continuous_safe_A: float
    heat_K_A2: float
    alpha: float
    t_attenuate_K: float
    t_end_K: float
    watchdog_period_ns: int | None


def safety_bounds(info, fs_hz: float, cfg: RendererConfig | None = None,
                  continuous_A: float | None = None) -> SafetyBounds:
    """The safety constants for ``info`` at ``fs_hz``.

    Parameters
    ----------
    info : devices.base.DeviceInfo
        Sensor ranges, current limits and thermal parameters of the device.
    fs_hz : float
        Servo rate (Hz).
    cfg : RendererConfig or None
        Position limit, bad-sample count, thermal fractions and watchdog margin (defaults if None).
    continuous_A : float or None
        Continuous current limit (A) before the thermal cap; default ``info.current_continuous_A``.

    Returns
    -------
    SafetyBounds
    """
    cfg = cfg if cfg is not None else RendererConfig()
    dt = 1.0 / fs_hz
    heat, alpha = step_coefficients(info, dt)
    tmax = info.winding_max_temp_rise_K
    gmax = 2.0 * max(abs(info.grip_range_N[0]), abs(info.grip_range_N[1]), 1.0)
    ic = info.current_continuous_A if continuous_A is None else min(continuous_A, info.current_continuous_A)
    period_ns = int(round(1e9 / fs_hz))
    return SafetyBounds(
        position_limit_m=float(cfg.position_limit_m), accel_limit_m_s2=2.0 * info.accel_range_m_s2,
        grip_min_N=-gmax, grip_max_N=gmax, max_bad_samples=int(cfg.max_bad_samples),
        continuous_safe_A=safe_continuous_current(info, ic), heat_K_A2=heat, alpha=alpha,
        t_attenuate_K=cfg.thermal_attenuate_frac * tmax, t_end_K=cfg.thermal_end_frac * tmax,
        # a stalled simulation endangers nothing: the watchdog guards real motors only
        watchdog_period_ns=None if info.simulated else period_ns + int(cfg.watchdog_overrun_s * 1e9))

