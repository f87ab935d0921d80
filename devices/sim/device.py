"""The simulated haptic device (thesis chapter 3): nonlinear (sec. 3.5.4) or Phantom-like LTI (sec. 3.4.4).

Servo cycle: ``state = dev.read()`` then ``dev.command(i)``. ``command()``
advances the physics by one servo period ``1/info.servo_rate_hz`` (all
internal substeps in one numba call); the current commanded at tick k is
applied (zero-order hold) during the period after the next ``command()``,
i.e. one servo cycle of output delay. ``read()`` returns the same
:class:`DeviceState` object, updated in place by ``command()``.

The simulated hand's plan (desired position and grip per servo tick) is
streamed: the device holds a window of :data:`PLAN_WINDOW_TICKS` ticks of it
and computes the next window (``TapTrajectory.sample_range``) when the ticks
reach its end, in ``command()`` or between the chunks of a compiled loop
(:meth:`SimDevice.fused_span`), so memory does not grow with the number of
taps. The kernel sees the same numbers as with the whole plan
(windows overlap by a tick and the last one ends where the plan does).
"""

from __future__ import annotations

import math
import sys
from operator import itemgetter

import numpy as np

from ..base import Device, DeviceState, Status
from . import layout as K
from .hand import HoldTrajectory, ReactiveHand, sample_grip
from .mechconfig import ASSEMBLED, LOCKED_MASS_KG, get_config
from .params import SimParams, default_params, load_sim_params
from .person import DEFAULT_PERSON, PRESCRIBED, Person
from .presets import PRESETS, preset_params
from .samples import KIND_BLOCK_ON_FOAM, get_sample

_HOT = int(Status.OVER_TEMPERATURE)
#: ticks of the hand's plan held at once (position and grip, 16 bytes a tick: 1 MB; 6.6 s at 10 kHz); a plan
#: that fits is held whole, as before streaming
PLAN_WINDOW_TICKS = 1 << 16
#: the fields of the ``D_*`` vector that :meth:`SimDevice.fused_sync` takes back, in one call
_SYNCED = itemgetter(K.D_TICK, K.D_HELD, K.D_REJECTED, K.D_LAST, K.D_STATUS, K.D_POS, K.D_ACC, K.D_GRIP, K.D_T)


def _kernel_tick():
    """The compiled physics step ``devices.sim.kernel.tick``.

    Imported at a device's first :meth:`SimDevice.command`, not with this module: a simulated run whose
    servo loop was compiled ahead of time (``renderer.sim_aot``) never calls it and starts without numba.
    """
    from . import kernel  # deferred: numba and the cached kernels, 0.3 s CPU; a run compiled ahead of time never needs it

    return kernel.tick


