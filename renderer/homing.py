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

A PD whose gains are too high for the device (sampling, the velocity filter's lag and the amplifier's
delay make it active) oscillates at the current limit, and one whose motor or encoder sign is reversed
runs away from home; both are stopped with zero current (docs/study.md, "Homing controller"):

* ``"unstable"``: a passivity observer on the PD, like the wall's (:mod:`renderer.passivity`, Hannaford
  & Ryu 2002), sums every tick the work the force commanded over the last period did on the handle
  plus the change of the energy the PD's saturated spring stores, with a leak of time constant
  ``instability_window_s``, never below zero (energy the damping dissipated earlier is no credit for
  energy generated later)::

      E <- max(0, exp(-T / window) E + F_{k-1} (x_k - x_{k-1}) + U(x_k) - U(x_{k-1}))

  ``U`` is the potential of ``clamp(kp (x_home - x), +-F_max)``. A PD that behaves like a spring and
  a damper keeps ``E`` near zero whatever the hand does (the hand's work is not counted: it moves
  ``x`` and ``U`` together); a limit cycle at the current limit generates energy every cycle. The
  limit is ``instability_energy_frac * (F_max^2 / (2 kp) + F_max * 1 mm)`` (:func:`renderer.passivity.energy_limit`).
* ``"runaway"``: the observer assumes the commanded force is the force applied, which a reversed
  sign breaks (it then sees a spring). The second check: the handle moved more than
  ``runaway_distance_m`` away from home, faster than ``runaway_speed_m_s`` all the way, while
  homing pushed toward home at its full current. A hand that overpowers homing presses the stylus
  onto the sample, at most the home height plus a few millimetres into it, far below the default 50 mm.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass

import numpy as np

from plumbing.validation import require_number, require_positive

from . import law_layout as LL
from . import sim_aot
from .passivity import PassivityObserver, energy_limit, wall_energy
from .safety import SafetyPath, safety_bounds, zero_on_error


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
    instability_window_s : float
        Leak time constant (s) of the PD's passivity observer (module doc).
    instability_energy_frac : float
        Stop (``"unstable"``) once the observed energy exceeds this fraction of
        :func:`renderer.passivity.energy_limit`'s scale; inf turns the check off.
    runaway_distance_m : float
        Stop (``"runaway"``) once the handle moved this far (m) away from home at more than
        ``runaway_speed_m_s`` while homing pushed toward home at its current limit; inf turns it off.
    runaway_speed_m_s : float
        Speed (m/s) above which motion away from home counts toward ``runaway_distance_m``.
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
    instability_window_s: float = 1.0
    instability_energy_frac: float = 1.0
    runaway_distance_m: float = 0.05
    runaway_speed_m_s: float = 0.02

    def __post_init__(self) -> None:
        require_positive(self, "home_height_m", "kp_N_m", "velocity_cutoff_hz", "settle_tolerance_m",
                         "settle_speed_m_s", "rearm_margin_m", "contact_tolerance_m", "instability_window_s",
                         prefix="homing.")
        for key in ("instability_energy_frac", "runaway_distance_m", "runaway_speed_m_s"):
            value = getattr(self, key)
            if value != math.inf:  # inf: that check off
                require_number(key, value, minimum=0.0, strict=True, prefix="homing.")
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
    stop_reason: str = "duration"  # duration | settled | until | sensor | disconnected | watchdog | unstable | runaway
    bad_samples: int = 0          # implausible sensor samples held (renderer.safety)
    temp_rise_K: float = 0.0      # winding temperature rise at the end (K)
    peak_energy_J: float = 0.0    # largest energy the PD's passivity observer saw (J; module doc)
    energy_limit_J: float = math.inf  # its stop threshold (J)
    max_runaway_m: float = 0.0    # longest run away from home under full current toward it (m; module doc)
    message: str = ""             # why a safety stop happened, and what to change (empty otherwise)


#: stop reasons after which the output was zeroed for safety (the owner should end its session)
SAFETY_STOPS = ("sensor", "disconnected", "watchdog", "unstable", "runaway")

_HOME_UNTIL = -1    # the compiled path's code for "until() returned True" (checked in Python)
#: stop reason of each return code of the compiled loop (renderer.law.run_homing); HOME_RAN: its ticks ran out
_HOME_REASONS = {LL.HOME_DISCONNECTED: "disconnected", LL.HOME_SENSOR: "sensor", LL.HOME_UNSTABLE: "unstable",
                 LL.HOME_RUNAWAY: "runaway", LL.HOME_SETTLED: "settled", _HOME_UNTIL: "until"}


