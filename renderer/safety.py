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

import contextlib
import time
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
        # a stalled simulation endangers nothing: the watchdog guards real motors only (a lockstep device's clock
        # is simulated too and waits for the host: docs/protocol.md "Lockstep")
        watchdog_period_ns=None if info.on_device_clock else period_ns + int(cfg.watchdog_overrun_s * 1e9))


class SafetyPath:
    """The per-tick rules of the module doc for a servo law written in plain Python (homing): one instance per
    run, its methods called in the order read -> :meth:`sample` -> law -> :meth:`current` -> :meth:`heat` ->
    command -> :meth:`watchdog`. (:class:`renderer.loop.ServoLoop` inlines the same rules, with the same
    :class:`SafetyBounds`, into its compiled law.)

    Parameters
    ----------
    bounds : SafetyBounds
        From :func:`safety_bounds`.
    current_limit_A : float
        Largest |current| commanded (A); a NaN current becomes 0 A.

    Attributes
    ----------
    bad_in_row, bad_total : int
        Implausible samples held: in a row now, and in all.
    """

    __slots__ = ("bounds", "current_limit_A", "bad_in_row", "bad_total", "_prev_ns")

    def __init__(self, bounds: SafetyBounds, current_limit_A: float):
        self.bounds = bounds
        self.current_limit_A = float(current_limit_A)
        self.bad_in_row = 0
        self.bad_total = 0
        self._prev_ns = time.perf_counter_ns()

    def sample(self, state, x_prev_m: float) -> tuple[float, str | None]:
        """The position to use this tick and the stop reason, if any.

        Parameters
        ----------
        state : devices.base.DeviceState
            What ``read()`` returned.
        x_prev_m : float
            The last good position (m): held when this sample is implausible or NaN (a disconnect returns
            the sample's own position).

        Returns
        -------
        (position_m, reason) : (float, str or None)
            ``reason`` is ``"disconnected"`` (status bit), ``"sensor"`` (``max_bad_samples`` implausible
            samples in a row) or None.
        """
        b = self.bounds
        if state.status & STATUS_DISCONNECTED:
            return state.position_m, "disconnected"
        x = state.position_m
        if state.status & STATUS_SENSOR_INVALID or not (-b.position_limit_m <= x <= b.position_limit_m) \
                or not (-b.accel_limit_m_s2 <= state.accel_m_s2 <= b.accel_limit_m_s2):
            self.bad_in_row += 1
            self.bad_total += 1
            return x_prev_m, ("sensor" if self.bad_in_row >= b.max_bad_samples else None)
        self.bad_in_row = 0
        return x, None

    def current(self, i_A: float) -> float:
        """``i_A`` clamped to +-``current_limit_A``; NaN -> 0 A."""
        limit = self.current_limit_A
        if i_A > limit:
            return limit
        if i_A < -limit:
            return -limit
        if i_A != i_A:
            return 0.0
        return i_A

    def heat(self, temp_rise_K: float, i_A: float) -> float:
        """The winding temperature rise (K) after one tick at ``i_A`` (section 4.4.2, :mod:`renderer.thermal`)."""
        b = self.bounds
        return temp_rise_K + (b.heat_K_A2 * i_A * i_A - temp_rise_K) * b.alpha

    def watchdog(self) -> bool:
        """True if the servo period that just ended exceeded the bound (hardware only; never on a sim)."""
        if self.bounds.watchdog_period_ns is None:
            return False
        now = time.perf_counter_ns()
        stalled = now - self._prev_ns > self.bounds.watchdog_period_ns
        self._prev_ns = now
        return stalled

    def pause_watchdog(self) -> None:
        """Restart the watchdog's period after a deliberate pause (pacing, a check): it was not a stall."""
        self._prev_ns = time.perf_counter_ns()


@contextlib.contextmanager
def zero_on_error(device):
    """Command 0 A to ``device`` when the block raises (anything, Ctrl-C included), then re-raise: the
    output is never left on by an error (the servo loop's rule, for laws written in plain Python)."""
    try:
        yield device
    except BaseException:
        device.command(0.0)
        raise
