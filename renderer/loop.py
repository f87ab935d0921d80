"""The haptic servo loop: proportional feedback plus event-based transient overlay (thesis Fig. 4.9).

One tick (rate ``fs``, period ``dt``):

1. ``state = device.read()``; validate the sensors (NaN/inf/out of range:
   hold the last good value, flag it, stop after ``max_bad_samples`` in a row).
2. Velocity: O(1) sliding least-squares slope of the position (renderer.velocity).
3. Transient channel: next sample of the playing transient (it starts on the
   tick *after* the crossing: sample ``k`` plays at ``t = (k + 1) dt`` after contact).
4. Collision detection of the proxy against the scene: signed depth ``d``, normal ``n``.
5. Contact events: if armed and ``d > 0`` an impact fires: incoming velocity
   (least squares over ``impact_window_s`` ending now), grip sampled now, the
   transient waveform is written into a preallocated buffer. The latch re-arms
   only when the transient has finished *and* ``d < -rearm_margin_m``.
6. Proportional channel ``F_p = k d n_z`` (eq. 2.1) while ``d > 0``, minus
   ``b v`` while entering (section 2.2.2).
7. Force to current with ``i = F / (rho k_t / h)`` (eq. 3.17); separate
   saturation (section 4.4.2): proportional to the continuous limit, transient
   to the peak limit, the sum to the amplifier limit; clip bits 1/2/4.
8. Winding thermal model (renderer.thermal) attenuates, then ends, transients.
9. ``device.command(i)``; then the tick is logged into preallocated buffers.

The tick is plain scalar Python on local variables; nothing is allocated
per tick except Python floats. The output is zeroed on every exit path.
"""

from __future__ import annotations

import array
import csv
import ctypes
import dataclasses
import json
import math
import os
import pathlib
import time
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Callable

import numpy as np

from devices import provenance

from .config import RendererConfig
from .safety import safety_bounds
from .thermal import safe_continuous_current
from .velocity import ImpactVelocityEstimator, ls_constants

# name, array typecode, numpy dtype, description (documented in docs/renderer.md)
LOG_CHANNELS: tuple[tuple[str, str, str, str], ...] = (
    ("t_s", "d", "f8", "device time of the sample (s)"),
    ("position_m", "d", "f8", "validated handle position, + up (m)"),
    ("velocity_m_s", "d", "f8", "sliding least-squares velocity estimate (m/s)"),
    ("penetration_m", "d", "f8", "signed penetration depth, + inside (m)"),
    ("force_prop_N", "d", "f8", "proportional(+damping) force before saturation (N)"),
    ("force_transient_N", "d", "f8", "transient force after thermal attenuation, before saturation (N)"),
    ("current_A", "d", "f8", "commanded current after saturation (A)"),
    ("clipped", "B", "u1", "bit 1 proportional, 2 transient, 4 amplifier limit hit"),
    ("accel_m_s2", "d", "f8", "measured handle acceleration (m/s^2)"),
    ("grip_N", "d", "f8", "measured grip force (N)"),
    ("temp_rise_K", "d", "f8", "modelled winding temperature rise (K)"),
    ("sensor_flags", "B", "u1", "bit 1 position, 2 accel, 4 grip invalid (held), 8 device SENSOR_INVALID"),
    ("wall_ns", "q", "i8", "wall-clock time after read(), ns since the run started"),
    ("compute_ns", "q", "i8", "controller compute time read() -> command() (ns)"),
)

CLIP_PROPORTIONAL, CLIP_TRANSIENT, CLIP_AMPLIFIER = 1, 2, 4
_STATUS_SENSOR_INVALID, _STATUS_DISCONNECTED = 16, 32

EVENT_COLUMNS = ("t_s", "incoming_velocity_m_s", "grip_N", "max_penetration_m", "peak_accel_m_s2",
                 "transient", "clipped", "tick", "transient_samples", "thermal_gain")


@dataclass
class ContactEvent:
    """One contact (impact) event; statistics cover the crossing tick until the latch re-arms.

    Attributes
    ----------
    t_s : float
        Device time of the crossing tick (s).
    incoming_velocity_m_s : float
        Speed into the surface at the crossing (m/s, >= 0).
    grip_N : float
        Grip force sampled on the crossing tick (N).
    max_penetration_m, peak_accel_m_s2 : float
        Maximum depth and maximum |acceleration| during the event.
    transient : str
        Name of the transient played ("none" if none).
    clipped : bool
        True if the amplifier limit was hit during the event.
    tick : int
        Loop tick of the crossing (-1 if unknown, e.g. on-device events).
    transient_samples : int
        Length of the transient written for this event.
    thermal_gain : float
        Thermal attenuation factor at the crossing (1 = none).
    """

    t_s: float
    incoming_velocity_m_s: float
    grip_N: float
    max_penetration_m: float = 0.0
    peak_accel_m_s2: float = 0.0
    transient: str = "none"
    clipped: bool = False
    tick: int = -1
    transient_samples: int = 0
    thermal_gain: float = 1.0

    @classmethod
    def from_dict(cls, data: dict) -> "ContactEvent":
        """Build from a dict with ContactEvent keys (e.g. ``device.pop_events()``); unknown keys ignored."""
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in names})