def _unstable_message(observer, cfg, kp: float, kd: float) -> str:
    """Why homing stopped as unstable, and what to change."""
    return (f"homing generated {observer.energy_J * 1e3:.3g} mJ net over the last "
            f"~{cfg.instability_window_s:g} s (limit {observer.limit_J * 1e3:.3g} mJ) at "
            f"kp_N_m={kp:g}, kd_N_s_m={kd:g}: the homing PD oscillates on this device; "
            "output zeroed. Lower homing kp_N_m or kd_N_s_m (a study protocol's "
            "homing_kp_N_m, homing_kd_N_s_m; docs/study.md, 'Homing controller')")


def _runaway_message(away: float, v: float, err: float, imax: float, kp: float, kd: float) -> str:
    """Why homing stopped as a run-away, and what to check."""
    return (f"the handle ran {away * 1e3:.0f} mm away from home (at {abs(v):.2f} m/s, "
            f"now {abs(err) * 1e3:.0f} mm from it) while homing pushed toward home at "
            f"its current limit {imax:g} A (kp_N_m={kp:g}, kd_N_s_m={kd:g}): the motor's "
            "or the encoder's sign is probably reversed; output zeroed. Check the "
            "device's calibration and wiring (docs/study.md, 'Homing controller')")


class HomingController:
    """Saturated PD homing through the Device API (see module doc)."""

    def __init__(self, device, config: HomingConfig | None = None, surface_height_m: float = 0.0,
                 safety_config=None) -> None:
        """``safety_config``: the :class:`renderer.RendererConfig` whose safety settings (the watchdog's
        ``watchdog_overrun_s``, position and sensor limits) homing shares with the servo loops it sits
        between (default: the renderer's defaults)."""
        self.device = device
        self.config = config or HomingConfig()
        info = device.info
        self.force_per_amp_N_A = info.force_per_amp_N_A
        limit = self.config.max_current_A if self.config.max_current_A is not None else info.current_continuous_A
        self.dt_s = 1.0 / info.servo_rate_hz
        self.bounds = safety_bounds(info, info.servo_rate_hz, safety_config, continuous_A=limit)
        self.max_current_A = self.bounds.continuous_safe_A
        self.temp_rise_K = 0.0  # winding temperature rise (K); the owner sets and reads it between calls
        self.surface_height_m = surface_height_m
        wc = 2.0 * math.pi * self.config.velocity_cutoff_hz * self.dt_s
        self._alpha = wc / (1.0 + wc)
        self.force_limit_N = self.max_current_A * abs(self.force_per_amp_N_A)
        self.energy_limit_J = energy_limit(self.config.kp_N_m, self.force_limit_N,
                                           float(self.config.instability_energy_frac))
        # a device on the wall clock (hardware that is not lockstep) is paced here every tick, as the servo loop
        # paces it: a driver whose read() returns the newest sample without waiting for the next one (a vendor
        # library's servo thread, the Touch) would otherwise run a burst of ticks, then hold one force through
        # the pause at the next check, and the PD oscillates (measured: homing stopped as unstable in 0.2 s)
        self.pace_ticks = not info.on_device_clock

    def _compiled_loop(self):
        """The compiled homing loop (``renderer.law.run_homing``: the ahead-of-time build's when there is one,
        else numba's JIT) if the device is exactly a :class:`devices.sim.SimDevice` whose physics step is its
        own (``devices.sim.kernel.tick``, JIT or ahead of time), which that loop reproduces tick for tick;
        else None (the Python loop: any other device)."""
        dev = self.device
        sim = sys.modules.get("devices.sim.device")
        if sim is None or type(dev) is not sim.SimDevice:
            return None
        module = sim_aot.load()
        step = dev._tick_fn
        if step is not None:
            kernel = sys.modules.get("devices.sim.kernel")
            if not ((kernel is not None and step is kernel.tick)
                    or (module is not None and step is getattr(module, "tick", None))):
                return None
        fn = getattr(module, "run_homing", None) if module is not None else None
        return fn if fn is not None else sim_aot.jit_laws().law.run_homing

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
        plim = b.position_limit_m
        temp = float(self.temp_rise_K)
        fmax = self.force_limit_N
        fpa = self.force_per_amp_N_A
        run_dist, run_speed = cfg.runaway_distance_m, cfg.runaway_speed_m_s
        state = dev.read()
        x_prev = state.position_m
        if not (-plim <= x_prev <= plim):
            x_prev = home  # no plausible first sample: assume home (no velocity kick)
        # the passivity observer (module doc): leak, limit; the PD's saturated spring stores what a wall of
        # stiffness kp clamped at fmax stores (two-sided)
        observer = PassivityObserver(math.exp(-self.dt_s / cfg.instability_window_s), self.energy_limit_J,
                                     wall_energy(kp, fmax, abs(home - x_prev), 1.0))
        f_prev = 0.0  # force commanded over the last period (N)
        away = away_max = 0.0  # distance run away from home under full current toward it (m)
        message = ""
        v = 0.0
        armed = x_prev > armed_level
        contacts = 0
        settled = False
        reason = "duration"
        tick = 0
        wall0 = time.perf_counter()
        check_dt = check_every * self.dt_s
        dt_s, pace_ticks = self.dt_s, self.pace_ticks
        x = x_prev
        # the renderer's safety path (renderer.safety): sensor plausibility, current limit, winding heat,
        # watchdog, and zero output when anything raises
        safety = SafetyPath(b, imax)
        fast = (self._compiled_loop() if (not pace_ticks and b.watchdog_period_ns is None and check_every >= 1)
                else None)
        try:
            with zero_on_error(dev):
                if fast is not None:
                    # the same ticks in compiled chunks (renderer.law.run_homing): between them until() and the
                    # realtime pause at its checks, and the hand's plan's next window (SimDevice.fused_span)
                    h = np.zeros(LL.N_HOMING)
                    for key, value in ((LL.H_HOME, home), (LL.H_SURFACE, surface), (LL.H_ARMED_LEVEL, armed_level),
                                       (LL.H_KP, kp), (LL.H_KD, kd), (LL.H_INV_FPA, inv_fpa), (LL.H_IMAX, imax),
                                       (LL.H_ALPHA, alpha), (LL.H_INV_DT, inv_dt), (LL.H_N, n), (LL.H_NMIN, n_min),
                                       (LL.H_TOL, tol), (LL.H_VTOL, vtol), (LL.H_PLIM, plim),
                                       (LL.H_ALIM, b.accel_limit_m_s2), (LL.H_MAX_BAD, b.max_bad_samples),
                                       (LL.H_FMAX, fmax), (LL.H_FPA, fpa), (LL.H_RUN_DIST, run_dist),
                                       (LL.H_RUN_SPEED, run_speed), (LL.H_DECAY, observer.decay),
                                       (LL.H_ELIMIT, observer.limit_J), (LL.H_HEAT, b.heat_K_A2),
                                       (LL.H_THERM_ALPHA, b.alpha), (LL.H_UNTIL_SETTLED, 1.0 if until_settled else 0.0),
                                       (LL.H_CHECK_EVERY, check_every if (until is not None or realtime) else 0),
                                       (LL.H_X_PREV, x_prev), (LL.H_X, x), (LL.H_ARMED, 1.0 if armed else 0.0),
                                       (LL.H_TEMP, temp), (LL.H_STORED, observer._stored_J)):
                        h[key] = value
                    code = LL.HOME_RAN
                    while int(h[LL.H_TICK]) < n:
                        arrays = dev.fused_arrays()     # (the next window of the plan when this one is used up)
                        span = dev.fused_span()
                        dv = dev.fused_state()
                        try:
                            code = fast(h, dv, *arrays, min(n - int(h[LL.H_TICK]), span))
                        finally:
                            dev.fused_sync(dv)
                        if code == LL.HOME_CHECK:
                            tick = int(h[LL.H_TICK])
                            if until is not None and until():
                                code = _HOME_UNTIL
                                break
                            if realtime:
                                ahead = tick * self.dt_s - (time.perf_counter() - wall0)
                                if ahead > 0:
                                    time.sleep(min(ahead, check_dt))
                            if until_settled and tick >= n_min and abs(h[LL.H_X] - home) < tol \
                                    and abs(h[LL.H_V]) < vtol:
                                code = LL.HOME_SETTLED
                                break
                        elif code != LL.HOME_RAN:
                            break
                    tick, x, v = int(h[LL.H_TICK]), float(h[LL.H_X]), float(h[LL.H_V])
                    contacts, away_max, temp = int(h[LL.H_CONTACTS]), float(h[LL.H_AWAY_MAX]), float(h[LL.H_TEMP])
                    observer.energy_J, observer.peak_J = float(h[LL.H_E]), float(h[LL.H_PEAK])
                    observer._stored_J = float(h[LL.H_STORED])
                    safety.bad_in_row, safety.bad_total = int(h[LL.H_BAD_ROW]), int(h[LL.H_BAD_TOTAL])
                    reason = _HOME_REASONS.get(code, "duration")
                    settled = reason == "settled"
                    err, away, dx = float(h[LL.H_ERR]), float(h[LL.H_AWAY]), float(h[LL.H_DX])
                    if reason == "disconnected":
                        message = str(state.extra.get("error") or "") if hasattr(state, "extra") else ""
                    elif reason == "unstable":
                        message = _unstable_message(observer, cfg, kp, kd)
                    elif reason == "runaway":
                        message = _runaway_message(away, v, err, imax, kp, kd)
                for tick in (() if fast is not None else range(1, n + 1)):
                    # (1) read and validate
                    x, stop = safety.sample(state, x_prev)
                    if stop is not None:
                        reason = stop
                        if stop == "disconnected":
                            # the driver's own words (a lost link, a device fault), as the servo loop reports them
                            message = str(state.extra.get("error") or "") if hasattr(state, "extra") else ""
                        break
                    dx = x - x_prev
                    v += alpha * (dx * inv_dt - v)
                    x_prev = x
                    # passivity observer: work of the force held over the last period + change of stored energy
                    err = home - x
                    if observer.update(f_prev, dx, wall_energy(kp, fmax, abs(err), 1.0)):
                        reason = "unstable"
                        message = _unstable_message(observer, cfg, kp, kd)
                        break
                    if armed:
                        if x < surface:
                            contacts += 1
                            armed = False
                    elif x > armed_level:
                        armed = True
                    # (2) the homing law, (3) saturated at the thermally safe continuous current
                    i = safety.current((kp * (home - x) - kd * v) * inv_fpa)
                    # run-away: moving away from home, fast, while homing pushes toward it at full current
                    if (i == imax if err > 0.0 else i == -imax) and v * err < 0.0 and abs(v) > run_speed:
                        away += abs(dx)
                        if away > away_max:
                            away_max = away
                        if away > run_dist:
                            reason = "runaway"
                            message = _runaway_message(away, v, err, imax, kp, kd)
                            break
                    else:
                        away = 0.0
                    f_prev = i * fpa
                    temp = safety.heat(temp, i)
                    # (4) command
                    dev.command(i)
                    state = dev.read()
                    if pace_ticks:   # to this tick's deadline (a blocking read has mostly waited already)
                        ahead = tick * dt_s - (time.perf_counter() - wall0)
                        if ahead > 0:
                            time.sleep(ahead)
                    if safety.watchdog():  # hardware: a stalled loop must not leave a current on
                        reason = "watchdog"
                        break
                    if tick % check_every == 0:
                        if until is not None and until():
                            reason = "until"
                            break
                        if realtime:
                            ahead = tick * self.dt_s - (time.perf_counter() - wall0)
                            if ahead > 0:
                                time.sleep(min(ahead, check_dt))
                        safety.pause_watchdog()  # the pause above is not a stall
                    if until_settled and tick >= n_min and abs(x - home) < tol and abs(v) < vtol:
                        settled = True
                        reason = "settled"
                        break
        finally:
            self.temp_rise_K = temp
        if zero_at_end or reason in SAFETY_STOPS:
            dev.command(0.0)
        common = dict(duration_s=tick * self.dt_s, ticks=tick, contacts=contacts, stop_reason=reason,
                      bad_samples=safety.bad_total, temp_rise_K=temp, peak_energy_J=observer.peak_J,
                      energy_limit_J=observer.limit_J,
                      max_runaway_m=away_max)
        if reason in SAFETY_STOPS:
            if not message:
                message = {"sensor": f"{safety.bad_in_row} implausible sensor samples in a row",
                           "disconnected": "the device reported a disconnect",
                           "watchdog": "a servo period beyond the watchdog bound"}[reason] + "; output zeroed"
            elif reason == "disconnected" and "output zeroed" not in message:
                message += "; output zeroed"
            return HomingResult(settled=False, final_position_m=x, message=message, **common)
        x = state.position_m if -plim <= state.position_m <= plim else x
        if not settled:
            settled = abs(x - home) < tol and abs(v) < vtol
        return HomingResult(settled=settled, final_position_m=x, **common)
