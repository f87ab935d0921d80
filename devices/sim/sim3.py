"""The 3-DOF simulated device: a point endpoint tapped along any direction (docs/sim.md, "3-DOF simulated device").

Along the tap direction the endpoint *is* the 1-DOF simulated device: an inner :class:`SimDevice` with the
same parameters, seed, person, plan and sample, whose compiled kernel (``devices.sim.kernel.tick``) runs
the tap axis. Nothing of the 1-DOF physics is re-derived here, so a tap straight down on a plane normal to
z gives the 1-DOF traces by construction, whatever the 1-DOF kernel's physics are. Across the tap, two
lateral axes (``devices.sim.lateral``): a lumped mass with friction on the grip impedance. The device's
own per-axis inertia and friction and an optional linkage's (``devices.sim.linkage``) are projected onto
the tap frame; gravity acts along -z unless the device compensates it (the default, as the Falcon's and
the Phantom's drivers do).

Frames: the device frame of ``devices.base`` (z up). The tap frame: ``u`` = minus the tap direction (out
of the tapped surface), ``v``, ``w`` completing a right-handed frame. The endpoint is
``target + u q_u + v q_v + w q_w``; ``q_u`` is the 1-DOF device's handle position (its surface at 0).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..base import Device, DeviceInfo, DeviceState
from . import layout as K
from . import lateral as L
from .device import SimDevice
from .hand import ReactiveHand, TapTrajectory
from .linkage import LINKAGES
from .params import SimParams
from .person import DEFAULT_PERSON, Person

#: the simulated 3-DOF device's workspace (m, device frame): a 10 cm cube, a Falcon's and an Inverse3's order
WORKSPACE_HALF_M = 0.05
#: the largest stiffness each variant renders stably (N/m; ours: the Falcon's ~2 N/mm, the Phantom Premium's
#: 3.5 N/mm, a Cartesian stage with the 1-DOF testbed's drive a little more)
MAX_STIFFNESS_N_M = {None: 5000.0, "delta": 2000.0, "serial": 3500.0}
GRAVITY_M_S2 = 9.81


def tap_frame(direction) -> tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]:
    """The tap frame ``(u, v, w)`` for a tap moving along ``direction`` (module doc).

    ``u = -direction / |direction|``; ``v`` is the unit vector of ``a x u`` with ``a`` = y (or x when u is
    near y); ``w = u x v``. A tap straight down gives u = +z, v = +x, w = +y exactly.
    """
    d = [float(c) for c in direction]
    n = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    if not (n > 0 and math.isfinite(n)):
        raise ValueError(f"tap direction must be a non-zero finite 3-vector, got {direction!r}")
    u = (-d[0] / n, -d[1] / n, -d[2] / n)
    a = (0.0, 1.0, 0.0) if abs(u[1]) < 0.9 else (1.0, 0.0, 0.0)
    v = (a[1] * u[2] - a[2] * u[1], a[2] * u[0] - a[0] * u[2], a[0] * u[1] - a[1] * u[0])
    nv = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    v = (v[0] / nv, v[1] / nv, v[2] / nv)
    w = (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])
    return u, v, w


class Sim3Device(Device):
    """Simulated 3-DOF impedance-type device with a simulated person tapping along any direction.

    Parameters
    ----------
    params : SimParams or None
        The 1-DOF sim's parameters (Table 3.1 by default): the tap axis's physics.
    seed : int
        Noise seed of the tap axis (the 1-DOF device's with the same seed).
    linkage : None, "delta" or "serial"
        None: a Cartesian endpoint (the same impedance in every direction); "delta" (Falcon-like) or
        "serial" (Phantom-like): the motors' inertia and friction through the linkage's Jacobian.
    axis_mass_kg, axis_friction_N : 3 floats
        Extra inertia (kg) and Coulomb friction (N) along the device frame's x, y, z (a stage's carriages).
    gravity_compensated : bool
        True (default): the device cancels the endpoint's weight; False: ``m g`` pulls along -z.
    """

    def __init__(self, params: SimParams | None = None, seed: int = 0, linkage: str | None = None,
                 axis_mass_kg=(0.0, 0.0, 0.0), axis_friction_N=(0.0, 0.0, 0.0), gravity_compensated: bool = True):
        super().__init__()
        if linkage not in (None, "delta", "serial"):
            raise ValueError(f"linkage must be None, 'delta' or 'serial', got {linkage!r}")
        for name, vec in (("axis_mass_kg", axis_mass_kg), ("axis_friction_N", axis_friction_N)):
            if len(vec) != 3 or not all(math.isfinite(float(x)) and float(x) >= 0 for x in vec):
                raise ValueError(f"{name} must be three finite numbers >= 0, got {vec!r}")
        self.tap = SimDevice(params, seed=seed)
        if self.tap.params.model != "nonlinear":
            raise ValueError("the 3-DOF sim needs the nonlinear 1-DOF model along its tap axis")
        self.linkage = linkage
        self.axis_mass_kg = tuple(float(x) for x in axis_mass_kg)
        self.axis_friction_N = tuple(float(x) for x in axis_friction_N)
        self.gravity_compensated = bool(gravity_compensated)
        base = self.tap.info
        half = WORKSPACE_HALF_M
        self.info = DeviceInfo(**{**{f: getattr(base, f) for f in base.__dataclass_fields__},
                                  "name": "sim-3d" + (f"-{linkage}" if linkage else ""), "axes": 3,
                                  "workspace_min_m": (-half, -half, -half), "workspace_max_m": (half, half, half),
                                  "max_stiffness_N_m": MAX_STIFFNESS_N_M[linkage], "linear": linkage is None,
                                  "buttons": 1})
        self._kf = base.force_per_amp_N_A
        self._inv_kf = 1.0 / self._kf
        self._res = base.position_resolution_m
        self._p_nominal = self.tap._p.copy()
        self.lat = np.zeros(L.N_LAT)
        self.lp = np.zeros(L.N_LP)
        # frame: target (3), u (3), v (3), w (3); a tap straight down at the origin by default
        self.frame = np.zeros(12)
        self._state = DeviceState(vx_m_s=math.nan, vy_m_s=math.nan, vz_m_s=math.nan)
        self._i_grav_u = 0.0
        self.set_frame((0.0, 0.0, 0.0), (0.0, 0.0, -1.0))

    # -- the tap frame and its projected physics ---------------------------
    def set_frame(self, target_m, direction) -> None:
        """Point the tap axis: the person taps ``target_m`` (device frame, m) moving along ``direction``.

        Projects the device's inertia, friction, linkage and gravity onto the tap frame; the lateral axes
        are put at rest on the tap line. Called by :meth:`set_user`.
        """
        t = [float(c) for c in target_m]
        if len(t) != 3 or not all(math.isfinite(c) for c in t):
            raise ValueError(f"tap target must be a finite 3-vector, got {target_m!r}")
        u, v, w = tap_frame(direction)
        self.frame[:] = (*t, *u, *v, *w)
        p = self.tap._p
        p[:] = self._p_nominal
        mtool = p[K.P_MM] + p[K.P_MD] + p[K.P_MH]
        m_extra = np.diag(self.axis_mass_kg)
        link = LINKAGES.get(self.linkage) if self.linkage else None
        if link is not None:
            m_extra = m_extra + link.endpoint_inertia(t)

        def fric(e):
            c = sum(self.axis_friction_N[i] * abs(e[i]) for i in range(3))
            return c + (link.friction_along(t, e) if link is not None else 0.0)

        mu = float(np.asarray(u) @ m_extra @ np.asarray(u))
        cu = fric(u)
        # what the device adds along the tap to the 1-DOF tool: the person's reflex discounts it (set_user)
        self._added_mass_u_kg, self._added_friction_u_N = mu, cu
        if mu or cu:     # untouched when nothing is added: the 1-DOF device's numbers exactly
            p[K.P_MH] += mu
            p[K.P_CD] += cu
        lp = self.lp
        nominal = self._p_nominal
        c_chain = nominal[K.P_CM] + nominal[K.P_CD]      # the chain's Coulomb friction, motor and drum
        lp[L.LP_MV] = mtool + float(np.asarray(v) @ m_extra @ np.asarray(v))
        lp[L.LP_MW] = mtool + float(np.asarray(w) @ m_extra @ np.asarray(w))
        lp[L.LP_CV] = c_chain + fric(v)
        lp[L.LP_CW] = c_chain + fric(w)
        lp[L.LP_BV] = lp[L.LP_BW] = p[K.P_BM] + p[K.P_BD]
        lp[L.LP_KU_PER_N], lp[L.LP_BU_PER_N] = p[K.P_KU_PER_N], p[K.P_BU_PER_N]
        lp[L.LP_DT], lp[L.LP_NSUB], lp[L.LP_VSTICK] = p[K.P_DT], p[K.P_NSUB], p[K.P_VSTICK]
        lp[L.LP_RES] = self._res
        g_force = 0.0 if self.gravity_compensated else -(mtool + float(m_extra[2, 2])) * GRAVITY_M_S2
        lp[L.LP_FGV], lp[L.LP_FGW] = g_force * v[2], g_force * w[2]
        # gravity along the tap axis enters at the motor, as a current (exact in the static balance)
        self._i_grav_u = g_force * u[2] * self._inv_kf
        self.lat[:] = 0.0
        self._refresh()

    @property
    def tap_axis(self) -> tuple[float, float, float]:
        """``u``: the unit vector out of the tapped surface (device frame)."""
        return tuple(float(x) for x in self.frame[3:6])

    def set_user(self, trajectory=None, grip_N=2.0, hand=None, target_m=(0.0, 0.0, 0.0),
                 direction=(0.0, 0.0, -1.0)) -> None:
        """The simulated person taps ``target_m`` along ``direction`` following ``trajectory``.

        ``trajectory``, ``grip_N`` and ``hand`` as :meth:`SimDevice.set_user`: the plan's height is the
        distance from ``target_m`` against the tap direction (a :class:`TapTrajectory` approaches from
        ``approach_height_m`` and presses ``press_depth_m`` past the target). Across the tap the hand holds
        still on the tap line.
        """
        self.set_frame(target_m, direction)
        self.tap.set_user(trajectory, grip_N=grip_N, hand=self._hand_along_tap(hand, trajectory))
        self._refresh()

    def _hand_along_tap(self, hand, trajectory):
        """The person as the tap axis gets it: its contact reflex discounts the drag the device adds along
        the tap.

        The person's internal model knows the tool it holds (``SimDevice.set_user``: the feedforward's
        ``m_tool`` and Coulomb drag include the inertia and friction projected on the tap axis here), and
        its reflex is armed only once the plan stops accelerating; but the grip (Table 3.1's 40 N/m,
        23 N s/m, behind the fingertip's 5 g) still carries the tool's own drag then, ``(m_tool + m_f) a +
        c_tool``. ``reflex_force_N`` (0.3 N) clears that with ~0.13 N to spare on the 1-DOF tool (32 g,
        24 mN); a linkage's inertia and friction along the tap (serial arm sideways: +28 g, +49 mN) would
        take it past the threshold at the end of the approach, and the person would "feel" the surface and
        hold 5 mm above it. So the threshold is raised by what the device adds to that drag: its friction
        along the tap plus its inertia times the tap plan's ramp acceleration. The contact force that
        triggers the reflex beyond the tool's expected drag stays the person's; with nothing added
        (a Cartesian endpoint) the person is passed on unchanged (the 1-DOF numbers, bit for bit).
        """
        mu, cu = self._added_mass_u_kg, self._added_friction_u_N
        if not (mu or cu):
            return hand
        person = DEFAULT_PERSON if hand is None else hand
        if not isinstance(person, (Person, ReactiveHand)):
            return hand     # "prescribed": no reflex
        extra_N = cu + mu * _plan_peak_accel_m_s2(trajectory)
        return dataclasses.replace(person, reflex_force_N=person.reflex_force_N + extra_N)

    def set_sample(self, name: str) -> None:
        """A real sample (``devices.sim.samples``) at the target, its surface normal to the tap axis."""
        self.tap.set_sample(name)

    # -- Device ----------------------------------------------------------------
    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def read(self) -> DeviceState:
        """The state sample (the same object every call): endpoint x, y, z (m), grip, accel along ``u``."""
        return self._state

    def _send_zero(self) -> None:
        self.tap._send_current(0.0)
        self.lat[L.LAT_HV] = self.lat[L.LAT_HW] = 0.0

    def _send_force(self, fx_N: float, fy_N: float, fz_N: float) -> None:
        """The force's tap-frame components: along ``u`` as the 1-DOF device's current (eq. 3.17), across
        it to the lateral axes; advances the simulation one servo period."""
        f = self.frame
        fu = f[3] * fx_N + f[4] * fy_N + f[5] * fz_N
        fv = f[6] * fx_N + f[7] * fy_N + f[8] * fz_N
        fw = f[9] * fx_N + f[10] * fy_N + f[11] * fz_N
        tap = self.tap
        g = tap._grip_at(tap._tick - tap._user_tick)
        if not tap.motor_enabled:   # motor off: no force across the tap either (the tap axis ignores its own)
            fv = fw = 0.0
        tap.command(fu * self._inv_kf + self._i_grav_u)
        L.lateral_step(self.lat, self.lp, fv, fw, g)
        self._refresh()

    def _refresh(self) -> None:
        ts = self.tap.read()
        f, lat, res = self.frame, self.lat, self._res
        qu = ts.position_m
        qv = res * math.floor(lat[L.LAT_QV] / res)
        qw = res * math.floor(lat[L.LAT_QW] / res)
        st = self._state
        st.t_s = ts.t_s
        st.x_m = f[0] + f[3] * qu + f[6] * qv + f[9] * qw
        st.y_m = f[1] + f[4] * qu + f[7] * qv + f[10] * qw
        st.position_m = f[2] + f[5] * qu + f[8] * qv + f[11] * qw
        st.accel_m_s2 = ts.accel_m_s2
        st.grip_N = ts.grip_N
        st.status = ts.status

    def jacobian(self):
        """The linkage's ``dx/dq`` at the endpoint (3 x 3, m/rad), or None without a linkage."""
        if self.linkage is None:
            return None
        st = self._state
        return LINKAGES[self.linkage].jacobian((st.x_m, st.y_m, st.position_m))

    # -- simulation controls -----------------------------------------------------
    @property
    def time_s(self) -> float:
        """Simulated time (s)."""
        return self.tap.time_s

    @property
    def trajectory_done(self) -> bool:
        """True when the person's plan is done."""
        return self.tap.trajectory_done

    @property
    def motor_enabled(self) -> bool:
        """False: commands are ignored (zero force), e.g. for real-sample taps."""
        return self.tap.motor_enabled

    @motor_enabled.setter
    def motor_enabled(self, on: bool) -> None:
        """False: commands are ignored (zero force), e.g. for real-sample taps."""
        self.tap.motor_enabled = on

    def true_state(self) -> dict:
        """True (unquantized) endpoint position (m) and velocity (m/s), device frame, and the tap axis's state."""
        ts = self.tap.true_state()
        f, lat = self.frame, self.lat
        qu, vu = ts["motor_position_m"], ts["motor_velocity_m_s"]
        hu = ts["handle_position_m"]
        pos = [f[i] + f[3 + i] * hu + f[6 + i] * lat[L.LAT_QV] + f[9 + i] * lat[L.LAT_QW] for i in range(3)]
        vel = [f[3 + i] * ts["handle_velocity_m_s"] + f[6 + i] * lat[L.LAT_VV] + f[9 + i] * lat[L.LAT_VW]
               for i in range(3)]
        return {**ts, "endpoint_position_m": tuple(pos), "endpoint_velocity_m_s": tuple(vel),
                "tap_motor_position_m": qu, "tap_motor_velocity_m_s": vu,
                "lateral_position_m": (float(lat[L.LAT_QV]), float(lat[L.LAT_QW]))}

    def use_compiled_step(self, step) -> None:
        """Advance the tap axis's physics with ``step`` (``devices.sim.kernel.tick`` compiled ahead of time,
        ``renderer.sim_aot``): :meth:`SimDevice.use_compiled_step` of the tap axis."""
        self.tap.use_compiled_step(step)

    # -- the compiled loop (renderer.law3.run_sim3) ------------------------------
    def fused3(self):
        """The arrays the compiled 3-D loop advances: the tap axis's (``SimDevice.fused_arrays``), the
        lateral state and parameters, the frame, and the gravity current along u."""
        return (*self.tap.fused_arrays(), self.lat, self.lp, self.frame, self._i_grav_u)


def _plan_peak_accel_m_s2(trajectory) -> float:
    """The largest acceleration (m/s^2) of a person's tapping plan before contact.

    A :class:`TapTrajectory`: each tap's approach ramp, ``v / ramp`` (its deceleration below the surface,
    ``v^2 / press_depth``, comes after contact). Any other plan (a held position, a script): 0, the reflex
    discounts the added friction only -- a script's second differences jump at its corners, where the grip
    carries no sustained load, and would blunt the reflex for nothing.
    """
    if isinstance(trajectory, TapTrajectory):
        return max(v / min(trajectory.ramp_s, trajectory.approach_height_m / v) for v in trajectory.velocities_m_s)
    return 0.0