@dataclass
class RunResult:
    """Outcome of :meth:`ServoLoop.run`.

    Attributes
    ----------
    events : list of ContactEvent
    log : dict of str -> ndarray
        Full-rate arrays (see ``LOG_CHANNELS``), trimmed to the ticks logged
        (the last ``log_capacity_s`` if the run was longer).
    timing : dict
        The ``run.json`` timing fields.
    stop_reason : str
        "duration", "until", "stopped" (request_stop), "watchdog", "sensor", "disconnected",
        "exception", "interrupted".
    config, device, transient : run metadata for ``run.json``.
    """

    events: list
    log: dict
    timing: dict
    stop_reason: str = "duration"
    config: dict = field(default_factory=dict)
    device: dict = field(default_factory=dict)
    transient: str = "none"
    error: str = ""

    def save(self, out_dir: str | os.PathLike) -> pathlib.Path:
        """Write ``events.csv``, ``run.json`` and ``log.npz`` into ``out_dir`` (created if needed).

        Each file is written to a temporary name and renamed, so an existing
        file is never left half-written.
        """
        out = pathlib.Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        tmp = out / "events.csv.tmp"
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh)
            writer.writerow(EVENT_COLUMNS)
            for ev in self.events:
                row = []
                for name in EVENT_COLUMNS:
                    value = getattr(ev, name)
                    if isinstance(value, (bool, np.bool_)):
                        row.append("true" if value else "false")
                    elif isinstance(value, (float, np.floating)):
                        row.append(repr(float(value)))
                    elif isinstance(value, np.integer):
                        row.append(int(value))
                    else:
                        row.append(value)
                writer.writerow(row)
        os.replace(tmp, out / "events.csv")
        tmp = out / "log.tmp.npz"
        np.savez(tmp, **self.log)
        os.replace(tmp, out / "log.npz")
        run = dict(self.timing)
        run.update(stop_reason=self.stop_reason, error=self.error, events=len(self.events),
                   transient=self.transient, device=self.device, config=self.config,
                   software_version=provenance.software_versions())
        tmp = out / "run.json.tmp"
        tmp.write_text(json.dumps(run, indent=2, default=_json_default) + "\n", encoding="utf-8")
        os.replace(tmp, out / "run.json")
        return out

    @classmethod
    def load(cls, out_dir: str | os.PathLike) -> "RunResult":
        """Read back a directory written by :meth:`save`."""
        out = pathlib.Path(out_dir)
        run = json.loads((out / "run.json").read_text(encoding="utf-8"))
        with np.load(out / "log.npz") as data:
            log = {k: data[k] for k in data.files}
        events = []
        with open(out / "events.csv", newline="", encoding="utf-8") as fh:
            for row in csv.DictReader(fh):
                events.append(ContactEvent(
                    t_s=float(row["t_s"]), incoming_velocity_m_s=float(row["incoming_velocity_m_s"]),
                    grip_N=float(row["grip_N"]), max_penetration_m=float(row["max_penetration_m"]),
                    peak_accel_m_s2=float(row["peak_accel_m_s2"]), transient=row["transient"],
                    clipped=row["clipped"] == "true", tick=int(row.get("tick") or -1),
                    transient_samples=int(row.get("transient_samples") or 0),
                    thermal_gain=float(row.get("thermal_gain") or 1.0)))
        meta = {k: run.pop(k) for k in ("stop_reason", "error", "events", "transient", "device", "config") if k in run}
        return cls(events=events, log=log, timing=run, stop_reason=meta.get("stop_reason", ""),
                   config=meta.get("config", {}), device=meta.get("device", {}),
                   transient=meta.get("transient", "none"), error=meta.get("error", ""))


def _json_default(obj):
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, tuple):
        return list(obj)
    return str(obj)


def transient_name(transient) -> str:
    """The transient's ``name`` ("none" for None)."""
    if transient is None:
        return "none"
    return str(getattr(transient, "name", type(transient).__name__))


