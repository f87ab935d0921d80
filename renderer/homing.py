"""Homing controller: moves the stylus to a home height above the sample between trials.

Section 4.5.3: "Before each tap, the system would move the stylus to a home
position above the sample, giving the operator space to place the next object",
and after the five-second window "the device moved the user's hand back to the
home position". A subject who overpowers the homing force and taps the object
after the window invalidates the trial; :meth:`HomingController.run` detects it.

The control law is a saturated PD on the handle position through the Device
API only (``read()`` then ``command()``), plain scalar Python per tick:

    F = kp * (x_home - x) - kd * v,     i = clamp(F / (rho k_t / h), +-i_max)   (eq. 3.17)

with ``v`` a first-order low-passed backward difference of the quantized
position. ``i_max`` defaults to the continuous current limit, lowered so the
winding can never overheat (:func:`renderer.thermal.safe_continuous_current`),
so homing never commands more than the motor tolerates indefinitely and a
determined hand can overpower it (which is how overpowering is possible at all).
On hardware ``read()`` blocks until the device's next state frame, which paces
the loop; sim devices advance one servo period per ``command()``.

Homing runs through the same safety path as the renderer's servo loop
(:mod:`renderer.safety`): implausible or NaN sensor samples are held and
counted (too many in a row stop it), a disconnect stops it, the winding
temperature is stepped every tick (``temp_rise_K``, carried between calls so
the study's loops and homing share one thermal state), and on hardware a servo
period beyond the watchdog bound stops it; every stop zeroes the output and is
reported in :attr:`HomingResult.stop_reason`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from devices.validation import require_number, require_positive

from .safety import STATUS_DISCONNECTED, STATUS_SENSOR_INVALID, safety_bounds


@dataclass(frozen=True)
class HomingConfig:
    """Homing parameters.

    Attributes
    ----------
    home_height_m : float
        Home position above the surface (surface at 0, positive up).
    kp_N_m : float
        Proportional gain.
    kd_N_s_m : float
        Damping gain.
    max_current_A : float | None
        Current limit of the homing output; None = the device's continuous limit.
    velocity_cutoff_hz : float
        Cut-off of the velocity low-pass.
    settle_tolerance_m : float
        Settled when within this distance of home and slower than ``settle_speed_m_s``.
    settle_speed_m_s : float
    rearm_margin_m : float
        A post-window contact counts only after the stylus was this far above the surface.
    contact_tolerance_m : float
        The stylus counts as touching the surface within this height above it
        (a stiff real sample stops it at the surface, within encoder quantization).
    """

    home_height_m: float = 0.01
    kp_N_m: float = 300.0
    kd_N_s_m: float = 3.0
    max_current_A: float | None = None
    velocity_cutoff_hz: float = 200.0
    settle_tolerance_m: float = 0.002
    settle_speed_m_s: float = 0.02
    rearm_margin_m: float = 0.004
    contact_tolerance_m: float = 0.002

    def __post_init__(self) -> None:
        require_positive(self, "home_height_m", "kp_N_m", "velocity_cutoff_hz", "settle_tolerance_m",
                         "settle_speed_m_s", "rearm_margin_m", "contact_tolerance_m", prefix="homing.")
        require_number("kd_N_s_m", self.kd_N_s_m, minimum=0.0, prefix="homing.")
        require_number("max_current_A", self.max_current_A, minimum=0.0, strict=True, optional=True, prefix="homing.")


@dataclass
class HomingResult:
    """What happened while homing: duration, whether home was reached, post-window contacts."""

    duration_s: float
    ticks: int
    settled: bool
    contacts: int                 # impacts on the surface (from above the rearm margin) while homing
    final_position_m: float
    stop_reason: str = "duration"  # duration | settled | until | sensor | disconnected | watchdog
    bad_samples: int = 0          # implausible sensor samples held (renderer.safety)
    temp_rise_K: float = 0.0      # winding temperature rise at the end (K)


class HomingController:
    """Saturated PD homing through the Device API (see module doc)."""

    def __init__(self, device, config: HomingConfig | None = None, surface_height_m: float = 0.0) -> None:
        self.device = device
        self.config = config or HomingConfig()
        info = device.info
        self.force_per_amp_N_A = info.force_per_amp_N_A
        limit = self.config.max_current_A if self.config.max_current_A is not None else info.current_continuous_A
        self.dt_s = 1.0 / info.servo_rate_hz
        self.bounds = safety_bounds(info, info.servo_rate_hz, continuous_A=limit)
        self.max_current_A = self.bounds.continuous_safe_A
        self.temp_rise_K = 0.0  # winding temperature rise (K); the owner sets and reads it between calls
        self.surface_height_m = surface_height_m
        wc = 2.0 * math.pi * self.config.velocity_cutoff_hz * self.dt_s
        self._alpha = wc / (1.0 + wc)

    def run(self, duration_s: float, until_settled: bool = False, min_duration_s: float = 0.0,
            until=None, check_every: int = 200, realtime: bool = False, zero_at_end: bool = True) -> HomingResult:
        """Hold the stylus at home for at most ``duration_s``.

        Stops early when settled (if ``until_settled``, after ``min_duration_s``)
        or when ``until()`` returns True (checked every ``check_every`` ticks,
        e.g. "the subject has rated" in keyboard sessions). ``realtime`` paces
        an unpaced (sim) device to wall-clock time at each check, so waiting
        for a person does not spin a core. Returns a :class:`HomingResult`.
        The output is zeroed when anything raises, and at the end unless
        ``zero_at_end`` is False (back-to-back calls that keep holding home).
        """
        dev = self.device
        cfg = self.config
        b = self.bounds
        home = self.config.home_height_m + self.surface_height_m
        surface = self.surface_height_m + cfg.contact_tolerance_m
        armed_level = self.surface_height_m + cfg.rearm_margin_m
        kp, kd = cfg.kp_N_m, cfg.kd_N_s_m
        inv_fpa = 1.0 / self.force_per_amp_N_A
        imax = self.max_current_A
        alpha = self._alpha
        inv_dt = 1.0 / self.dt_s
        n = max(1, int(round(duration_s * inv_dt)))
        n_min = int(round(min_duration_s * inv_dt))
        tol, vtol = cfg.settle_tolerance_m, cfg.settle_speed_m_s
        plim, alim, max_bad = b.position_limit_m, b.accel_limit_m_s2, b.max_bad_samples
        heat, t_alpha, wd_ns = b.heat_K_A2, b.alpha, b.watchdog_period_ns
        temp = float(self.temp_rise_K)
        state = dev.read()
        x_prev = state.position_m
        if not (-plim <= x_prev <= plim):
            x_prev = home  # no plausible first sample: assume home (no velocity kick)
        v = 0.0
        armed = x_prev > armed_level
        contacts = 0
        settled = False
        reason = "duration"
        nbad = bad_total = 0
        tick = 0
        wall0 = time.perf_counter()
        prev_ns = time.perf_counter_ns()
        check_dt = check_every * self.dt_s
        x = x_prev
        try:
            for tick in range(1, n + 1):
                # (1) read and validate: the renderer's safety path (renderer.safety)
                x = state.position_m
                bad = False
                if state.status & STATUS_DISCONNECTED:
                    reason = "disconnected"
                    break
                if state.status & STATUS_SENSOR_INVALID or not (-plim <= x <= plim) \
                        or not (-alim <= state.accel_m_s2 <= alim):
                    bad = True
                    x = x_prev  # NaN or implausible: hold the last good value
                if bad:
                    nbad += 1
                    bad_total += 1
                    if nbad >= max_bad:
                        reason = "sensor"
                        break
                else:
                    nbad = 0
                v += alpha * ((x - x_prev) * inv_dt - v)
                x_prev = x
                if armed:
                    if x < surface:
                        contacts += 1
                        armed = False
                elif x > armed_level:
                    armed = True
                # (2) the homing law, (3) saturated at the thermally safe continuous current
                i = (kp * (home - x) - kd * v) * inv_fpa
                if i > imax:
                    i = imax
                elif i < -imax:
                    i = -imax
                elif i != i:
                    i = 0.0
                temp += (heat * i * i - temp) * t_alpha
                # (4) command
                dev.command(i)
                state = dev.read()
                if wd_ns is not None:  # hardware: a stalled loop must not leave a current on
                    now_ns = time.perf_counter_ns()
                    if now_ns - prev_ns > wd_ns:
                        reason = "watchdog"
                        break
                    prev_ns = now_ns
                if tick % check_every == 0:
                    if until is not None and until():
                        reason = "until"
                        break
                    if realtime:
                        ahead = tick * self.dt_s - (time.perf_counter() - wall0)
                        if ahead > 0:
                            time.sleep(min(ahead, check_dt))
                    prev_ns = time.perf_counter_ns()  # the pause above is not a stall
                if until_settled and tick >= n_min and abs(x - home) < tol and abs(v) < vtol:
                    settled = True
                    reason = "settled"
                    break
        except BaseException:
            dev.command(0.0)
            self.temp_rise_K = temp
            raise
        self.temp_rise_K = temp
        if zero_at_end or reason in ("sensor", "disconnected", "watchdog"):
            dev.command(0.0)
        if reason in ("sensor", "disconnected", "watchdog"):
            return HomingResult(duration_s=tick * self.dt_s, ticks=tick, settled=False, contacts=contacts,
                                final_position_m=x, stop_reason=reason, bad_samples=bad_total, temp_rise_K=temp)
        x = state.position_m if -plim <= state.position_m <= plim else x
        if not settled:
            settled = abs(x - home) < tol and abs(v) < vtol
        return HomingResult(duration_s=tick * self.dt_s, ticks=tick, settled=settled, contacts=contacts,
                            final_position_m=x, stop_reason=reason, bad_samples=bad_total, temp_rise_K=temp)
