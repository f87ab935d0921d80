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
9. ``device.command(i)``; then, on an impact, the event's work (velocity fit, transient lookup).

Steps 1-8 and the tick's log row are one compiled function, ``renderer.law.law_tick``, over
preallocated arrays: the per-tick loop calls it between ``read()`` and ``command()`` (hardware,
paced simulations), and ``renderer.law.run_sim`` runs it together with a simulated device's physics
(as fast as possible). The output is zeroed on every exit path.
"""

from __future__ import annotations

import array
import contextlib
import csv
import ctypes
import dataclasses
import json
import math
import mmap
import os
import pathlib
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from devices.base import Status
from plumbing import provenance
from devices.limits import check_stiffness
from plumbing.npzfile import save_npz
from plumbing.stopsignals import Terminated, holding, stop_if_signalled, stop_in, stop_on_signals

from . import law_layout as LAW
from plumbing import rtpolicy
from . import sim_aot
from . import timing_verdict
from .config import RendererConfig
from .passivity import passivity_constants
from .ring import same_sample_limit
from .safety import safety_bounds
from .scene import SHAPE_CODES
from .thermal import safe_continuous_current
from .velocity import ImpactVelocityEstimator, ls_constants

_STATUS_UNSTABLE = int(Status.UNSTABLE)  # an on-device wall stopped by the device's passivity observer
_UNSTABLE_ADVICE = "Lower the stiffness or add damping (docs/renderer.md, 'Stopping an unstable wall')"

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
        The ``run.json`` timing fields; ``log_rate_hz`` is the log's row rate (the servo rate, or the
        on-device telemetry's: servo rate / decimation).
    stop_reason : str
        "duration", "until", "stopped" (request_stop), "watchdog", "sensor", "disconnected",
        "unstable" (the wall's passivity observer), "exception", "interrupted" (Ctrl-C, SIGTERM, SIGHUP).
    config, device, transient : run metadata for ``run.json``.
    """

    #: the columns of events.csv (a 3-D run adds the object, normal and position: renderer.loop3)
    event_columns = EVENT_COLUMNS

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
            writer.writerow(self.event_columns)
            for ev in self.events:
                row = []
                for name in self.event_columns:
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
        save_npz(tmp, self.log)
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


def prefaulted_zeros(shape: tuple[int, int]) -> np.ndarray:
    """A zeroed float64 array whose pages are already mapped, so the loop never takes a first-touch fault.

    On Linux an anonymous ``MAP_POPULATE`` mapping: the kernel maps every page in one call (~0.4 ms/MB
    here). numpy's own arrays of 4 MB and more ask for transparent huge pages, whose compaction made
    the same 29 MB (a 30 s log) cost 10-70 ms, varying with the machine's memory. Elsewhere an array
    filled (touched page by page) here.
    """
    nbytes = 8 * shape[0] * shape[1]
    populate = getattr(mmap, "MAP_POPULATE", 0)
    if populate and nbytes:
        buf = mmap.mmap(-1, nbytes, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS | populate)
        return np.frombuffer(buf, dtype=np.float64).reshape(shape)
    out = np.empty(shape)
    out.fill(0.0)
    return out


#: ticks between stop-request polls of a compiled simulated run without an ``until`` predicate: each poll
#: returns to Python (~5 us), so 16-tick chunks cost as much as the physics; 10 000 ticks take ~5 ms
COMPILED_POLL_TICKS = 10_000


