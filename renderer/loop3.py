"""The 3-D servo loop: a point proxy in a scene of planes, spheres, boxes and meshes on any device.

``ServoLoop3(device, cfg, transient)`` renders ``cfg.scene`` (``renderer.scene``; its objects may carry their
own stiffness, friction and transient: ``SurfaceProps``) with the god-object proxy (``renderer.proxy``) and
the 3-D law (``renderer.law3``): per tick ``read()``, the law, ``command_force()``. On the 3-DOF simulated
device (``devices.sim.Sim3Device``), as fast as possible, law and physics run together in
``renderer.law3.run_sim3`` (from the ahead-of-time build when there is one for these sources,
``renderer.sim_aot``: then the process never imports numba). On a 1-axis device the endpoint is ``(0, 0, z)`` and only the force's z
reaches the motor (``Device.command_force``). A scene of horizontal walls only on a 3-axis device holds
x and y with a stiff virtual spring-damper (docs/architecture.md, "A 1-DOF scene on a 3-DOF device").

The output is zeroed on every exit path (``device.zero()`` in a ``finally``), a NaN never reaches a motor
(the law zeroes it, ``Device.command_force`` too), and a bad scene is refused before the device is opened.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

import stimuli
from plumbing import rtpolicy
from plumbing.stopsignals import holding, stop_if_signalled, stop_in, stop_on_signals

from . import law3_layout as L3
from . import proxy_layout as PX
from . import sim_aot
from .config import RendererConfig
from .loop import EVENT_COLUMNS, ContactEvent, RunResult, prefaulted_zeros, transient_name
from .passivity import passivity_constants
from .ring import same_sample_limit
from .safety import safety_bounds
from .scene import Wall
from .scene3 import O_K, STACK_DEPTH, pack_scene
from .velocity import ImpactVelocityEstimator, ls_constants

#: the hold channel of a 1-DOF scene on a 3-axis device (N/m, N s/m; at most half the device's stable bound)
HOLD_STIFFNESS_N_M = 2000.0
HOLD_DAMPING_N_S_M = 2.0
EVENT3_COLUMNS = EVENT_COLUMNS + ("object", "normal_x", "normal_y", "normal_z", "x_m", "y_m", "z_m")


@dataclass
class ContactEvent3(ContactEvent):
    """A contact event of the 3-D renderer: the proxy's new contact with ``object``.

    Besides :class:`renderer.loop.ContactEvent`'s fields (``incoming_velocity_m_s`` is the normal component
    ``v_n`` of the endpoint's velocity into the surface, ``max_penetration_m`` the deepest the endpoint
    went behind it), the object's name, the contact normal (device frame) and the endpoint at contact (m).
    """

    object: str = ""
    normal_x: float = 0.0
    normal_y: float = 0.0
    normal_z: float = 1.0
    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 0.0


@dataclass
class RunResult3(RunResult):
    """A 3-D run: ``log`` has ``renderer.law3.LOG_COLUMNS``; ``events`` are :class:`ContactEvent3`."""

    event_columns = EVENT3_COLUMNS


def surface_point_above(packed, name: str | None = None, xy_m=None) -> tuple[tuple, tuple, str]:
    """Where a person tapping straight down meets the scene: the first surface a vertical line crosses.

    Parameters
    ----------
    packed : renderer.scene3.PackedScene
    name : str or None
        The object to tap (its ``name``, or ``<shape><index>``); the line goes through its centre (x, y)
        unless ``xy_m`` is given. None: the line through ``xy_m`` (default the origin).

    Returns
    -------
    point_m, normal, object : the surface point (m), its outward normal, and the object's name.

    Raises
    ------
    ValueError
        An unknown name, or another object above it on that line.
    """
    if name is not None and name not in packed.names:
        raise ValueError(f"no object named {name!r} in the scene (objects: {', '.join(packed.names)})")
    if xy_m is None:
        if name is None:
            xy_m = (0.0, 0.0)
        else:
            j = packed.names.index(name)
            b = packed.bounds[j]
            o = packed.obj[j]
            xy_m = (0.5 * (b[0][0] + b[1][0]), 0.5 * (b[0][1] + b[1][1])) if b is not None else (o[5], o[6])
    x, y = float(xy_m[0]), float(xy_m[1])
    stack = np.zeros(STACK_DEPTH, dtype=np.int64)
    first_hit = sim_aot.loop3_kernels().first_hit
    t, j, nx, ny, nz, _, _, _, _, _, _ = first_hit(packed.obj, packed.tri, packed.node, stack, x, y, 1.0, x, y, -1.0)
    if j < 0:
        raise ValueError(f"nothing in the scene below ({x:g}, {y:g})")
    if name is not None and packed.names[j] != name:
        raise ValueError(f"{name!r} is covered by {packed.names[j]!r} at ({x:g}, {y:g})")
    return (x, y, 1.0 - 2.0 * t), (float(nx), float(ny), float(nz)), packed.names[j]


def make_object_transient(kind: str | None, library: str | None = None, gain: float | None = None):
    """A Table 4.1 transient by name (``none``, ``pulse``, ``sinusoid``, ``hfam`` with its ``library``)."""
    kw = {} if gain is None else {"gain": float(gain)}
    if kind in (None, "none"):
        return None
    if kind == "pulse":
        return stimuli.Pulse(**kw)
    if kind == "sinusoid":
        return stimuli.DecayingSinusoid(**kw)
    if kind == "hfam":
        return stimuli.HfamLibrary.load(library, **kw)
    raise ValueError(f"unknown transient {kind!r}")


class ServoLoop3:
    """The 3-D servo loop (module doc).

    Parameters
    ----------
    device : devices.base.Device
        Any device (1 or 3 axes); opened on demand, never closed here.
    cfg : RendererConfig
        ``scene`` (objects, their props), ``stiffness_N_m`` (objects without their own), rearm, limits.
    transient : stimuli transient or None
        The transient of objects that name none.
    compiled_sim : bool
        Run law and physics together on a ``Sim3Device`` (not paced).

    Attributes ``ticks``, ``time_s``, ``events`` are readable from an ``until`` callback; ``temp_rise_K`` (the
    winding model's, K) carries from one run to the next (a study's windows), as ``ServoLoop``'s does.
    """

    def __init__(self, device, cfg: RendererConfig | None = None, transient=None, compiled_sim: bool = True):
        self.device = device
        self.cfg = cfg if cfg is not None else RendererConfig()
        self.transient = transient
        self.compiled_sim = bool(compiled_sim)
        self.events: list[ContactEvent3] = []
        self.ticks = 0
        self.time_s = 0.0
        self.result = None
        self.stop_requested = False
        self.packed = None
        #: the winding model's temperature rise (K): the config's at first, then where the last run left it
        self.temp_rise_K = self.cfg.initial_temp_rise_K

    # ---------------------------------------------------------------- set-up
    def prepare(self) -> None:
        """Check the scene against the device and build the arrays; ValueError (file, object) before any motion."""
        cfg, info = self.cfg, self.device.info
        self.info = info
        # the compiled law, proxy and (on the simulated device) physics: ahead of time or JIT (renderer.sim_aot)
        self.kernels = kn = sim_aot.loop3_kernels()
        if kn.tick is not None and callable(getattr(self.device, "use_compiled_step", None)):
            self.device.use_compiled_step(kn.tick)
        self.specs = specs = info.specs()
        fs = float(cfg.rate_hz) if cfg.rate_hz is not None else float(info.servo_rate_hz)
        if info.simulated and abs(fs - info.servo_rate_hz) > 1e-9 * fs:
            raise ValueError(f"rate_hz={fs:g} differs from the sim device's servo_rate_hz={info.servo_rate_hz:g}")
        self.fs_hz, self.dt_s = fs, 1.0 / fs
        self.scene = scene = cfg.effective_scene
        catalog = None
        packed = pack_scene(scene, cfg.stiffness_N_m, specs if specs.axes == 3 else None)
        transients = []
        for j, pr in enumerate(packed.props):
            where = f"{scene.source}.objects[{j}] ({packed.names[j]})"
            tr = self.transient
            if pr is not None and pr.sample:
                catalog = catalog if catalog is not None else {c.name: c for c in stimuli.load_catalog()}
                smp = catalog.get(pr.sample)
                if smp is None or smp.kind != "virtual":
                    raise ValueError(f"{where}: sample {pr.sample!r} is not a virtual sample of the catalog "
                                     f"(known: {', '.join(n for n, c in catalog.items() if c.kind == 'virtual')})")
                if packed.obj[j, O_K] < 0:
                    packed.obj[j, O_K] = smp.stiffness_N_m
                tr = smp.make_transient() if pr.transient is None else tr
            if pr is not None and pr.transient is not None:
                try:
                    tr = make_object_transient(pr.transient, pr.library)
                except (OSError, ValueError) as exc:
                    raise ValueError(f"{where}: {exc}") from None
            k = packed.obj[j, O_K]
            if k > specs.max_stiffness_N_m:
                raise ValueError(f"{where}: stiffness {k:g} N/m is above the device's stable bound "
                                 f"{specs.max_stiffness_N_m:g} N/m")
            if tr is not None:
                tr.check_device(info, fs)
            transients.append(tr)
        self.packed, self.transients = packed, transients
        self.names = packed.names
        self.nbuf = max(1, int(math.ceil(cfg.max_transient_s * fs - 1e-9)))
        for tr in transients:
            if tr is not None and tr.max_samples(fs) > self.nbuf:
                raise ValueError(f"transient {transient_name(tr)!r} is longer than max_transient_s={cfg.max_transient_s}")
        self.kf = info.force_per_amp_N_A
        self.w_vel = max(2, int(round(cfg.velocity_window_s * fs)))
        self.impact = [ImpactVelocityEstimator(self.dt_s, specs.position_resolution_m, cfg.impact_min_window_s,
                                               cfg.impact_window_s, cfg.impact_counts) for _ in range(3)]
        self.nring = max(self.w_vel, self.impact[0].history)
        self.tbuf_at = L3.W_RING + 6 * self.nring
        self.w = np.zeros(self.tbuf_at + self.nbuf)
        for a in range(3):
            self.impact[a].bind(self.w[L3.W_RING + 2 * a * self.nring:L3.W_RING + 2 * (a + 1) * self.nring])
        self.tview = self.w[self.tbuf_at:]
        self.stack = np.zeros(STACK_DEPTH, dtype=np.int64)
        self.hold = specs.axes == 3 and all(isinstance(o, Wall) and (o.props is None or o.props.is_default())
                                            for o in scene.objects)
        self.c = self._constants()

    def _constants(self) -> np.ndarray:
        cfg, info, fs, specs = self.cfg, self.info, self.fs_hz, self.specs
        b = safety_bounds(info, fs, cfg)
        c = np.zeros(L3.N_C)
        # the wall channel's continuous force: the thermally safe continuous current's on a 1-DOF drive
        f_c = min(specs.max_force_N, b.continuous_safe_A * self.kf) if cfg.current_continuous_A is None else \
            min(specs.max_force_N, cfg.current_continuous_A * self.kf)
        f_pk = specs.max_peak_force_N if cfg.current_peak_A is None else min(specs.max_peak_force_N,
                                                                           cfg.current_peak_A * self.kf)
        c[L3.C_FC], c[L3.C_FPK], c[L3.C_INV_KF] = f_c, f_pk, 1.0 / self.kf
        c[L3.C_MARGIN], c[L3.C_HOLD_N] = cfg.rearm_margin_m, max(1, int(round(cfg.rearm_hold_s * fs)))
        c[L3.C_MOTOR] = 1.0 if cfg.motor_enabled else 0.0
        c[L3.C_PLIM], c[L3.C_MAX_BAD] = b.position_limit_m, b.max_bad_samples
        c[L3.C_AMIN], c[L3.C_AMAX] = -b.accel_limit_m_s2, b.accel_limit_m_s2
        c[L3.C_GMIN], c[L3.C_GMAX] = b.grip_min_N, b.grip_max_N
        c[L3.C_WV], c[L3.C_NRING], c[L3.C_FS] = self.w_vel, self.nring, fs
        c[L3.C_SAME_MAX] = same_sample_limit(cfg, fs, self.nring)
        c[L3.C_C_SHIFT], c[L3.C_C_SCALE] = ls_constants(self.w_vel, self.dt_s)
        c[L3.C_TBUF] = self.tbuf_at
        k_max = float(np.max(self.packed.obj[:, O_K]))
        c[L3.C_PO_DECAY], c[L3.C_PO_LIMIT] = passivity_constants(cfg.replace(stiffness_N_m=k_max), self.dt_s, f_c)
        c[L3.C_HEAT], c[L3.C_ALPHA] = b.heat_K_A2, b.alpha
        c[L3.C_T_ATT], c[L3.C_T_END] = b.t_attenuate_K, b.t_end_K
        c[L3.C_INV_SPAN] = 1.0 / (b.t_end_K - b.t_attenuate_K)
        c[L3.C_DEV_FPK] = specs.max_peak_force_N
        c[L3.C_HOLD_ON] = 1.0 if self.hold else 0.0
        c[L3.C_HOLD_K] = min(HOLD_STIFFNESS_N_M, 0.5 * specs.max_stiffness_N_m)
        c[L3.C_HOLD_B] = HOLD_DAMPING_N_S_M
        return c

    def _prime(self) -> None:
        """Zero force, then the law's initial state (:meth:`_prime_state`). On a real device the law's first call
        (numba's compile or cache load: seconds on a cold cache, far beyond the host watchdog) is made here, on
        scratch copies, and the state primed again after it, so that no time passes between the priming read and
        the first paced tick."""
        self._prime_state()
        if self.info.simulated:
            return
        scratch_log = np.zeros((L3.N_LOG, 1))
        s = self.device.read()
        pk = self.packed
        self.kernels.law3_tick(self.c, self.w.copy(), pk.obj, pk.tri, pk.node, self.stack.copy(), scratch_log,
                               s.t_s, s.x_m, s.y_m, s.position_m, 0.0, s.grip_N, 0)
        self._prime_state()

    def _prime_state(self) -> None:
        """Zero force, then the law's initial state: rings, proxy at the endpoint (or the nearest outside point)."""
        dev, w, c = self.device, self.w, self.c
        dev.read()
        dev.command_force(0.0, 0.0, 0.0)
        s = dev.read()
        x, y, z = s.x_m, s.y_m, s.position_m
        w[:L3.W_RING] = 0.0
        nr, wv = self.nring, self.w_vel
        for a, p in enumerate((x, y, z)):
            w[L3.W_RING + 2 * a * nr:L3.W_RING + 2 * (a + 1) * nr] = p
        w[L3.W_S0X], w[L3.W_S1X] = wv * x, x * wv * (wv - 1) / 2.0
        w[L3.W_S0Y], w[L3.W_S1Y] = wv * y, y * wv * (wv - 1) / 2.0
        w[L3.W_S0Z], w[L3.W_S1Z] = wv * z, z * wv * (wv - 1) / 2.0
        w[L3.W_PI], w[L3.W_PO] = 0, (0 - wv) % nr
        w[L3.W_TRING] = s.t_s         # the primed rings' newest slot is this sample, at its time
        w[L3.W_LX], w[L3.W_LY], w[L3.W_LZ] = x, y, z
        w[L3.W_LAST_GRIP] = s.grip_N if c[L3.C_GMIN] <= s.grip_N <= c[L3.C_GMAX] else 0.0
        w[L3.W_PO_X], w[L3.W_PO_Y], w[L3.W_PO_Z] = x, y, z
        w[L3.W_HX], w[L3.W_HY] = x, y
        w[L3.W_GTH] = 1.0
        w[L3.W_ENZ] = w[L3.W_LNZ] = 1.0
        ps = w[L3.W_PS:L3.W_PS + PX.N_PS]
        ps[:] = 0.0
        pk = self.packed
        # start outside: from far above the scene straight down to the endpoint (a start inside an object
        # leaves the proxy on its surface, and the run starts in contact, unarmed)
        ps[PX.PS_PX], ps[PX.PS_PY], ps[PX.PS_PZ] = x, y, z + 1.0
        n_c = self.kernels.proxy_step(pk.obj, pk.tri, pk.node, self.stack, ps, x, y, z)
        w[L3.W_ARMED] = 1.0 if n_c == 0 else 0.0
        ps[PX.PS_NC] = 0.0
        w[L3.W_TEMP] = self.temp_rise_K     # the winding's temperature rise carried from the last run

    # ---------------------------------------------------------------- run
    def run(self, duration_s: float | None = None, until=None, realtime: bool | None = None,
            max_ticks: int | None = None) -> RunResult3:
        """Run (as :meth:`renderer.loop.ServoLoop.run`); returns a :class:`RunResult3`. Zero on every exit."""
        with stop_on_signals():
            return self._run(duration_s, until, realtime, max_ticks)

    def _run(self, duration_s, until, realtime, max_ticks) -> RunResult3:
        if getattr(self, "packed", None) is None:   # prepared once: the scene does not change under a loop
            self.prepare()
        dev = self.device
        if not dev.is_open:
            dev.open()
        if realtime is None:
            realtime = not self.info.simulated
        limit = math.inf if duration_s is None else int(round(duration_s * self.fs_hz))
        if max_ticks is not None:
            limit = min(limit, int(max_ticks))
        cap = max(1, int(round(self.cfg.log_capacity_s * self.fs_hz)))
        if limit != math.inf:
            cap = max(1, min(cap, int(limit)))
        self.cap = cap
        self.c[L3.C_CAP] = cap
        self.log = prefaulted_zeros((L3.N_LOG, cap))     # no first-touch page faults inside the loop
        self.events = []
        self._ev = None
        self.stop_requested = False
        compiled = self.compiled_sim and not realtime and callable(getattr(dev, "fused3", None))
        st = {"stop_reason": "exception", "error": "", "compiled": compiled}
        self._prime()
        stop_if_signalled()
        wall0, cpu0 = time.perf_counter(), time.process_time()
        self._n = 0
        failure = None
        # the cyclic collector paused for the paced ticks, as the 1-DOF loop does (plumbing.rtpolicy): a collection
        # in a large process walks its objects for tens to hundreds of milliseconds, past the host watchdog
        gc_pause = rtpolicy.gc_paused() if realtime and not compiled else contextlib.nullcontext()
        try:
            with gc_pause:
                st["stop_reason"] = (self._run_compiled(limit, until) if compiled
                                     else self._run_ticks(limit, until, realtime))
        except BaseException as exc:
            exc = stop_in(exc) or exc   # a stop that Python wrapped (a signal inside an import) is a stop
            st["stop_reason"] = "interrupted" if isinstance(exc, (KeyboardInterrupt, SystemExit)) else "exception"
            st["error"] = f"{type(exc).__name__}: {exc}"
            failure = exc
        with holding():
            try:
                dev.zero()
            finally:
                self.result = self._build_result(time.perf_counter() - wall0, time.process_time() - cpu0, st,
                                                 bool(realtime))
        if failure is not None:
            raise failure
        return self.result

    def _stop(self, until) -> str:
        stop_if_signalled()
        if self.stop_requested:
            return "stopped"
        if until is not None and until(self):
            return "until"
        return ""

    def _law_stop(self, code: int) -> tuple[str, str]:
        if code & L3.CODE_DISCONNECTED:
            return "disconnected", str(self.device.read().extra.get("error", "device reported a disconnect"))
        if code & L3.CODE_UNSTABLE:
            return "unstable", (f"the wall generated {self.w[L3.W_PO_E] * 1e3:.3g} mJ net (limit "
                                f"{self.c[L3.C_PO_LIMIT] * 1e3:.3g} mJ) at tick {self._n}: the loop is unstable; "
                                "output zeroed. Lower the stiffness or add damping")
        return "sensor", f"{int(self.w[L3.W_NBAD])} invalid sensor samples in a row at tick {self._n}"

    def _run_ticks(self, limit, until, realtime: bool) -> str:
        dev, c, w, log = self.device, self.c, self.w, self.log
        pk, stack = self.packed, self.stack
        read, command = dev.read, dev.command_force
        tick, clock = self.kernels.law3_tick, time.perf_counter_ns
        period = int(round(1e9 / self.fs_hz))
        deadline = prev = clock()
        # the host watchdog of a real device (not a simulation's): a period this much over nominal stops the run
        wd_ns = None if self.info.simulated else period + int(self.cfg.watchdog_overrun_s * 1e9)
        every = int(self.cfg.until_every)
        n = 0
        reason = "duration"
        while n < limit:
            if realtime:
                deadline += period
                rem = deadline - clock()
                if rem > 100_000:
                    time.sleep((rem - 80_000) * 1e-9)
                while clock() < deadline:
                    pass
            s = read()
            now = clock()
            if wd_ns is not None and n and now - prev > wd_ns:
                dev.zero()
                self._err = f"tick {n} period {(now - prev) / 1000:.0f} us exceeds the watchdog bound"
                reason = "watchdog"
                break
            prev = now
            fx, fy, fz = tick(c, w, pk.obj, pk.tri, pk.node, stack, log, s.t_s, s.x_m, s.y_m, s.position_m,
                              s.accel_m_s2, s.grip_N, s.status)
            code = int(w[L3.W_CODE])
            if code >= 4:
                dev.zero()
                reason, self._err = self._law_stop(code)
                break
            command(fx, fy, fz)
            n += 1
            self._n = n
            if code:
                self._after_command(code, n - 1)
            if n % every == 0:
                self.ticks, self.time_s = n, float(w[L3.W_T])
                stop = self._stop(until)
                if stop:
                    reason = stop
                    break
        return reason

    def _run_compiled(self, limit, until) -> str:
        dev, c, w, log = self.device, self.c, self.w, self.log
        pk, stack = self.packed, self.stack
        every = int(self.cfg.until_every) if until is not None else 10_000
        n = 0
        reason = "duration"
        tap = dev.tap
        run_sim3 = self.kernels.run_sim3
        while n < limit:
            sp, ss, srs, traj, grip, lat, lp, frame, igrav = dev.fused3()
            dv = tap.fused_state()
            span = tap.fused_span()
            k = run_sim3(c, w, pk.obj, pk.tri, pk.node, stack, log, dv, sp, ss, srs, traj, grip, lat, lp, frame,
                            igrav, int(min(every, limit - n, max(span, 1))))
            tap.fused_sync(dv)
            dev._refresh()
            n += k
            self._n = n
            code = int(w[L3.W_CODE])
            if code >= 4:
                dev.zero()
                reason, self._err = self._law_stop(code)
                break
            if code:
                self._after_command(code, n - 1)
            self.ticks, self.time_s = n, float(w[L3.W_T])
            stop = self._stop(until)
            if stop:
                reason = stop
                break
        return reason

    def _after_command(self, code: int, n: int) -> None:
        """The event's work after the command: close the open event; on an impact the normal velocity
        ``v_n``, the contacted object's transient written into the buffer (force, N), the event record."""
        w = self.w
        if code & L3.CODE_CLOSED and self._ev is not None:
            ev = self._ev
            ev.max_penetration_m, ev.peak_accel_m_s2 = float(w[L3.W_CLOSED_PEN]), float(w[L3.W_CLOSED_ACC])
            ev.clipped = bool(w[L3.W_CLOSED_CLIP])
            self._ev = None
        if not code & L3.CODE_IMPACT:
            return
        j = int(w[L3.W_EV_OBJ])
        nx, ny, nz = float(w[L3.W_LNX]), float(w[L3.W_LNY]), float(w[L3.W_LNZ])
        newest = int(w[L3.W_PNEW])
        rough = float(w[L3.W_VX]) * nx + float(w[L3.W_VY]) * ny + float(w[L3.W_VZ]) * nz
        v = [est.at(newest, rough) for est in self.impact]
        v_n = -(v[0] * nx + v[1] * ny + v[2] * nz)
        if v_n < 0.0:
            v_n = 0.0
        g_th, grip = float(w[L3.W_GTH]), float(w[L3.W_GRIP])
        tr = self.transients[j]
        tlen = 0
        gain = self.cfg.transient_gain * g_th
        if tr is not None and gain > 0.0 and self.cfg.motor_enabled:
            view = self.tview
            into = getattr(tr, "current_into", None)
            if callable(into):
                tlen = min(int(into(v_n, grip, view)), self.nbuf)
                view[:tlen] *= gain * tr.force_per_amp_N_A
            else:
                wave = np.asarray(tr.waveform(v_n, grip, self.fs_hz), dtype=np.float64)
                tlen = min(len(wave), self.nbuf)
                np.multiply(wave[:tlen], gain, out=view[:tlen])
            if tlen and not np.isfinite(view[:tlen].sum()):
                np.nan_to_num(view[:tlen], copy=False, nan=0.0, posinf=0.0, neginf=0.0)
        w[L3.W_TLEN] = tlen
        w[L3.W_TJ] = 0.0
        self._ev = ContactEvent3(t_s=float(w[L3.W_T]), incoming_velocity_m_s=v_n, grip_N=grip,
                                 transient=transient_name(tr), tick=n, transient_samples=tlen, thermal_gain=g_th,
                                 object=self.names[j], normal_x=nx, normal_y=ny, normal_z=nz,
                                 x_m=float(w[L3.W_LX]), y_m=float(w[L3.W_LY]), z_m=float(w[L3.W_LZ]))
        self.events.append(self._ev)

    def _build_result(self, wall_s: float, cpu_s: float, st: dict, realtime: bool) -> RunResult3:
        n = self._n
        w = self.w
        self.temp_rise_K = float(w[L3.W_TEMP])
        if self._ev is not None:
            self._ev.max_penetration_m, self._ev.peak_accel_m_s2 = float(w[L3.W_EV_PEN]), float(w[L3.W_EV_ACC])
            self._ev.clipped = bool(w[L3.W_EV_CLIP])
        li = int(w[L3.W_LI])
        wrapped = n > self.cap
        log = {}
        for r, name in enumerate(L3.LOG_COLUMNS):
            row = self.log[r]
            row = np.concatenate([row[li:], row[:li]]) if wrapped else row[:min(n, self.cap)]
            # float64 channels are views of the log; the integer ones narrowed (as the 1-DOF log's flags)
            log[name] = row.astype(L3.LOG_INT_DTYPES[name]) if name in L3.LOG_INT_DTYPES else row
        sim = n / self.fs_hz
        timing = {"sim_time_s": sim, "wall_time_s": wall_s, "ticks": n, "rate_hz": self.fs_hz,
                  "log_rate_hz": self.fs_hz, "realtime_factor": sim / wall_s if wall_s > 0 else 0.0,
                  "realtime_factor_cpu": sim / cpu_s if cpu_s > 0 else 0.0, "realtime": realtime,
                  "cpu_time_s": cpu_s, "log_wrapped": wrapped, "compiled_sim": bool(st.get("compiled")),
                  "aot": bool(self.kernels.aot),
                  "bad_sensor_samples": int(w[L3.W_BAD_TOTAL]), "max_temp_rise_K": float(w[L3.W_TEMP]),
                  "peak_passivity_energy_J": float(np.max(w[L3.W_PO_E:L3.W_PO_E + 1])),
                  "renderer": "3d", "objects": list(self.names), "hold_channel": bool(self.hold),
                  "force_limits_N": {"continuous": float(self.c[L3.C_FC]), "peak": float(self.c[L3.C_FPK])}}
        device = dataclasses.asdict(self.info) if dataclasses.is_dataclass(self.info) else {}
        return RunResult3(events=list(self.events), log=log, timing=timing,
                          stop_reason=st["stop_reason"], config=self.cfg.to_dict(), device=device,
                          transient=transient_name(self.transient), error=st.get("error") or getattr(self, "_err", ""))