def _set_timer_slack_ns(ns: int) -> int | None:
    """Set this thread's timer slack (Linux prctl) so short sleeps wake on time; returns the old value."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        old = libc.prctl(30, 0, 0, 0, 0)  # PR_GET_TIMERSLACK
        if old < 0 or libc.prctl(29, ctypes.c_ulong(ns), 0, 0, 0) != 0:  # PR_SET_TIMERSLACK
            return None
        return int(old)
    except (OSError, AttributeError):
        return None


class ServoLoop:
    """Servo loop rendering a scene on a 1-DOF device (see the module doc for one tick).

    Parameters
    ----------
    device : devices.base.Device
        Opened on demand (never closed here). Sim devices advance one servo
        period per ``command()``.
    cfg : RendererConfig, optional
    transient : object or None
        Duck-typed stimuli transient: ``waveform(v_in_m_s, grip_N, fs_hz)`` (force N,
        sample k at t=(k+1)/fs), ``max_samples(fs_hz)``, ``check_device(info, fs_hz)``,
        ``name``; optionally ``current_into(v_in_m_s, grip_N, out) -> n`` (A, no allocation).

    Attributes readable from an ``until`` callback: ``ticks``, ``time_s``
    (device time), ``events``, ``temp_rise_K``; ``result`` holds the last
    RunResult (also a partial one after an exception or Ctrl-C).
    """

    def __init__(self, device, cfg: RendererConfig | None = None, transient=None):
        self.device = device
        self.cfg = cfg if cfg is not None else RendererConfig()
        if not isinstance(self.cfg, RendererConfig):
            raise ValueError(f"cfg must be a RendererConfig, got {type(self.cfg).__name__}")
        self.transient = transient
        self.events: list[ContactEvent] = []
        self.ticks = 0
        self.time_s = 0.0
        self.temp_rise_K = self.cfg.initial_temp_rise_K
        self.result: RunResult | None = None
        self.stop_requested = False
        self._prepared = False

    # ------------------------------------------------------------------ set-up
    def prepare(self) -> None:
        """Validate device, limits, rate and transient; allocate buffers. Raises ValueError before any motion."""
        cfg, dev = self.cfg, self.device
        info = dev.info
        self.info = info
        fs = float(cfg.rate_hz) if cfg.rate_hz is not None else float(info.servo_rate_hz)
        if info.simulated and abs(fs - info.servo_rate_hz) > 1e-9 * fs:
            raise ValueError(f"rate_hz={fs:g} differs from the sim device's servo_rate_hz={info.servo_rate_hz:g}; "
                             "a sim device advances 1/servo_rate_hz per command, so create it with that rate")
        self.fs_hz = fs
        self.dt_s = 1.0 / fs
        limits = {}
        for key in ("current_continuous_A", "current_peak_A", "current_amplifier_A"):
            dev_value = getattr(info, key)
            value = getattr(cfg, key)
            if value is None:
                value = dev_value
            elif value > dev_value:
                raise ValueError(f"{key}={value} exceeds the device's {key}={dev_value}")
            limits[key] = float(value)
        ic, ipk, iamp = limits["current_continuous_A"], limits["current_peak_A"], limits["current_amplifier_A"]
        if not ic <= ipk <= iamp:
            raise ValueError(f"current limits must satisfy continuous <= peak <= amplifier, got {ic}, {ipk}, {iamp}")
        self.limits = {"continuous_A": ic, "peak_A": ipk, "amplifier_A": iamp}
        # the proportional channel alone must never be able to overheat the winding
        self.continuous_safe_A = safe_continuous_current(info, ic)
        self.force_per_amp = info.force_per_amp_N_A
        self.scene = cfg.effective_scene
        self.on_device = bool(getattr(dev, "on_device_rendering", False)) and "on_device" in info.capabilities
        self.nbuf = max(1, int(math.ceil(cfg.max_transient_s * fs - 1e-9)))
        tr = self.transient
        self.transient_name = transient_name(tr)
        if tr is not None:
            for attr in ("waveform", "max_samples", "check_device"):
                if not callable(getattr(tr, attr, None)):
                    raise ValueError(f"transient {self.transient_name!r} has no {attr}() method")
            tr.check_device(info, fs)
            need = int(tr.max_samples(fs))
            if need > self.nbuf:
                raise ValueError(f"transient {self.transient_name!r} needs up to {need} samples "
                                 f"({need / fs:.3f} s) at {fs:g} Hz but the buffer holds {self.nbuf} "
                                 f"(max_transient_s={cfg.max_transient_s}); raise max_transient_s")
        if self.on_device and self.scene.single_wall is None:
            raise ValueError("on-device rendering supports only a single horizontal wall scene")
        self.tbuf = array.array("d", bytes(8 * self.nbuf))
        self.tview = np.frombuffer(self.tbuf, dtype=np.float64)
        self.w_vel = max(2, int(round(cfg.velocity_window_s * fs)))
        self.impact_velocity = ImpactVelocityEstimator(self.dt_s, info.position_resolution_m,
                                                       cfg.impact_min_window_s, cfg.impact_window_s,
                                                       cfg.impact_counts)
        self._prepared = True

    def request_stop(self) -> None:
        """Ask a running loop (e.g. from a UI thread) to stop within ``cfg.until_every`` ticks."""
        self.stop_requested = True

    def _stop_check(self, until) -> str:
        """Stop reason from a stop request or the caller's ``until`` predicate, else ""; polled every
        ``until_every`` ticks (not per tick) by both loops."""
        if self.stop_requested:
            return "stopped"
        if until is not None and until(self):
            return "until"
        return ""

    def _alloc_log(self, capacity: int) -> dict:
        # repetition writes every page now, so the loop never takes a first-touch page fault
        return {name: array.array(code, [0.0 if code == "d" else 0]) * capacity for name, code, _, _ in LOG_CHANNELS}

    def _fill_transient(self, v_in: float, grip: float, gain: float) -> int:
        """Write the event's transient current (A) into the buffer; returns its length (event time, not per tick)."""
        tr = self.transient
        if tr is None or gain <= 0.0 or not self.cfg.motor_enabled:
            return 0
        view = self.tview
        into = getattr(tr, "current_into", None)
        if callable(into):
            n = int(into(v_in, grip, view))
            n = min(n, self.nbuf)
            if gain != 1.0:
                view[:n] *= gain
        else:
            w = np.asarray(tr.waveform(v_in, grip, self.fs_hz), dtype=np.float64)
            n = min(len(w), self.nbuf)
            np.multiply(w[:n], gain / self.force_per_amp, out=view[:n])
        total = float(view[:n].sum()) if n else 0.0
        if total != total or total in (math.inf, -math.inf):  # cheap test: NaN/inf make the sum non-finite
            np.nan_to_num(view[:n], copy=False, nan=0.0, posinf=0.0, neginf=0.0)
            self.bad_transients += 1
        return n

    # ------------------------------------------------------------------ run
    def run(self, duration_s: float | None = None, until: Callable[["ServoLoop"], bool] | None = None,
            realtime: bool | None = None, max_ticks: int | None = None) -> RunResult:
        """Run the loop; returns a :class:`RunResult` (also stored in ``self.result``).

        Parameters
        ----------
        duration_s : float, optional
            Stop after ``round(duration_s * rate)`` ticks.
        until : callable(loop) -> bool, optional
            Stop when it returns True; evaluated every ``cfg.until_every`` ticks.
        realtime : bool, optional
            Pace ticks to wall-clock time. Default: False for simulated
            devices (as fast as possible), True for hardware.
        max_ticks : int, optional
            Hard cap on ticks.

        Without any stop condition the loop runs until Ctrl-C. The device is
        commanded to zero on every exit path; exceptions (including
        KeyboardInterrupt) propagate after zeroing, with the partial result in
        ``self.result``.
        """
        if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
            raise ValueError(f"duration_s must be > 0, got {duration_s!r}")
        self.prepare()
        dev = self.device
        if not dev.is_open:
            dev.open()
        if realtime is None:
            realtime = not self.info.simulated
        limit = math.inf
        if duration_s is not None:
            limit = int(round(duration_s * self.fs_hz))
        if max_ticks is not None:
            limit = min(limit, int(max_ticks))
        cap_ticks = max(1, int(round(self.cfg.log_capacity_s * self.fs_hz)))
        if limit != math.inf:
            cap_ticks = max(1, min(cap_ticks, int(limit)))
        self.events = []
        self.bad_transients = 0
        self.stop_requested = False
        self._log = self._alloc_log(cap_ticks)
        self._cap = cap_ticks
        self._stats = {"stop_reason": "exception", "n_logged": 0, "wrapped": False, "ticks": 0,
                       "overruns": 0, "bad_samples": 0, "error": ""}
        old_slack = _set_timer_slack_ns(1000) if realtime and self.cfg.pacing == "sleep_spin" else None
        wall0 = time.perf_counter()
        cpu0 = time.process_time()
        try:
            try:
                if self.on_device:
                    self._loop_on_device(limit, until)
                else:
                    self._loop(limit, until, bool(realtime))
            except BaseException as exc:
                self._stats["stop_reason"] = "interrupted" if isinstance(exc, KeyboardInterrupt) else "exception"
                self._stats["error"] = f"{type(exc).__name__}: {exc}"
                raise
            finally:
                try:
                    dev.zero()
                finally:
                    if self.on_device:
                        try:
                            dev.stop_rendering()
                        except Exception:
                            pass
        finally:
            # measured from the first tick (after the priming cycle) when the loop got that far
            wall = (time.perf_counter_ns() - self._stats["t0_ns"]) * 1e-9 if "t0_ns" in self._stats \
                else time.perf_counter() - wall0
            cpu = time.process_time() - self._stats.get("cpu0", cpu0)
            if old_slack is not None:
                _set_timer_slack_ns(old_slack)
            self.result = self._build_result(wall, cpu, bool(realtime))
        return self.result

    def _tick_constants(self, realtime: bool) -> SimpleNamespace:
        """Everything the tick reads but never changes: gains, limits, thermal and sensor bounds, buffers, timing.

        Returns
        -------
        SimpleNamespace
            Unpacked into locals by :meth:`_loop` (a local is the cheapest lookup in CPython).
        """
        cfg, info = self.cfg, self.info
        fs, dt = self.fs_hz, self.dt_s
        c = SimpleNamespace()
        # the wall law (proportional + damping, re-arm hysteresis) and the transient channel
        c.k = float(cfg.stiffness_N_m)
        c.damp = float(cfg.damping_N_s_m)
        c.margin = float(cfg.rearm_margin_m)
        c.hold_n = max(1, int(round(cfg.rearm_hold_s * fs)))
        c.kf = self.force_per_amp
        c.inv_kf = 1.0 / c.kf
        c.motor = bool(cfg.motor_enabled)
        c.tgain = float(cfg.transient_gain)
        # saturation (section 4.4.2) and the winding thermal model
        c.ic = self.continuous_safe_A
        c.ipk = self.limits["peak_A"]
        c.iamp = self.limits["amplifier_A"]
        # the safety path shared with every servo law (renderer.safety): thermal model, sensor bounds
        b = safety_bounds(info, fs, cfg)
        c.heat, c.alpha = b.heat_K_A2, b.alpha
        c.t_att, c.t_end = b.t_attenuate_K, b.t_end_K
        c.inv_span = 1.0 / (c.t_end - c.t_att)
        c.plim, c.alim = b.position_limit_m, b.accel_limit_m_s2
        c.gmin, c.gmax = b.grip_min_N, b.grip_max_N
        c.max_bad = b.max_bad_samples
        # the scene
        c.wall = self.scene.single_wall
        c.wall_h = c.wall.height_m if c.wall is not None else 0.0
        c.pen1d = self.scene.penetration_1d
        # velocity estimators (renderer.velocity): a double-written ring (sample i at i and i + nring)
        # so the impact fit reads a contiguous slice
        c.wv = self.w_vel
        c.nring = max(c.wv, self.impact_velocity.history)
        c.pring = array.array("d", bytes(16 * c.nring))
        self.impact_velocity.bind(c.pring)
        c.c_shift, c.c_scale = ls_constants(c.wv, dt)
        # timing: pacing, overrun and watchdog bounds
        c.period_ns = int(round(1e9 / fs))
        c.paced = realtime or not info.simulated
        tol = cfg.overrun_tolerance_s if cfg.overrun_tolerance_s is not None else 0.5 * dt
        c.over_ns = c.period_ns + int(tol * 1e9)
        c.wd_ns = c.period_ns + int(cfg.watchdog_overrun_s * 1e9)
        c.watchdog = not info.simulated  # a stalled simulation endangers nothing: the watchdog guards real motors
        c.spin_ns = int(cfg.spin_margin_s * 1e9)
        c.sleep_spin = cfg.pacing == "sleep_spin"
        c.catchup_ns = int(cfg.max_catchup_s * 1e9)
        c.until_every = int(cfg.until_every)
        return c

    def _loop(self, limit, until, realtime: bool) -> None:
        """The servo loop proper: everything in locals, no attribute lookups or allocation per tick.

        Each tick, in order: pace; (1) read and validate the sensors; (2) estimate the velocity and
        compute the forces (transient sample, collision, contact events, wall law); (3) saturate per
        channel and in sum, step the thermal model; (4) command the motor, then the impact work
        (velocity fit, transient lookup) that must not delay the output; (5) log into the ring and,
        every ``until_every`` ticks, publish progress and honour stop requests.
        """
        st = self._stats
        read, command = self.device.read, self.device.command
        clock, sleep = time.perf_counter_ns, time.sleep
        c = self._tick_constants(realtime)
        # locals for speed: a local costs one lookup per tick, an attribute two
        k, damp, margin, hold_n, kf, inv_kf, motor, tgain = (c.k, c.damp, c.margin, c.hold_n, c.kf, c.inv_kf,
                                                              c.motor, c.tgain)
        ic, ipk, iamp, heat, alpha, t_att, t_end, inv_span = (c.ic, c.ipk, c.iamp, c.heat, c.alpha, c.t_att,
                                                              c.t_end, c.inv_span)
        plim, alim, gmax, gmin, max_bad = c.plim, c.alim, c.gmax, c.gmin, c.max_bad
        wall, wall_h, pen1d = c.wall, c.wall_h, c.pen1d
        wv, nring, pring, c_shift, c_scale = c.wv, c.nring, c.pring, c.c_shift, c.c_scale
        impact_velocity = self.impact_velocity
        period_ns, paced, over_ns, wd_ns, watchdog = c.period_ns, c.paced, c.over_ns, c.wd_ns, c.watchdog
        spin_ns, sleep_spin, catchup_ns, until_every = c.spin_ns, c.sleep_spin, c.catchup_ns, c.until_every
        # transient playback and events
        tbuf, fill, tname, events = self.tbuf, self._fill_transient, self.transient_name, self.events
        tlen = tj = 0
        # log buffers (preallocated ring)
        log, cap = self._log, self._cap
        L_t, L_x, L_v, L_d = log["t_s"], log["position_m"], log["velocity_m_s"], log["penetration_m"]
        L_fp, L_ft, L_i, L_c = log["force_prop_N"], log["force_transient_N"], log["current_A"], log["clipped"]
        L_a, L_g, L_T, L_f = log["accel_m_s2"], log["grip_N"], log["temp_rise_K"], log["sensor_flags"]
        L_w, L_cn = log["wall_ns"], log["compute_ns"]
        # priming cycle (zero current) so one-time costs (a sim's JIT compile, a driver's first transfer)
        # do not land in the first paced tick; then the estimators' history and the contact latch. It stays
        # inline: done in a helper method returning these values, the tick measured 50 % slower (bench_renderer)
        read()
        command(0.0)
        s0_state = read()
        p0 = s0_state.position_m
        if not (-plim <= p0 <= plim):
            p0 = 0.0 if wall is None else wall_h + 2.0 * margin + 1e-3
        for j in range(2 * nring):
            pring[j] = p0
        s0 = wv * p0
        s1 = p0 * wv * (wv - 1) / 2.0
        pi = 0
        po = (pi - wv) % nring
        last_pos = p0
        last_acc = 0.0
        last_grip = 0.0
        g0 = s0_state.grip_N
        if gmin <= g0 <= gmax:
            last_grip = g0
        d0 = wall_h - p0 if wall is not None else pen1d(p0)[0]
        armed = d0 <= 0.0
        # state carried from tick to tick
        out_n = 0
        ev = None
        crossing = False
        ev_pen = ev_acc = 0.0
        ev_clip = False
        temp = float(self.temp_rise_K)
        g_th = 1.0
        nbad = bad_total = overruns = n = li = 0
        uc = until_every
        st["cpu0"] = time.process_time()
        t0 = clock()
        st["t0_ns"] = t0
        prev = deadline = t0
        reason = "duration"
        t = 0.0
        try:
            while n < limit:
                # ---- pace (real time: sleep, then spin to the deadline)
                if realtime:
                    deadline += period_ns
                    now = clock()
                    rem = deadline - now
                    if rem > 0:
                        if sleep_spin and rem > spin_ns:
                            sleep((rem - spin_ns) * 1e-9)
                        while clock() < deadline:
                            pass
                    elif rem < -catchup_ns:
                        deadline = now  # hopelessly behind (e.g. suspended): resynchronise, ticks are lost
                # ---- (1) read and validate: overrun/watchdog, disconnect, implausible samples held
                s = read()
                tr = clock()
                if paced:
                    per = tr - prev
                    if per > over_ns and n:
                        overruns += 1
                        if per > wd_ns and watchdog:
                            command(0.0)
                            reason = "watchdog"
                            st["error"] = f"tick {n} period {per / 1000:.0f} us exceeds the watchdog bound"
                            break
                prev = tr
                t = s.t_s
                pos = s.position_m
                acc = s.accel_m_s2
                grip = s.grip_N
                flags = 0
                if s.status:
                    sts = s.status
                    if sts & _STATUS_DISCONNECTED:
                        command(0.0)
                        reason = "disconnected"
                        st["error"] = str(s.extra.get("error", "device reported a disconnect"))
                        break
                    if sts & _STATUS_SENSOR_INVALID:
                        flags = 8
                        pos = last_pos
                        acc = last_acc
                        grip = last_grip
                if not (-plim <= pos <= plim):  # also False for NaN
                    pos = last_pos
                    flags |= 1
                else:
                    last_pos = pos
                if not (-alim <= acc <= alim):
                    acc = last_acc
                    flags |= 2
                else:
                    last_acc = acc
                if not (gmin <= grip <= gmax):
                    grip = last_grip
                    flags |= 4
                else:
                    last_grip = grip
                if flags:
                    nbad += 1
                    bad_total += 1
                    if nbad >= max_bad:
                        command(0.0)
                        reason = "sensor"
                        st["error"] = f"{nbad} invalid sensor samples in a row (flags {flags}) at tick {n}"
                        break
                else:
                    nbad = 0
                # ---- (2) forces: velocity, transient sample, collision, contact events, wall law
                # sliding least-squares velocity, O(1)
                old = pring[po]
                po += 1
                if po == nring:
                    po = 0
                pring[pi] = pos
                pring[pi + nring] = pos
                pnew = pi
                pi += 1
                if pi == nring:
                    pi = 0
                s1 += (wv - 1) * pos - s0 + old
                s0 += pos - old
                vel = (s1 - c_shift * s0) * c_scale
                # transient playback: the sample for this tick was fixed before this tick's event check
                if tj < tlen:
                    i_t = tbuf[tj] * g_th
                    tj += 1
                else:
                    i_t = 0.0
                # collision detection
                if wall is not None:
                    d = wall_h - pos
                    nz = 1.0
                else:
                    d, nz = pen1d(pos)
                # contact events
                if d > 0.0:
                    if armed:  # impact: the event work is done right after command() (below)
                        armed = False
                        crossing = True
                        if ev is not None:
                            ev.max_penetration_m, ev.peak_accel_m_s2, ev.clipped = ev_pen, ev_acc, ev_clip
                            ev = None
                    else:
                        out_n = 0
                    f_p = k * d * nz
                    if damp > 0.0 and vel * nz < 0.0:
                        f_p -= damp * vel
                else:
                    f_p = 0.0
                    if not armed:
                        if d < -margin and tj >= tlen:
                            out_n += 1
                            if out_n >= hold_n:
                                armed = True
                                if ev is not None:
                                    ev.max_penetration_m, ev.peak_accel_m_s2, ev.clipped = ev_pen, ev_acc, ev_clip
                                    ev = None
                        else:
                            out_n = 0
                # ---- (3) saturate per channel, then the sum (section 4.4.2); thermal model
                clip = 0
                i_p = f_p * inv_kf
                if i_p > ic:
                    i_p = ic
                    clip = 1
                elif i_p < -ic:
                    i_p = -ic
                    clip = 1
                i_t_req = i_t
                if i_t > ipk:
                    i_t = ipk
                    clip |= 2
                elif i_t < -ipk:
                    i_t = -ipk
                    clip |= 2
                i = i_p + i_t
                if i > iamp:
                    i = iamp
                    clip |= 4
                elif i < -iamp:
                    i = -iamp
                    clip |= 4
                if not motor or i != i:
                    i = 0.0
                # winding thermal model: attenuate, then end, transients before the limit
                temp += (heat * i * i - temp) * alpha
                if temp > t_att:
                    g_th = (t_end - temp) * inv_span
                    if g_th <= 0.0:
                        g_th = 0.0
                        tj = tlen
                else:
                    g_th = 1.0
                # ---- (4) command, then the impact work that must not delay the output
                tc = clock()
                command(i)
                if crossing:
                    # after the command, so the crossing tick's output is not delayed: the fit and the
                    # transient lookup use the rest of the period; sample 0 plays on the next tick
                    crossing = False
                    v_in = -impact_velocity.at(pnew, vel) * nz
                    if v_in < 0.0:
                        v_in = 0.0
                    tlen = fill(v_in, grip, tgain * g_th) if g_th > 0.0 else 0
                    tj = 0
                    ev = ContactEvent(t_s=t, incoming_velocity_m_s=v_in, grip_N=grip, transient=tname,
                                      tick=n, transient_samples=tlen, thermal_gain=g_th)
                    events.append(ev)
                    ev_pen = d
                    ev_acc = 0.0
                    ev_clip = False
                if ev is not None:
                    if d > ev_pen:
                        ev_pen = d
                    if acc > ev_acc:
                        ev_acc = acc
                    elif -acc > ev_acc:
                        ev_acc = -acc
                    if clip & 4:
                        ev_clip = True
                # ---- (5) log into the preallocated ring; every until_every ticks publish and check stop
                L_t[li] = t
                L_x[li] = pos
                L_v[li] = vel
                L_d[li] = d
                L_fp[li] = f_p
                L_ft[li] = i_t_req * kf
                L_i[li] = i
                L_c[li] = clip
                L_a[li] = acc
                L_g[li] = grip
                L_T[li] = temp
                L_f[li] = flags
                L_w[li] = tr - t0
                L_cn[li] = tc - tr
                li += 1
                if li == cap:
                    li = 0
                n += 1
                uc -= 1
                if uc == 0:  # every until_every ticks: publish progress, honour stop requests
                    uc = until_every
                    self.ticks = n
                    self.time_s = t
                    self.temp_rise_K = temp
                    stop = self._stop_check(until)
                    if stop:
                        reason = stop
                        break
            else:
                reason = "duration"
        finally:
            if ev is not None:
                ev.max_penetration_m, ev.peak_accel_m_s2, ev.clipped = ev_pen, ev_acc, ev_clip
            self.ticks = n
            self.time_s = t
            self.temp_rise_K = temp
            st.update(stop_reason=reason, ticks=n, n_logged=min(n, cap), wrapped=n > cap, li=li,
                      overruns=overruns, bad_samples=bad_total, paced=paced)

    def _loop_on_device(self, limit, until) -> None:
        """On-device rendering (docs/architecture.md): configure once, then only read, log and collect events."""
        cfg, dev, st = self.cfg, self.device, self._stats
        wall = self.scene.single_wall
        dev.configure_rendering(
            {"height_m": wall.height_m, "stiffness_N_m": cfg.stiffness_N_m, "damping_N_s_m": cfg.damping_N_s_m,
             "rearm_margin_m": cfg.rearm_margin_m},
            dict(self.limits), self.transient)
        read, pop = dev.read, dev.pop_events
        clock = time.perf_counter_ns
        log, cap = self._log, self._cap
        L_t, L_x, L_d, L_a, L_g = log["t_s"], log["position_m"], log["penetration_m"], log["accel_m_s2"], log["grip_N"]
        L_f, L_w, L_cn = log["sensor_flags"], log["wall_ns"], log["compute_ns"]
        wall_h = wall.height_m
        n = li = 0
        reason = "duration"
        st["cpu0"] = time.process_time()
        t0 = clock()
        st["t0_ns"] = t0
        t = 0.0
        try:
            while n < limit:
                s = read()
                tr = clock()
                t = s.t_s
                pos = s.position_m
                flags = 0 if pos == pos else 1
                for raw in pop() or ():
                    self.events.append(ContactEvent.from_dict(raw))
                L_t[li] = t
                L_x[li] = pos
                L_d[li] = wall_h - pos
                L_a[li] = s.accel_m_s2
                L_g[li] = s.grip_N
                L_f[li] = flags
                L_w[li] = tr - t0
                L_cn[li] = clock() - tr
                li += 1
                if li == cap:
                    li = 0
                n += 1
                if s.status & _STATUS_DISCONNECTED:
                    reason = "disconnected"
                    st["error"] = str(s.extra.get("error", "device reported a disconnect"))
                    break
                if n % cfg.until_every == 0:
                    self.ticks = n
                    self.time_s = t
                    stop = self._stop_check(until)
                    if stop:
                        reason = stop
                        break
        finally:
            self.ticks = n
            self.time_s = t
            st.update(stop_reason=reason, ticks=n, n_logged=min(n, cap), wrapped=n > cap, li=li,
                      overruns=0, bad_samples=0, paced=True)

    # ------------------------------------------------------------------ result
    def _build_result(self, wall_s: float, cpu_s: float, realtime: bool) -> RunResult:
        st = self._stats
        n_logged = st.get("n_logged", 0)
        li = st.get("li", n_logged)
        log = {}
        for name, _, dtype, _ in LOG_CHANNELS:
            arr = np.frombuffer(self._log[name], dtype=dtype)
            if st.get("wrapped"):
                arr = np.concatenate([arr[li:], arr[:li]])
            else:
                arr = arr[:n_logged].copy()
            log[name] = arr
        ticks = st.get("ticks", 0)
        periods = np.diff(log["wall_ns"]) / 1000.0 if n_logged > 1 else np.zeros(0)
        compute = log["compute_ns"] / 1000.0
        sim_time = ticks / self.fs_hz

        def pct(a, q):
            return float(np.percentile(a, q)) if len(a) else 0.0

        period_us = 1e6 / self.fs_hz
        lateness = np.zeros(0)
        if realtime and n_logged:
            # how late each tick's read() returned after its deadline (t0 + (n + 1) period)
            first = ticks - n_logged
            idx = np.arange(first + 1, ticks + 1, dtype=np.float64)
            lateness = log["wall_ns"] / 1000.0 - idx * period_us
        timing = {
            "sim_time_s": sim_time,
            "wall_time_s": wall_s,
            "ticks": int(ticks),
            "rate_hz": self.fs_hz,
            "achieved_rate_hz": ticks / wall_s if wall_s > 0 else 0.0,
            "realtime_factor": sim_time / wall_s if wall_s > 0 else 0.0,
            "realtime_factor_cpu": sim_time / cpu_s if cpu_s > 0 else 0.0,
            "realtime": realtime,
            "period_p50_us": pct(periods, 50),
            "period_p99_us": pct(periods, 99),
            "period_max_us": float(periods.max()) if len(periods) else 0.0,
            "period_error_p99_us": pct(np.abs(periods - period_us), 99),
            "period_error_max_us": float(np.abs(periods - period_us).max()) if len(periods) else 0.0,
            "overruns": int(st.get("overruns", 0)),
            "lateness_p50_us": pct(lateness, 50),
            "lateness_p99_us": pct(lateness, 99),
            "lateness_max_us": float(lateness.max()) if len(lateness) else 0.0,
            "compute_p50_us": pct(compute, 50),
            "compute_p99_us": pct(compute, 99),
            "compute_max_us": float(compute.max()) if len(compute) else 0.0,
            "cpu_time_s": cpu_s,
            "cpu_percent": 100.0 * cpu_s / wall_s if wall_s > 0 else 0.0,
            "log_wrapped": bool(st.get("wrapped", False)),
            "bad_sensor_samples": int(st.get("bad_samples", 0)),
            "clipped_ticks": {name: int(np.count_nonzero(log["clipped"] & bit)) for name, bit in
                              (("proportional", 1), ("transient", 2), ("amplifier", 4))},
            "max_temp_rise_K": float(log["temp_rise_K"].max()) if n_logged else self.temp_rise_K,
            "final_temp_rise_K": float(self.temp_rise_K),
            "on_device": bool(self.on_device),
        }
        link_stats = getattr(self.device, "link_stats", None)
        if callable(link_stats):  # hardware links: frames, CRC errors, losses, longest gap, round trip
            timing["link"] = link_stats()
        info = self.info
        device = dataclasses.asdict(info) if dataclasses.is_dataclass(info) else {}
        device["limits_used"] = dict(self.limits)
        device["continuous_safe_A"] = self.continuous_safe_A
        return RunResult(events=list(self.events), log=log, timing=timing, stop_reason=st["stop_reason"],
                         config=self.cfg.to_dict(), device=device, transient=self.transient_name,
                         error=st.get("error", ""))