def _law():
    """``renderer.law``: the JIT-compiled law, imported by the first loop that runs it per tick or JIT
    (``renderer.sim_aot.jit_laws``: a run compiled ahead of time never imports it, nor numba)."""
    return sim_aot.jit_laws().law


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

    def __init__(self, device, cfg: RendererConfig | None = None, transient=None, compiled_sim: bool = True):
        self.device = device
        # as fast as possible on a simulated device that offers its physics to the compiled loop
        # (devices.sim.SimDevice.fused_arrays): law and physics run together in renderer.law.run_sim
        self.compiled_sim = bool(compiled_sim)
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
        #: real-time treatment to ask for around a paced run (``plumbing.rtpolicy.acquire`` keywords, e.g.
        #: ``{"core": 1}``), or None to run with the process's policy as it is (still recorded in run.json)
        self.rt_request: dict | None = None

    # ------------------------------------------------------------------ set-up
    def prepare(self) -> None:
        """Validate device, limits, rate and transient; allocate buffers. Raises ValueError before any motion."""
        cfg, dev = self.cfg, self.device
        info = dev.info
        self.info = info
        on_device = bool(getattr(dev, "on_device_rendering", False)) and "on_device" in info.capabilities
        lockstep_hz = None if on_device else info.lockstep_rate_hz
        native_hz = float(lockstep_hz if lockstep_hz is not None else info.servo_rate_hz)
        fs = float(cfg.rate_hz) if cfg.rate_hz is not None else native_hz
        if lockstep_hz is not None and abs(fs - lockstep_hz) > 1e-9 * fs:
            raise ValueError(f"rate_hz={fs:g}: this device runs in lockstep (a simulated MCU; docs/protocol.md "
                             f"'Lockstep') and advances {info.lockstep_ticks} of its {info.servo_rate_hz:g} Hz ticks per "
                             f"command, so the streaming rate is {lockstep_hz:g} Hz: leave rate_hz unset or give that")
        if info.simulated and abs(fs - info.servo_rate_hz) > 1e-9 * fs:
            raise ValueError(f"rate_hz={fs:g} differs from the sim device's servo_rate_hz={info.servo_rate_hz:g}; "
                             "a sim device advances 1/servo_rate_hz per command, so create it with that rate")
        self.fs_hz = fs
        self.log_rate_hz = fs  # rows of the log per second of device time (lower on-device with decimated telemetry)
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
        check_stiffness(info, cfg.stiffness_N_m, ic)   # 1e9 N/m refused; beyond one count per limit, warned
        # the proportional channel alone must never be able to overheat the winding
        self.continuous_safe_A = safe_continuous_current(info, ic)
        self.force_per_amp = info.force_per_amp_N_A
        self.scene = cfg.effective_scene
        if self.scene.needs_3d:
            raise ValueError(f"{self.scene.source}: meshes and objects with their own stiffness, friction or "
                             "transient render with the 3-D renderer (renderer.loop3.ServoLoop3), not the 1-DOF loop")
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
        self.w_vel = max(2, int(round(cfg.velocity_window_s * fs)))
        self.impact_velocity = ImpactVelocityEstimator(self.dt_s, info.position_resolution_m,
                                                       cfg.impact_min_window_s, cfg.impact_window_s,
                                                       cfg.impact_counts)
        # the law's state (renderer.law): scalars, the double-written position ring, the transient buffer
        self.nring = max(self.w_vel, self.impact_velocity.history)
        self.tbuf_at = LAW.W_RING + 2 * self.nring
        self.law_state = np.zeros(self.tbuf_at + self.nbuf)
        self.tview = self.law_state[self.tbuf_at:]
        self.impact_velocity.bind(self.law_state[LAW.W_RING:self.tbuf_at])
        self._prepared = True

    def log_since(self, tick: int, columns: tuple, step: int = 1, end: int | None = None) -> tuple[int, np.ndarray]:
        """The log's ``columns`` for the ticks from ``tick`` to ``end`` (default: the last one run), every
        ``step``-th tick (those whose number is a multiple of it), for a consumer while the loop runs (the Lab
        Streaming Layer's state stream, :mod:`plumbing.lsl`, reads it from its own thread: the ring keeps the
        last ``capacity`` ticks, seconds, far more than the thread lags). At most the ring's last ``capacity``
        ticks before the last one run.

        Returns
        -------
        (int, ndarray)
            The first tick returned and the values, shape ``(len(columns), n)``.
        """
        n = self.ticks if end is None else min(int(end), self.ticks)
        start = max(int(tick), self.ticks - self._cap)
        start += (-start) % step
        idx = np.arange(start, n, step) % self._cap
        rows = [LAW.LOG_COLUMNS.index(c) for c in columns]
        return start, self._logf[np.ix_(rows, idx)]

    def request_stop(self) -> None:
        """Ask a running loop (e.g. from a UI thread) to stop within ``cfg.until_every`` ticks (a compiled
        simulated run without an ``until`` predicate: within ``COMPILED_POLL_TICKS``, a few ms of wall time)."""
        self.stop_requested = True

    def _stop_check(self, until) -> str:
        """Stop reason from a stop request or the caller's ``until`` predicate, else ""; polled every
        ``until_every`` ticks (not per tick) by both loops."""
        stop_if_signalled()   # a SIGTERM swallowed by a JIT compile since (plumbing.stopsignals) stops here
        if self.stop_requested:
            return "stopped"
        if until is not None and until(self):
            return "until"
        return ""

    def _alloc_log(self, capacity: int, clocks_per_tick: bool = True) -> None:
        # the law's channels (renderer.law.LOG_COLUMNS, one contiguous row each) and the loop's own clock
        # columns; mapped now, so the loop never takes a first-touch page fault (mapping them on the other
        # core while the compiled loop runs, which releases the GIL, measured no faster: the loop slowed by
        # what it saved). A compiled simulated run writes its clock columns once per chunk (compute_ns
        # never): zero pages mapped on demand
        self._logf = prefaulted_zeros((LAW.N_LOG, capacity))
        if clocks_per_tick:
            self._log_ns = {name: array.array("q", [0]) * capacity for name in ("wall_ns", "compute_ns")}
        else:
            self._log_ns = {name: np.zeros(capacity, dtype=np.int64) for name in ("wall_ns", "compute_ns")}

    def _compiled_path(self, realtime: bool) -> bool:
        """Whether this run takes the compiled simulated loop (:meth:`_run_compiled`)."""
        return (self.compiled_sim and not realtime and not self.on_device and self.info.simulated
                and callable(getattr(self.device, "fused_arrays", None)))

    def _fill_transient(self, v_in: float, grip: float, gain: float, nz: float = 1.0) -> int:
        """Write the event's transient current (A) into the buffer; returns its length (event time, not per tick).

        The transient (eq. 4.7, 4.8, HFAM) is a force along the outward normal of the surface hit, positive
        (out) at onset; the device's axis gets its z component, scaled by ``nz`` like the wall's
        ``k d n_z`` (eq. 2.1), so a surface facing down (a ceiling hit from below) is pushed down."""
        tr = self.transient
        if tr is None or gain <= 0.0 or nz == 0.0 or not self.cfg.motor_enabled:
            return 0
        view = self.tview
        into = getattr(tr, "current_into", None)
        if callable(into):
            n = int(into(v_in, grip, view))
            n = min(n, self.nbuf)
            if gain * nz != 1.0:
                view[:n] *= gain * nz
        else:
            w = np.asarray(tr.waveform(v_in, grip, self.fs_hz), dtype=np.float64)
            n = min(len(w), self.nbuf)
            np.multiply(w[:n], gain * nz / self.force_per_amp, out=view[:n])
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
        ``self.result``. In the main thread SIGTERM and SIGHUP stop the run the
        same way (``plumbing.stopsignals``: :class:`plumbing.stopsignals.Terminated`,
        a SystemExit with code 128 + the signal's number, propagates after the
        zero), unless the caller has its own handlers; the handlers in place
        before the call are back when it returns.
        """
        with stop_on_signals():
            return self._run(duration_s, until, realtime, max_ticks)

    def _run(self, duration_s, until, realtime, max_ticks) -> RunResult:
        if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
            raise ValueError(f"duration_s must be > 0, got {duration_s!r}")
        self.prepare()
        dev = self.device
        if not dev.is_open:
            dev.open()
        if realtime is None:
            realtime = not self.info.simulated
        if self.info.lockstep_ticks and not self.on_device:
            realtime = False  # the device's clock paces a lockstep device: wall-clock pacing would only lag it
        limit = math.inf
        if duration_s is not None:
            limit = int(round(duration_s * self.fs_hz))
        if max_ticks is not None:
            limit = min(limit, int(max_ticks))
        cap_ticks = max(1, int(round(self.cfg.log_capacity_s * self.fs_hz)))
        self.log_rate_hz = self.fs_hz  # one log row per tick (the on-device loop: per telemetry frame)
        if limit != math.inf:
            cap_ticks = max(1, min(cap_ticks, int(limit)))
        self.events = []
        self.bad_transients = 0
        self.stop_requested = False
        compiled = self._compiled_path(bool(realtime))
        self._alloc_log(cap_ticks, clocks_per_tick=not compiled)
        self._cap = cap_ticks
        self._stats = {"stop_reason": "exception", "n_logged": 0, "wrapped": False, "ticks": 0,
                       "overruns": 0, "bad_samples": 0, "error": ""}
        old_slack = _set_timer_slack_ns(1000) if realtime else None
        wall0 = time.perf_counter()
        cpu0 = time.process_time()
        failure = None
        try:
            if self.on_device:
                self._loop_on_device(limit, until)
            else:
                self._loop(limit, until, bool(realtime), compiled)
        except BaseException as exc:
            exc = stop_in(exc) or exc   # a stop that Python wrapped (a signal inside an import) is a stop
            self._stats["stop_reason"] = ("interrupted" if isinstance(exc, (KeyboardInterrupt, Terminated))
                                          else "exception")
            self._stats["error"] = f"{type(exc).__name__}: {exc}"
            failure = exc
        # the zero, then the (partial) result: a SIGTERM/SIGHUP arriving meanwhile is raised after both
        with holding():
            try:
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
            if failure is not None:
                try:
                    raise failure
                finally:
                    failure = None
        return self.result

    def _law_constants(self) -> np.ndarray:
        """The law's constants (``renderer.law.C_*``): gains, limits, thermal and sensor bounds, the scene."""
        cfg, info, fs = self.cfg, self.info, self.fs_hz
        b = safety_bounds(info, fs, cfg)  # the safety path shared with every servo law (renderer.safety)
        objs = self.scene.objects
        c = np.zeros(LAW.C_OBJ + LAW.OBJ_STRIDE * len(objs))
        c[LAW.C_K], c[LAW.C_DAMP] = float(cfg.stiffness_N_m), float(cfg.damping_N_s_m)
        c[LAW.C_MARGIN], c[LAW.C_HOLD_N] = float(cfg.rearm_margin_m), max(1, int(round(cfg.rearm_hold_s * fs)))
        c[LAW.C_KF], c[LAW.C_INV_KF] = self.force_per_amp, 1.0 / self.force_per_amp
        c[LAW.C_MOTOR], c[LAW.C_TGAIN] = 1.0 if cfg.motor_enabled else 0.0, float(cfg.transient_gain)
        c[LAW.C_IC], c[LAW.C_IPK], c[LAW.C_IAMP] = self.continuous_safe_A, self.limits["peak_A"], self.limits["amplifier_A"]
        c[LAW.C_HEAT], c[LAW.C_ALPHA] = b.heat_K_A2, b.alpha
        c[LAW.C_T_ATT], c[LAW.C_T_END] = b.t_attenuate_K, b.t_end_K
        c[LAW.C_INV_SPAN] = 1.0 / (b.t_end_K - b.t_attenuate_K)
        c[LAW.C_PLIM], c[LAW.C_ALIM] = b.position_limit_m, b.accel_limit_m_s2
        c[LAW.C_GMIN], c[LAW.C_GMAX], c[LAW.C_MAX_BAD] = b.grip_min_N, b.grip_max_N, b.max_bad_samples
        c[LAW.C_WV], c[LAW.C_NRING], c[LAW.C_FS] = self.w_vel, self.nring, fs
        c[LAW.C_SAME_MAX] = same_sample_limit(cfg, fs, self.nring)
        c[LAW.C_C_SHIFT], c[LAW.C_C_SCALE] = ls_constants(self.w_vel, self.dt_s)
        c[LAW.C_CAP], c[LAW.C_NOBJ], c[LAW.C_TBUF] = self._cap, len(objs), self.tbuf_at
        c[LAW.C_PO_FC] = self.continuous_safe_A * self.force_per_amp
        c[LAW.C_PO_DECAY], c[LAW.C_PO_LIMIT] = passivity_constants(cfg, self.dt_s, c[LAW.C_PO_FC])
        for j, obj in enumerate(objs):
            nums = obj.numbers()
            o = LAW.C_OBJ + LAW.OBJ_STRIDE * j
            c[o] = SHAPE_CODES[obj.shape]
            c[o + 1:o + 1 + len(nums)] = nums
        return c

    def _prime(self, warm_law: bool = True) -> None:
        """Zero-current priming cycle, then the law's initial state: the position ring and its sums, the
        last good samples, the contact latch, temperature. One-time costs (a sim's JIT compile, a
        driver's first transfer) land here, not in the first paced tick."""
        read, command = self.device.read, self.device.command
        c, w = self._law_c, self.law_state
        w[:LAW.W_RING] = 0.0
        read()
        command(0.0)
        s0 = read()
        plim, wall = c[LAW.C_PLIM], self.scene.single_wall
        p0 = s0.position_m
        if not (-plim <= p0 <= plim):
            p0 = 0.0 if wall is None else wall.height_m + 2.0 * self.cfg.rearm_margin_m + 1e-3
        nring, wv = self.nring, self.w_vel
        w[LAW.W_RING:LAW.W_RING + 2 * nring] = p0
        w[LAW.W_S0] = wv * p0
        w[LAW.W_S1] = p0 * wv * (wv - 1) / 2.0
        w[LAW.W_PI] = 0
        w[LAW.W_PO] = (0 - wv) % nring
        w[LAW.W_LAST_POS] = p0
        w[LAW.W_PO_X] = p0
        # the primed ring's newest slot is this sample, at its time: the first tick's sample fills the periods
        # since (the law's warm-up below, a driver's first transfer), not one period's worth of motion
        w[LAW.W_TRING] = s0.t_s
        # the passivity observer's account starts at the first tick (NaN: not started): the handle may move into
        # the wall between this priming read and that tick (the law's warm-up, a loaded machine), and energy the
        # wall stores then was put in by the hand against no force, not generated by the loop
        w[LAW.W_PO_U] = math.nan
        if c[LAW.C_GMIN] <= s0.grip_N <= c[LAW.C_GMAX]:
            w[LAW.W_LAST_GRIP] = s0.grip_N
        w[LAW.W_ARMED] = 1.0 if self.scene.penetration_1d(p0)[0] <= 0.0 else 0.0
        w[LAW.W_TEMP] = float(self.temp_rise_K)
        w[LAW.W_GTH] = 1.0
        if warm_law:
            # one tick of the law on scratch copies: its first call's one-time cost lands here, not in tick 0
            _law().law_tick(c, w.copy(), np.zeros((LAW.N_LOG, 1)), 0.0, p0, 0.0, 0.0, 0)

    def _loop(self, limit, until, realtime: bool, compiled: bool) -> None:
        """The servo loop proper; one tick of it: pace; read; the law (``renderer.law.law_tick``:
        validate, velocity, transient sample, collision, events, wall law, saturation, thermal, log
        row); command; then the impact's work that must not delay the output; every ``until_every``
        ticks publish progress and honour stop requests. On a simulated device run as fast as possible,
        law and physics run together in ``renderer.law.run_sim`` (:meth:`_run_compiled`).
        """
        st = self._stats
        dev = self.device
        self._law_c = self._law_constants()
        if compiled:
            # the ahead-of-time build when there is one (renderer.sim_aot: no numba in the process), which
            # also carries the device's own physics step for the priming tick and any Python-side command
            self._run_sim, step = sim_aot.run_sim_function()
            st["aot"] = step is not None
            if step is not None and callable(getattr(dev, "use_compiled_step", None)):
                dev.use_compiled_step(step)
        self._prime(warm_law=not compiled)
        if compiled:
            # the compiled loop's one-time cost (numba's JIT compile on a cold cache, or loading it) here too,
            # before the first tick: called for no ticks, it changes nothing
            self._run_sim(self._law_c, self.law_state, self._logf, dev.fused_state(), *dev.fused_arrays(), 0)
        # a SIGTERM/SIGHUP that landed inside numba's compiler was swallowed by llvmlite's ctypes callback
        # ("Exception ignored"): plumbing.stopsignals kept it, and the run stops now, as it would have
        stop_if_signalled()
        restart = getattr(dev, "restart_link_timing", None)
        if callable(restart):  # run.json's link round trip and longest gap: this run's ticks, not the priming
            restart()
        paced = realtime and not compiled
        # the real-time policy after the priming cycle (one-time costs must not run under SCHED_FIFO) and the
        # collector paused for the paced ticks (plumbing.rtpolicy); the policy is released when the loop ends
        acquired = None
        if paced and self.rt_request is not None:
            acquired = rtpolicy.acquire(**{"fifo": True, **self.rt_request})
        st["policy"] = acquired if acquired is not None else rtpolicy.describe_current()
        gc_pause = rtpolicy.gc_paused() if paced else contextlib.nullcontext()
        self._ev = None
        self._tlen = 0
        st["compiled"] = compiled
        st["cpu0"] = time.process_time()
        t0 = time.perf_counter_ns()
        st["t0_ns"] = t0
        self._n = 0
        self.ticks = 0     # this run's ticks (log_since reads the ring from its first row)
        reason = "duration"
        try:
            with gc_pause:
                if compiled:
                    reason = self._run_compiled(limit, until, t0)
                else:
                    reason = self._run_ticks(limit, until, realtime, t0)
        finally:
            if acquired is not None:
                rtpolicy.release(acquired)
            w = self.law_state
            ev = self._ev
            if ev is not None:
                ev.max_penetration_m, ev.peak_accel_m_s2 = float(w[LAW.W_EV_PEN]), float(w[LAW.W_EV_ACC])
                ev.clipped = bool(w[LAW.W_EV_CLIP])
            n = self._n
            self.ticks = n
            self.time_s = float(w[LAW.W_T])
            self.temp_rise_K = float(w[LAW.W_TEMP])
            st.update(stop_reason=reason, ticks=n, n_logged=min(n, self._cap), wrapped=n > self._cap,
                      li=int(w[LAW.W_LI]), overruns=st.get("overruns", 0),
                      bad_samples=int(w[LAW.W_BAD_TOTAL]), paced=st.get("paced", False))

    def _after_command(self, code: int, n: int) -> None:
        """An event's work after the tick's command: close the open event, and on an impact fit the
        incoming velocity, write the transient for the next ticks and record the event."""
        w = self.law_state
        if code & LAW.CODE_CLOSED and self._ev is not None:
            ev = self._ev
            ev.max_penetration_m, ev.peak_accel_m_s2 = float(w[LAW.W_CLOSED_PEN]), float(w[LAW.W_CLOSED_ACC])
            ev.clipped = bool(w[LAW.W_CLOSED_CLIP])
            self._ev = None
        if code & LAW.CODE_IMPACT:
            nz = float(w[LAW.W_NZ])
            v_in = -self.impact_velocity.at(int(w[LAW.W_PNEW]), float(w[LAW.W_VEL])) * nz
            if v_in < 0.0:
                v_in = 0.0
            g_th, grip = float(w[LAW.W_GTH]), float(w[LAW.W_GRIP])
            tlen = self._fill_transient(v_in, grip, self._law_c[LAW.C_TGAIN] * g_th, nz) if g_th > 0.0 else 0
            w[LAW.W_TLEN] = tlen
            w[LAW.W_TJ] = 0.0
            self._ev = ContactEvent(t_s=float(w[LAW.W_T]), incoming_velocity_m_s=v_in, grip_N=grip,
                                    transient=self.transient_name, tick=n, transient_samples=tlen,
                                    thermal_gain=g_th)
            self.events.append(self._ev)

    def _run_ticks(self, limit, until, realtime: bool, t0: int) -> str:
        """One ``law_tick`` per tick between ``read()`` and ``command()`` (hardware, paced simulation)."""
        st, cfg, info = self._stats, self.cfg, self.info
        read, command = self.device.read, self.device.command
        clock, sleep = time.perf_counter_ns, time.sleep
        law_tick, c, w, log = _law().law_tick, self._law_c, self.law_state, self._logf
        wm = memoryview(w)  # reading a Python float from a memoryview is cheaper than from numpy
        W_CODE = LAW.W_CODE
        L_w, L_cn = self._log_ns["wall_ns"], self._log_ns["compute_ns"]
        cap = self._cap
        fs = self.fs_hz
        period_ns = int(round(1e9 / fs))
        # a simulated device, and a lockstep one (its clock waits for the host: docs/protocol.md "Lockstep"), take
        # no wall-clock pacing: no overrun counting, no host watchdog on the wall clock (a stalled simulation
        # endangers nothing: the watchdog guards real motors; a dead lockstep link is the driver's to detect)
        on_device_clock = info.on_device_clock
        paced = realtime or not on_device_clock
        tol = cfg.overrun_tolerance_s if cfg.overrun_tolerance_s is not None else 0.5 / fs
        over_ns = period_ns + int(tol * 1e9)
        wd_ns = period_ns + int(cfg.watchdog_overrun_s * 1e9)
        watchdog = not on_device_clock
        spin_ns = int(cfg.spin_margin_s * 1e9)
        sleep_spin = cfg.pacing == "sleep_spin"
        if realtime and st.get("policy", {}).get("policy") == "SCHED_FIFO":
            # never busy-wait a whole period under SCHED_FIFO (RT throttling would stall the loop ~50 ms every
            # second): sleep to the deadline and spin only a short, throttling-safe margin (plumbing.rtpolicy)
            sleep_spin = True
            spin_ns = int(rtpolicy.fifo_spin_margin_s(1.0 / fs, cfg.spin_margin_s) * 1e9)
            st["policy"]["spin_margin_us"] = spin_ns / 1000.0
        catchup_ns = int(cfg.max_catchup_s * 1e9)
        until_every = int(cfg.until_every)
        uc = until_every
        overruns = n = li = 0
        prev = deadline = t0
        reason = "duration"
        st["paced"] = paced
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
                # ---- read; overrun and watchdog
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
                # ---- the law
                i = law_tick(c, w, log, s.t_s, s.position_m, s.accel_m_s2, s.grip_N, s.status)
                code = int(wm[W_CODE])
                if code >= 4:  # a stop: LAW.CODE_SENSOR, CODE_DISCONNECTED or CODE_UNSTABLE
                    command(0.0)
                    if code & LAW.CODE_DISCONNECTED:
                        reason = "disconnected"
                        st["error"] = str(s.extra.get("error", "device reported a disconnect"))
                    else:
                        reason, st["error"] = self._law_stop(code, n)
                    break
                # ---- command, then the impact work that must not delay the output
                tc = clock()
                command(i)
                if code:
                    self._after_command(code, n)
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
                    self.time_s = wm[LAW.W_T]
                    self.temp_rise_K = wm[LAW.W_TEMP]
                    stop = self._stop_check(until)
                    if stop:
                        reason = stop
                        break
        finally:
            self._n = n
            st["overruns"] = overruns
        return reason

    def _law_stop(self, code: int, n: int) -> tuple[str, str]:
        """Stop reason and message of a law stop at tick ``n``: invalid sensors or an unstable wall."""
        w, c = self.law_state, self._law_c
        if code & LAW.CODE_UNSTABLE:
            return "unstable", (f"the wall generated {w[LAW.W_PO_E] * 1e3:.3g} mJ net over the last "
                                f"~{self.cfg.instability_window_s:g} s at tick {n} (limit {c[LAW.C_PO_LIMIT] * 1e3:.3g} mJ "
                                f"at stiffness_N_m={self.cfg.stiffness_N_m:g}): the loop is unstable; output zeroed. "
                                f"{_UNSTABLE_ADVICE}")
        return "sensor", (f"{int(w[LAW.W_NBAD])} invalid sensor samples in a row "
                          f"(flags {int(w[LAW.W_FLAGS])}) at tick {n}")

    def _device_observer(self) -> tuple[float, float, float]:
        """The on-device wall observer's limit (J, 0 = off), force limit (N) and leak per device tick.

        The device runs it (protocol 1.1) at its own servo period, with its wall force limit: the
        continuous current limit sent with LIMITS (:func:`renderer.passivity.passivity_constants`).
        """
        cfg = self.cfg
        dt = 1.0 / float(self.info.servo_rate_hz)
        f_c = self.limits["continuous_A"] * self.force_per_amp
        _, limit = passivity_constants(cfg, dt, f_c)
        leak = -math.expm1(-dt / cfg.instability_window_s)  # 1 - decay, exact for small leaks
        return (limit if math.isfinite(limit) else 0.0), f_c, leak  # no stiffness: nothing to observe

    def _device_unstable_message(self, t: float) -> str:
        """The message of an on-device observer stop (the device reports the stop, not its energy)."""
        limit, f_c, _ = self._device_observer()
        cfg = self.cfg
        return (f"the device's passivity observer stopped its wall at t = {t:.3f} s: the wall generated more than "
                f"the limit of {limit * 1e3:.3g} mJ net over the last ~{cfg.instability_window_s:g} s "
                f"(stiffness_N_m={cfg.stiffness_N_m:g}, force limit {f_c:.3g} N): the loop is unstable; the device "
                f"zeroed its output. {_UNSTABLE_ADVICE}")

    def _run_compiled(self, limit, until, t0: int) -> str:
        """Law and simulated physics in ``renderer.law.run_sim``, in chunks of ``until_every`` ticks; an
        impact or a stop returns to Python for the event work or the stop. The per-tick clock columns
        hold the chunk's end (no per-tick timing inside a compiled chunk)."""
        st, dev = self._stats, self.device
        c, w, log, cap = self._law_c, self.law_state, self._logf, self._cap
        wall_col = np.frombuffer(self._log_ns["wall_ns"], dtype=np.int64)
        # between chunks (every few ticks with an ``until`` predicate) the loop's own Python work is most of
        # the run's time: the law's scalars read through a memoryview (Python floats, cheaper than numpy's)
        wm = memoryview(w)
        W_CODE, W_T, W_TEMP = LAW.W_CODE, LAW.W_T, LAW.W_TEMP
        clock = time.perf_counter_ns
        stop_check = self._stop_check
        # with an ``until`` predicate, it sees the device as it was every ``until_every`` ticks (as in the
        # per-tick loop); without one, only a stop request is polled, every COMPILED_POLL_TICKS ticks (a few
        # ms of wall time), and the device's Python side is brought up to date at the end
        until_every = int(self.cfg.until_every) if until is not None else max(int(self.cfg.until_every),
                                                                               COMPILED_POLL_TICKS)
        uc = until_every
        n = li = 0
        st["paced"] = False
        # a device that says when its arrays, state or span changed (devices.sim.SimDevice.fused_version) is
        # asked for them again only then; another, after every ``until`` call
        versioned = hasattr(dev, "fused_version")
        arrays = dev.fused_arrays()
        dv = dev.fused_state()
        span = dev.fused_span()
        version = dev.fused_version if versioned else None
        run_sim = self._run_sim
        reason = "duration"
        try:
            while n < limit:
                if span <= 0:
                    # the hand's plan is streamed (devices.sim.SimDevice.fused_span): its next window
                    dev.fused_sync(dv)
                    arrays = dev.fused_arrays()
                    dv = dev.fused_state()
                    span = dev.fused_span()
                    version = dev.fused_version if versioned else None
                k = run_sim(c, w, log, dv, *arrays, min(uc, limit - n, span))
                span -= k
                now = clock() - t0
                end = li + k
                if end <= cap:
                    wall_col[li:end] = now
                else:
                    wall_col[li:] = now
                    wall_col[:end - cap] = now
                li = end % cap
                n += k
                self._n = n
                uc -= k
                code = int(wm[W_CODE])
                if code >= 4:  # a stop before the tick's command: zero it through the device
                    dev.fused_sync(dv)
                    dev.command(0.0)
                    if code & LAW.CODE_DISCONNECTED:
                        reason = "disconnected"
                        st["error"] = str(dev.read().extra.get("error", "device reported a disconnect"))
                    else:
                        reason, st["error"] = self._law_stop(code, n)
                    break
                if code:
                    self._after_command(code, n - 1)
                if uc == 0:
                    uc = until_every
                    self.ticks = n
                    self.time_s = wm[W_T]
                    self.temp_rise_K = wm[W_TEMP]
                    if until is None:
                        stop_if_signalled()
                        if self.stop_requested:
                            reason = "stopped"
                            break
                        continue
                    dev.fused_sync(dv)
                    stop = stop_check(until)
                    if stop:
                        reason = stop
                        break
                    # the callback may have changed the device (a new user, sample, trajectory); unchanged, the
                    # arrays and the state vector held are the device's own, and ``span`` counts its ticks left
                    # (at 0 the next window is fetched now, as a fresh fused_arrays() would)
                    if span <= 0 or not versioned or dev.fused_version != version:
                        arrays = dev.fused_arrays()
                        dv = dev.fused_state()
                        span = dev.fused_span()
                        version = dev.fused_version if versioned else None
        finally:
            dev.fused_sync(dv)
            self._n = n
        return reason

    def _loop_on_device(self, limit, until) -> None:
        """On-device rendering (docs/architecture.md): configure once, then only read, log and collect events."""
        cfg, dev, st = self.cfg, self.device, self._stats
        wall = self.scene.single_wall
        po_limit, _, po_leak = self._device_observer()
        dev.configure_rendering(
            {"height_m": wall.height_m, "stiffness_N_m": cfg.stiffness_N_m, "damping_N_s_m": cfg.damping_N_s_m,
             "rearm_margin_m": cfg.rearm_margin_m, "instability_limit_J": po_limit,
             "instability_leak": po_leak},
            dict(self.limits), self.transient)
        read, pop = dev.read, dev.pop_events
        # a telemetry frame every ``per`` firmware ticks (a serial link's decimation): count device ticks, so
        # duration_s and max_ticks mean device time as in the host loops
        per = getattr(dev, "telemetry_decimation", 1)
        per = int(per) if isinstance(per, int) and per >= 1 else 1
        self.log_rate_hz = self.fs_hz / per  # the log holds one row per frame
        frames = 0
        clock = time.perf_counter_ns
        log, cap = self._logf, self._cap
        L_w, L_cn = self._log_ns["wall_ns"], self._log_ns["compute_ns"]
        col = {name: j for j, name in enumerate(LAW.LOG_COLUMNS)}
        C_T, C_X, C_D, C_A, C_G, C_F, C_I = (col[k] for k in ("t_s", "position_m", "penetration_m", "accel_m_s2",
                                                               "grip_N", "sensor_flags", "current_A"))
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
                log[C_T, li] = t
                log[C_X, li] = pos
                log[C_D, li] = wall_h - pos
                log[C_A, li] = s.accel_m_s2
                log[C_G, li] = s.grip_N
                log[C_F, li] = flags
                # the current the device commanded at that tick (STATE telemetry), not computed here
                log[C_I, li] = s.extra.get("current_A", math.nan)
                L_w[li] = tr - t0
                L_cn[li] = clock() - tr
                li += 1
                if li == cap:
                    li = 0
                n += per
                frames += 1
                if s.status & LAW.STATUS_DISCONNECTED:
                    reason = "disconnected"
                    st["error"] = str(s.extra.get("error", "device reported a disconnect"))
                    break
                if s.status & _STATUS_UNSTABLE:  # the device's passivity observer stopped its wall
                    reason = "unstable"
                    st["error"] = self._device_unstable_message(t)
                    break
                if frames % cfg.until_every == 0:
                    self.ticks = n
                    self.time_s = t
                    stop = self._stop_check(until)
                    if stop:
                        reason = stop
                        break
        finally:
            self.ticks = n
            self.time_s = t
            st.update(stop_reason=reason, ticks=n, n_logged=min(frames, cap), wrapped=frames > cap, li=li,
                      overruns=0, bad_samples=0, paced=True)

    # ------------------------------------------------------------------ result
    def _build_result(self, wall_s: float, cpu_s: float, realtime: bool) -> RunResult:
        st = self._stats
        n_logged = st.get("n_logged", 0)
        li = st.get("li", n_logged)
        log = {}
        for name, _, dtype, _ in LOG_CHANNELS:
            if name in self._log_ns:
                arr = np.frombuffer(self._log_ns[name], dtype=np.int64)
            else:
                arr = self._logf[LAW.LOG_COLUMNS.index(name)]
            if st.get("wrapped"):
                arr = np.concatenate([arr[li:], arr[:li]])
            else:
                arr = arr[:n_logged]
            # float64 channels are views of the log (a 30 s run's copies cost ~30 MB of page faults)
            log[name] = arr.astype(dtype, copy=False)
        ticks = st.get("ticks", 0)
        if st.get("compiled"):  # no per-tick clock inside a compiled chunk: no period or compute statistics
            periods = compute = np.zeros(0)
        else:
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
            "log_rate_hz": self.log_rate_hz,
            "achieved_rate_hz": ticks / wall_s if wall_s > 0 else 0.0,
            "realtime_factor": sim_time / wall_s if wall_s > 0 else 0.0,
            "realtime_factor_cpu": sim_time / cpu_s if cpu_s > 0 else 0.0,
            "realtime": realtime,
            "period_p50_us": pct(periods, 50),
            "period_p99_us": pct(periods, 99),
            "period_max_us": float(periods.max()) if len(periods) else 0.0,
            "period_error_p99_us": pct(np.abs(periods - period_us), 99),
            "period_error_p999_us": pct(np.abs(periods - period_us), 99.9),
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
            # law and physics in one compiled call (renderer.law.run_sim): no per-tick period or compute time
            "compiled_sim": bool(st.get("compiled", False)),
            # that call from the ahead-of-time build (renderer.sim_aot) rather than numba's JIT
            "aot": bool(st.get("aot", False)),
        }
        link_stats = getattr(self.device, "link_stats", None)
        if callable(link_stats):  # hardware links: frames, CRC errors, losses, longest gap, round trip
            timing["link"] = link_stats()
        # what the OS granted the servo (plumbing.rtpolicy) and whether the paced ticks met the thresholds
        timing["policy"] = st.get("policy") or rtpolicy.describe_current()
        if st.get("paced") and not timing["compiled_sim"] and not self.on_device:
            timing["timing_verdict"] = timing_verdict.verdict({**timing, "periods": len(periods)},
                                                              link=timing.get("link"))
        else:  # no per-tick clock of the servo here (compiled simulation, or the device's own loop)
            timing["timing_verdict"] = {"met": None, "failed": [], "thresholds":
                                        timing_verdict.DEFAULT_THRESHOLDS.to_dict()}
        info = self.info
        device = dataclasses.asdict(info) if dataclasses.is_dataclass(info) else {}
        device["limits_used"] = dict(self.limits)
        device["continuous_safe_A"] = self.continuous_safe_A
        return RunResult(events=list(self.events), log=log, timing=timing, stop_reason=st["stop_reason"],
                         config=self.cfg.to_dict(), device=device, transient=self.transient_name,
                         error=st.get("error", ""))