class SimDevice(Device):
    """Simulated 1-DOF impedance-type haptic device with a simulated user and sample.

    Parameters
    ----------
    params : SimParams or None
        Validated parameters; None gives Table 3.1 (``default_params.toml``).
    seed : int
        Seed of the accelerometer noise generator (reproducible runs).
    sample : str
        Initial sample under the stylus (default ``"placeholder"``: none).
    """

    def __init__(self, params: SimParams | None = None, seed: int = 0, sample: str = "placeholder"):
        super().__init__()
        self.params = default_params() if params is None else params
        self.info = self.params.device_info()
        self._period_s = 1.0 / self.info.servo_rate_hz
        self._limit_A = self.info.current_amplifier_A
        self._tick_fn = None    # devices.sim.kernel.tick, loaded at the first command (numba: ~0.3 s)
        self._s = np.zeros(K.N_STATE)
        self._p = self._build_param_array()
        # xorshift must not start at 0; mix the seed so nearby seeds differ
        self._rs = np.array([(int(seed) * 0x9E3779B97F4A7C15 + 0x2545F4914F6CDD1D) % (1 << 64) or 1],
                            dtype=np.uint64)
        self._state = DeviceState()
        self._tick = 0
        self._user_tick = 0
        self._held_A = 0.0
        self._traj = np.zeros(1)        # the window of the hand's plan: ticks _plan_lo.. (see _plan_fill)
        self._grip = np.zeros(1)
        self._traj_ticks = 0
        self._positions = lambda lo, hi: np.zeros(max(0, min(hi, 1) - lo))
        self._grip_N = 0.0
        self._plan_n = 1
        self._plan_lo = 0
        self._plan_kmin = 0
        self._plan_kmax = sys.maxsize
        self._plan_base = 0                 # _user_tick + _plan_lo: command()'s index into the window
        self._plan_tick_max = sys.maxsize   # the last device tick the window serves
        #: bumped by whatever changes what :meth:`fused_arrays`, :meth:`fused_state` or :meth:`fused_span`
        #: return (a command, a new user, sample, plan window...), so that a compiled loop fetches them again
        #: between its chunks only when they changed (:attr:`fused_version`)
        self._fused_version = 0
        self.trajectory = None
        self.hand = PRESCRIBED
        self.sample_name = "placeholder"
        self.mechanical_config = ASSEMBLED
        self.set_sample(sample)
        self._refresh_state()

    # -- construction --------------------------------------------------------
    @classmethod
    def from_spec(cls, spec: str | None = None, seed: int = 0, **options) -> "SimDevice":
        """Device from the part after ``sim:`` of a device string.

        ``None``/``""``: Table 3.1 nonlinear model (the joystick); a named device of
        :data:`devices.sim.presets.PRESETS` (``"joystick"``, ``"onedof"``: the section 4.4.3 one-dof
        testbed, ``"lti"``: Phantom-like LTI model); anything else: a ``.toml``/``.json`` parameter file.
        """
        if spec in (None, "", "nonlinear"):
            params = default_params("nonlinear")
        elif spec in PRESETS:
            params = preset_params(spec)
        else:
            try:
                params = load_sim_params(spec)
            except FileNotFoundError:
                raise FileNotFoundError(f"sim parameter file not found: {spec!r} (valid device strings: sim, "
                                        + ", ".join(f"sim:{n}" for n in PRESETS)
                                        + ", sim:<params file .toml|.json>)") from None
        return cls(params, seed=seed, **options)

    def _build_param_array(self) -> np.ndarray:
        pr = self.params
        p = np.zeros(K.N_PARAM)
        n_sub = max(1, math.ceil(self._period_s / pr.simulation["max_step_s"] - 1e-9))
        dt = self._period_s / n_sub
        p[K.P_MODEL] = 1.0 if pr.model == "lti" else 0.0
        p[K.P_DT] = dt
        p[K.P_NSUB] = n_sub
        p[K.P_KF] = self.info.force_per_amp_N_A
        p[K.P_AMP_LOWPASS] = 1.0 if pr.amplifier["kind"] == "lowpass" else 0.0
        p[K.P_AMP_ALPHA] = 1.0 - math.exp(-2 * math.pi * pr.amplifier["bandwidth_hz"] * dt)
        p[K.P_IMAX] = self.info.current_amplifier_A
        u = pr.user
        p[K.P_KU_PER_N] = u["k_u_N_m"] / u["nominal_grip_N"]
        p[K.P_BU_PER_N] = u["b_u_Ns_m"] / u["nominal_grip_N"]
        p[K.P_VSTICK] = pr.simulation["stick_velocity_m_s"]
        se = pr.sensors
        p[K.P_ACC_BETA] = 1.0 - math.exp(-2 * math.pi * se["accel_bandwidth_hz"] * dt)
        p[K.P_ACC_RES] = se["accel_resolution_m_s2"]
        p[K.P_ACC_NOISE] = se["accel_noise_m_s2"]
        p[K.P_ACC_RANGE] = se["accel_range_m_s2"]
        p[K.P_GRIP_RES] = se["grip_resolution_N"]
        p[K.P_GRIP_MAX] = se["grip_max_N"]
        p[K.P_ENC_RES] = self.info.position_resolution_m
        p[K.P_THERM_A] = math.exp(-self._period_s / self.info.thermal_time_constant_s)
        p[K.P_THERM_GAIN] = self.info.winding_resistance_ohm * self.info.thermal_resistance_K_W
        p[K.P_MOTOR_ON] = 1.0
        p[K.P_TEMP_MAX] = self.info.winding_max_temp_rise_K
        if pr.model == "nonlinear":
            m = pr.mechanics
            for idx, key in ((K.P_MM, "m_m_kg"), (K.P_BM, "b_m_Ns_m"), (K.P_CM, "c_m_N"), (K.P_KC, "k_c_N_m"),
                             (K.P_BC, "b_c_Ns_m"), (K.P_MD, "m_d_kg"), (K.P_BD, "b_d_Ns_m"), (K.P_CD, "c_d_N"),
                             (K.P_KLP, "k_lp_N_m"), (K.P_KLN, "k_ln_N_m"), (K.P_FLP, "f_lp_N"),
                             (K.P_FLN, "f_ln_N"), (K.P_GAMMA, "gamma_l_rad_m"), (K.P_BL, "b_l_Ns_m"),
                             (K.P_MH, "m_h_kg")):
                p[idx] = m[key]
            p[K.P_HYST] = 1.0 if m["hysteresis"] else 0.0
        else:
            p[K.P_MH] = pr.lti["handle_mass_kg"]
            ad, bd, cd, dd = _linear().lti_transmission_zoh(pr.lti, dt)
            n = ad.shape[0]
            if n > K.LTI_MAX_ORDER:
                raise ValueError(f"{pr.source}: LTI transmission order {n} exceeds {K.LTI_MAX_ORDER}")
            p[K.P_LTI_N] = n
            o = K.P_LTI_MATS
            p[o:o + n * n] = ad.ravel()
            p[o + n * n:o + n * n + n] = bd.ravel()
            p[o + n * n + n:o + n * n + 2 * n] = cd.ravel()
            p[o + n * n + 2 * n] = dd.ravel()[0]
        return p

    # -- Device hooks --------------------------------------------------------
    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _send_current(self, current_A: float) -> None:
        # used by open/close/zero: replaces the current that the next period applies
        self._held_A = current_A
        self._fused_version += 1

    def read(self) -> DeviceState:
        """The state sample at ``time_s`` (same object every call)."""
        return self._state

    def command(self, current_A: float) -> None:
        """Command motor current (A) and advance the simulation by one servo period.

        Same safety as :meth:`Device.command` (NaN/inf -> 0 and counted,
        clamp to the amplifier limit): ``devices.sim.kernel.command_rule``, which the compiled servo
        loop (``renderer.law.run_sim``) also applies.
        """
        current_A, status, rejected = K.command_rule(current_A, self._limit_A)
        if rejected:
            self.rejected_commands += 1
        self.last_command_A = current_A
        applied = self._held_A
        self._held_A = current_A
        tick = self._tick + 1
        self._tick = tick
        self._fused_version += 1
        fn = self._tick_fn
        if fn is None:
            fn = self._tick_fn = _kernel_tick()
        if tick > self._plan_tick_max:       # the plan's window is used up (ticks only go forward)
            self._plan_fill(tick - 1 - self._user_tick)
        pos, acc, grip, hot = fn(self._s, self._p, self._rs, self._traj, self._grip, tick - 1 - self._plan_base,
                                 applied)
        st = self._state
        st.t_s = tick * self._period_s
        st.position_m = pos
        st.accel_m_s2 = acc
        st.grip_N = grip
        st.status = status | _HOT if hot else status

    def use_compiled_step(self, step) -> None:
        """Advance the physics in :meth:`command` with ``step``: ``devices.sim.kernel.tick`` itself, compiled
        elsewhere (ahead of time, ``renderer.sim_aot``), so that a process that runs it needs no numba.
        Same signature and results; the loop that supplies it checks it was built from this kernel's source."""
        if not callable(step):
            raise ValueError(f"use_compiled_step needs a callable (devices.sim.kernel.tick), got {step!r}")
        self._tick_fn = step

    # -- the compiled servo loop (renderer.law.run_sim) ------------------------
    def fused_plan(self, ticks: int | None = None) -> tuple:
        """The hand's plan as ``devices.sim.kernel.tick`` indexes it, for the next ``ticks`` ticks.

        Parameters
        ----------
        ticks : int or None
            How many ticks from now the arrays must cover (a window that large is computed if needed);
            None: at least the next one (then :meth:`fused_span` says how many).

        Returns
        -------
        traj, grip : ndarray float64
            The window of desired positions (m) and grips (N).
        k : int
            The kernel's index of the next tick into them.
        """
        k = self._tick - self._user_tick
        last = k if ticks is None else k + max(int(ticks), 1) - 1
        if k < self._plan_kmin or last > self._plan_kmax:
            self._plan_fill(k, ticks)
        return self._traj, self._grip, k - self._plan_lo

    def fused_arrays(self, ticks: int | None = None) -> tuple:
        """The physics arrays of ``devices.sim.kernel.tick`` (params, state, noise state, trajectory,
        grip), advanced in place by a compiled loop that stands in for :meth:`command` calls.

        The trajectory and grip are the plan's window from the current tick (:meth:`fused_plan`): a loop
        runs at most :meth:`fused_span` ticks (or the ``ticks`` asked for) on them, then asks again."""
        traj, grip, _ = self.fused_plan(ticks)
        return self._p, self._s, self._rs, traj, grip

    @property
    def fused_version(self) -> int:
        """A counter that changes whenever what :meth:`fused_arrays`, :meth:`fused_state` and :meth:`fused_span`
        return may have changed through this device's methods (a command, a new user or sample, the plan's
        next window, a mechanical configuration, ``motor_enabled``), but not when a compiled loop advanced
        the state it took (:meth:`fused_sync`). A loop that finds it unchanged between its chunks keeps the
        arrays, the state vector and the span it holds (the span counted down by the ticks it ran); private
        attributes written directly do not change it."""
        return self._fused_version

    def fused_span(self) -> int:
        """Ticks from the current one that the arrays of :meth:`fused_arrays` cover (very large once they
        hold the end of the plan, after which the hand holds its last position)."""
        return max(0, self._plan_kmax - (self._tick - self._user_tick) + 1)

    def fused_state(self) -> np.ndarray:
        """The Python-side state that :meth:`command` keeps, as the ``D_*`` vector of :mod:`devices.sim.layout`.

        ``D_USER_TICK`` is offset by the start of the plan's window (:meth:`fused_plan`), so that a compiled
        loop's ``tick - 1 - D_USER_TICK`` indexes the window's arrays."""
        self.fused_plan()
        st = self._state
        return np.array([self._tick, self._user_tick + self._plan_lo, self._held_A, self._limit_A, self._period_s,
                         self.rejected_commands, self.last_command_A, st.status, st.position_m, st.accel_m_s2,
                         st.grip_N, st.t_s], dtype=np.float64)

    def fused_sync(self, d: np.ndarray) -> None:
        """Take back the state a compiled loop advanced (the inverse of :meth:`fused_state`)."""
        # one conversion of the whole vector to Python floats (the same values as float(d[i]) one by one, at
        # a fraction of the cost: a compiled loop syncs between every few ticks' chunks)
        tick, self._held_A, rejected, self.last_command_A, status, pos, acc, grip, t = _SYNCED(d.tolist())
        self._tick = int(tick)
        self.rejected_commands = int(rejected)
        st = self._state
        st.status = int(status)
        st.position_m, st.accel_m_s2, st.grip_N, st.t_s = pos, acc, grip, t

    # -- simulation controls -------------------------------------------------
    @property
    def time_s(self) -> float:
        """Simulated time (s) of the current state sample."""
        return self._tick * self._period_s

    @property
    def motor_enabled(self) -> bool:
        """False: commands are ignored (zero motor current), e.g. for real-sample taps."""
        return bool(self._p[K.P_MOTOR_ON] != 0.0)

    @motor_enabled.setter
    def motor_enabled(self, on: bool) -> None:
        """False: commands are ignored (zero motor current), e.g. for real-sample taps."""
        self._p[K.P_MOTOR_ON] = 1.0 if on else 0.0
        self._fused_version += 1

    @property
    def trajectory_done(self) -> bool:
        """True when the simulated hand has finished its trajectory (always True with no trajectory)."""
        return self._tick - self._user_tick >= self._traj_ticks

    @property
    def in_contact(self) -> bool:
        """True if the handle touched the sample during the last servo period (true state)."""
        return bool(self._s[K.S_CONTACT] != 0.0)

    def set_user(self, trajectory=None, grip_N=2.0, hand: Person | ReactiveHand | str | None = None) -> None:
        """Set the simulated user: a voluntary (planned) motion, a grip force and the person.

        Parameters
        ----------
        trajectory : TapTrajectory, ScriptedTrajectory, float or None
            The person's planned hand motion from now (approach, tap, lift).
            A float holds still at that height; None holds still at the
            handle's current position. The device (all masses, the hand) is
            placed at the trajectory's start, at rest, as if the user picked
            the handle up there.
        grip_N : float or callable
            Grip force in N, constant or a function of time since now (s);
            a callable is sampled over the trajectory's duration (the last
            value holds afterwards). Sets the grip impedance k_u(g), b_u(g).
        hand : Person, ReactiveHand, "prescribed" or None
            None (default): :data:`devices.sim.person.DEFAULT_PERSON` on the
            nonlinear model (a hand/arm mass behind the grip impedance that
            carries momentum, muscles, 8 Hz compensation, contact reflex;
            docs/sim.md "The simulated person"); on the LTI model, whose
            kernel has no person, ``"prescribed"``. ``"prescribed"``: the
            older hand, the grip spring-damper tied directly to the
            trajectory (eq. 3.34; a velocity source). ``ReactiveHand``: the
            earlier person without low-frequency compensation. Stays in force
            until the next ``set_user``.
        """
        if hand is None:
            hand = DEFAULT_PERSON if self.params.model == "nonlinear" else PRESCRIBED
        if isinstance(hand, str) and hand == PRESCRIBED:
            hand_obj = None
        elif isinstance(hand, (Person, ReactiveHand)):
            hand_obj = hand
        else:
            raise ValueError(f"set_user: hand must be a Person, a ReactiveHand, {PRESCRIBED!r} or None, "
                             f"got {hand!r}")
        if hand_obj is not None and self.params.model != "nonlinear":
            raise ValueError(f"set_user: the simulated person (hand mass) needs the nonlinear sim model, "
                             f"not {self.params.model!r}; use hand={PRESCRIBED!r}")
        if trajectory is None:
            trajectory = HoldTrajectory(self._s[K.S_XH])
        elif isinstance(trajectory, (int, float)):
            trajectory = HoldTrajectory(float(trajectory))
        fs = self.info.servo_rate_hz
        if callable(getattr(trajectory, "sample_range", None)) and callable(getattr(trajectory, "n_ticks", None)):
            n = int(trajectory.n_ticks(fs))    # streamed: computed a window at a time (_plan_fill)
            positions = (lambda lo, hi, tr=trajectory: tr.sample_range(fs, lo, hi))
        else:                                  # a trajectory that only samples whole is held whole
            whole = np.ascontiguousarray(trajectory.sample(fs), dtype=float)
            n = whole.size
            positions = (lambda lo, hi, x=whole: x[lo:hi])
        if n < 1:
            raise ValueError("set_user: trajectory must give finite positions")
        if n == 1 and callable(grip_N):
            # a held position with time-varying grip: sample the grip for a while and hold
            x0 = positions(0, 1)
            n = int(60 * fs)
            positions = (lambda lo, hi, x=x0: np.full(max(0, hi - lo), x[0]))
        old = (self._positions, self._grip_N, self._plan_n, self._user_tick)
        self._positions, self._grip_N, self._plan_n, self._user_tick = positions, grip_N, n, self._tick
        try:
            self._plan_fill(0)   # checks the first window before anything else changes
        except Exception:
            self._positions, self._grip_N, self._plan_n, self._user_tick = old   # the window is untouched
            raise
        traj = self._traj
        self.trajectory = trajectory
        self._traj_ticks = int(round(trajectory.duration_s * fs))
        p = self._p
        p[K.P_HAND_ON] = 0.0 if hand_obj is None else 1.0
        p[K.P_HAND_KCOMP] = 0.0
        p[K.P_HAND_CALPHA] = 0.0
        p[K.P_HAND_CTOOL] = 0.0
        p[K.P_HAND_BTOOL] = 0.0
        if hand_obj is not None:
            p[K.P_HAND_MA] = hand_obj.arm_mass_kg
            p[K.P_HAND_KM] = hand_obj.muscle_stiffness_N_m
            p[K.P_HAND_BM] = hand_obj.muscle_damping_Ns_m
            p[K.P_HAND_DELAY] = hand_obj.reflex_delay_s
            p[K.P_HAND_FTHR] = hand_obj.reflex_force_N
            # the arm's internal model knows the tool it holds: the device's masses in handle space
            p[K.P_HAND_MTOOL] = p[K.P_MM] + p[K.P_MD] + p[K.P_MH]
            if isinstance(hand_obj, Person):
                # the internal model also knows the tool's drag (Coulomb friction and damping, Table 3.1)
                p[K.P_HAND_CTOOL] = p[K.P_CM] + p[K.P_CD]
                p[K.P_HAND_BTOOL] = p[K.P_BM] + p[K.P_BD]
                p[K.P_HAND_KCOMP] = hand_obj.compensation_stiffness_N_m
                p[K.P_HAND_CALPHA] = 1.0 - math.exp(-2 * math.pi * hand_obj.compensation_bandwidth_hz * p[K.P_DT])
        ft = hand_obj if isinstance(hand_obj, Person) else None
        p[K.P_FT_MASS] = ft.fingertip_mass_kg if ft is not None else 0.0
        p[K.P_FT_K] = ft.fingertip_stiffness_N_m if ft is not None else 0.0
        p[K.P_FT_B] = ft.fingertip_damping_Ns_m if ft is not None else 0.0
        self.hand = hand_obj if hand_obj is not None else PRESCRIBED
        self._place_at(traj[0])

    def _plan_fill(self, k: int, ticks: int | None = None) -> None:
        """Compute the window of the hand's plan for tick ``k`` (from the user's start) onwards.

        The window holds ticks ``lo..hi-1`` with ``lo = k - 1`` (the kernel looks one tick back for the
        desired acceleration) and ``hi = lo + PLAN_WINDOW_TICKS`` (or ``ticks`` + 3), or it is the plan's
        last ``PLAN_WINDOW_TICKS`` ticks, ending where the plan ends, so the kernel's clamps and its
        "k >= 1 and k + 1 < n" test see exactly what they saw on the whole plan: it is used for
        ``k - 1 >= lo`` and ``k + 1 < hi`` only (or for every later tick in the last window).
        """
        size = PLAN_WINDOW_TICKS if ticks is None else max(PLAN_WINDOW_TICKS, int(ticks) + 3)
        n = self._plan_n
        lo = max(0, min(int(k) - 1, n - size))
        hi = min(n, lo + size)
        traj = np.ascontiguousarray(self._positions(lo, hi), dtype=float)
        if traj.size != hi - lo or not np.all(np.isfinite(traj)):
            raise ValueError("set_user: trajectory must give finite positions")
        grip = np.ascontiguousarray(sample_grip(self._grip_N, hi - lo, self.info.servo_rate_hz, start=lo))
        self._traj, self._grip = traj, grip
        self._plan_lo = lo
        self._plan_kmin = lo + 1 if lo > 0 else -sys.maxsize
        self._plan_kmax = hi - 2 if hi < n else sys.maxsize
        self._plan_base = self._user_tick + lo
        self._plan_tick_max = self._user_tick + self._plan_kmax + 1
        self._fused_version += 1

    def _grip_at(self, k: int) -> float:
        """The plan's grip (N) at tick ``k`` from the user's start (held at its ends), from the window when
        it holds it."""
        k = min(max(k, 0), self._plan_n - 1)
        j = k - self._plan_lo
        if 0 <= j < self._grip.size:
            return float(self._grip[j])
        return float(sample_grip(self._grip_N, 1, self.info.servo_rate_hz, start=k)[0])

    def _place_at(self, x0: float) -> None:
        s = self._s
        for i in (K.S_XM, K.S_XD, K.S_XH):
            s[i] = x0
        for i in (K.S_VM, K.S_VD, K.S_VH, K.S_FL, K.S_FHAT, K.S_AH, K.S_ACCF, K.S_XB, K.S_VB):
            s[i] = 0.0
        s[K.S_XLPREV] = 0.0
        s[K.S_LTI:K.S_LTI + K.LTI_MAX_ORDER] = 0.0
        s[K.S_XU] = x0
        s[K.S_XA], s[K.S_VA] = x0, 0.0            # reactive hand (unused otherwise)
        s[K.S_RFX_T], s[K.S_RFX_X], s[K.S_RFX_ON] = -1.0, x0, 0.0
        s[K.S_EF] = 0.0
        s[K.S_XF], s[K.S_VF] = x0, 0.0            # the person's fingertip (unused without one)
        s[K.S_FM] = 0.0
        self._refresh_state()

    def set_sample(self, name: str) -> None:
        """Put a simulated real sample under the stylus: placeholder, wood, wood_on_foam or foam."""
        smp = get_sample(name)
        p = self._p
        p[K.P_S_KIND] = float(smp.kind)
        p[K.P_S_K] = smp.contact_k_N_m
        p[K.P_S_ALPHA] = smp.contact_alpha_s_m
        p[K.P_S_MB] = smp.block_mass_kg if smp.kind == KIND_BLOCK_ON_FOAM else 1.0
        p[K.P_S_KF] = smp.foam_k_N_m
        p[K.P_S_BF] = smp.foam_b_Ns_m
        p[K.P_S_K1] = smp.maxwell_k_N_m
        p[K.P_S_MXDECAY] = math.exp(-p[K.P_DT] / smp.maxwell_tau_s)
        self._s[K.S_FM] = 0.0
        self._s[K.S_XB] = 0.0
        self._s[K.S_VB] = 0.0
        self.sample_name = name
        self.sample = smp
        self._fused_version += 1

    def set_mechanical_config(self, config="assembled") -> None:
        """Put the device into a mechanical test configuration for successive isolation (sec. 3.5.1).

        Parameters
        ----------
        config : MechanicalConfig or str
            A :class:`devices.sim.mechconfig.MechanicalConfig` or a key of
            ``devices.sim.mechconfig.CONFIGS`` (``motor_locked``, ``motor_only``,
            ``drum_locked``, ``linkage_off``, ``handle_locked``, ``assembled``).
            Disconnected cables or linkage exert no force; a locked mass keeps
            its position (its inertia becomes ``LOCKED_MASS_KG``). Applies from
            the next ``command()``; ``set_user`` then places the device at rest.
        """
        cfg = get_config(config)
        if self.params.model != "nonlinear" and cfg != ASSEMBLED:
            raise ValueError(f"mechanical configurations need the nonlinear sim model, not {self.params.model!r}")
        if self.params.model == "nonlinear":
            m = self.params.mechanics
            p = self._p
            p[K.P_KC] = m["k_c_N_m"] if cfg.cables else 0.0
            p[K.P_BC] = m["b_c_Ns_m"] if cfg.cables else 0.0
            p[K.P_MM] = LOCKED_MASS_KG if cfg.motor_locked else m["m_m_kg"]
            p[K.P_MD] = LOCKED_MASS_KG if cfg.drum_locked else m["m_d_kg"]
            p[K.P_MH] = LOCKED_MASS_KG if cfg.handle_locked else m["m_h_kg"]
            for idx, key in ((K.P_KLP, "k_lp_N_m"), (K.P_KLN, "k_ln_N_m"), (K.P_FLP, "f_lp_N"),
                             (K.P_FLN, "f_ln_N"), (K.P_BL, "b_l_Ns_m")):
                p[idx] = m[key] if cfg.linkage else 0.0
            p[K.P_HYST] = 1.0 if (m["hysteresis"] and cfg.linkage) else 0.0
            self._s[K.S_FL] = self._s[K.S_FHAT] = 0.0
        self.mechanical_config = cfg
        self._fused_version += 1

    def _refresh_state(self) -> None:
        st = self._state
        res = self.info.position_resolution_m
        st.t_s = self.time_s
        st.position_m = res * math.floor(self._s[K.S_XM] / res)
        st.accel_m_s2 = 0.0
        st.grip_N = self._grip_at(self._tick - self._user_tick)
        self._fused_version += 1

    def true_state(self) -> dict:
        """True (unquantized) physical state, SI units, for tests and recordings."""
        s = self._s
        return {
            "t_s": self.time_s,
            "motor_position_m": float(s[K.S_XM]), "motor_velocity_m_s": float(s[K.S_VM]),
            "drum_position_m": float(s[K.S_XD]), "drum_velocity_m_s": float(s[K.S_VD]),
            "handle_position_m": float(s[K.S_XH]), "handle_velocity_m_s": float(s[K.S_VH]),
            "handle_accel_m_s2": float(s[K.S_AH]),
            "linkage_force_N": float(s[K.S_FL]),
            "amplifier_current_A": float(s[K.S_IAMP]),
            "block_position_m": float(s[K.S_XB]), "block_velocity_m_s": float(s[K.S_VB]),
            "in_contact": bool(s[K.S_CONTACT] != 0.0), "contact_force_N": float(s[K.S_FCONTACT]),
            "hand_position_m": float(s[K.S_XU]), "hand_velocity_m_s": float(s[K.S_VU]),
            "arm_position_m": float(s[K.S_XA]), "arm_velocity_m_s": float(s[K.S_VA]),
            "reflex_holding": bool(s[K.S_RFX_ON] != 0.0),
            "grip_N": self._grip_at(self._tick - self._user_tick),
            "winding_temp_rise_K": float(s[K.S_TEMP]),
            "pending_current_A": self._held_A,
        }

    def contact_force_N(self) -> float:
        """The sample's contact force now (N): :meth:`true_state`'s ``contact_force_N`` without the rest of the
        dict (a study polls it every few ticks of a real sample's window to see saturation)."""
        return float(self._s[K.S_FCONTACT])

    def linear_model(self, grip_N: float = 2.0, output: str = "accel_m_s2", linkage: str = "small_signal"):
        """Analytic LTI model of commanded current -> handle acceleration (or motor position).

        Linearizes this device's physics: no Coulomb friction, the
        hysteretic linkage replaced by the mean slope of its loops
        (``linkage="small_signal"``: minor loops of high-frequency
        transients; ``"asymptotic"``: (k_lp + k_ln)/2, see
        :func:`devices.sim.linear.linkage_stiffness_N_m`), user
        impedance at ``grip_N``, the amplifier low-pass (if configured), the
        accelerometer's low-pass (acceleration output), and the output delay
        (one servo period plus half a period for the zero-order hold) as
        ``delay_s``. Returns a :class:`devices.model.ZpkModel`.
        """
        return _linear().linear_model(self.params, grip_N, output, linkage)


def _linear():
    """:mod:`devices.sim.linear` (the LTI transmission and the linearized models), loaded on first use."""
    from . import linear  # deferred: scipy.signal behind it, 1.2 s CPU; only sim:lti and linear models need it

    return linear
