"""Simulated teleoperation testbed: slave joystick, tip sensors, environments, operator (thesis ch. 5).

The slave is a second joystick with Table 3.1 dynamics (or any :class:`SimParams` of the nonlinear
model), its motor under the controller's PD, a tip force sensor (ATI Mini40-like: first-order
bandwidth, white noise) and a tip accelerometer (ADXL321-like: +/-18 g, 1 kHz). Environments are the
Hunt-Crossley samples of ``devices.sim.samples`` plus the hard top of the force sensor and a rough
texture (a periodic bump profile along a stroke coordinate). The operator holds the master through a
linear-plus-quintic grip stiffness and damper (section 5.7.1) with a hand/arm mass behind it, driven
by a muscle impedance towards a voluntary path below 5 Hz, with integral compensation of low-frequency
handle deflection (section 5.6.2). Everything is stepped by :func:`devices.sim.teleop_kernel.run_session`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from plumbing.validation import require_number

from . import teleop_kernel as K
from .params import SimParams, default_params
from .samples import KIND_BLOCK_ON_FOAM, KIND_HALFSPACE, SampleParams, get_sample


@dataclass(frozen=True)
class Environment:
    """A slave environment (surface at height 0 under the slave, positive up).

    The contact is the virtual environment's (``devices.sim.kernel._contact``): a Hunt-Crossley half-space
    F = k d (1 + alpha d') plus a Maxwell branch, or a block resting on a viscoelastic foam.

    Attributes
    ----------
    name : str
    kind : int
        1 Hunt-Crossley half-space, 2 block on a foam spring-damper (``devices.sim.samples.KIND_*``).
    k_N_m, alpha_s_m : float
        Contact stiffness (N/m) and Hunt-Crossley damping (s/m).
    block_mass_kg, foam_k_N_m, foam_b_Ns_m : float
        Block-on-foam parameters (kind 2).
    maxwell_k_N_m, maxwell_tau_s : float
        Maxwell branch (spring in series with a damper of relaxation time tau) of the half-space contact
        (kind 1) or of the foam (kind 2); 0 N/m: elastic.
    texture_amplitude_m, texture_wavelength_m : float
        Bump profile h(y) = A (1 - cos(2 pi y / L)) / 2 along the stroke coordinate (0: flat).
    struck_by : str
        ``"tip"``: the slave's handle tip meets the environment; ``"drum"``: the slave's front transmission
        element (the drum) rests on it, as on the section 5.7 testbed, whose force sensor is "located beneath
        the front transmission element of the slave joystick".
    source : str
        Where the parameters come from (``devices.sim.samples`` for the shared samples).
    """

    name: str
    kind: int
    k_N_m: float
    alpha_s_m: float
    block_mass_kg: float = 1.0
    foam_k_N_m: float = 0.0
    foam_b_Ns_m: float = 0.0
    maxwell_k_N_m: float = 0.0
    maxwell_tau_s: float = 1.0
    texture_amplitude_m: float = 0.0
    texture_wavelength_m: float = 1e-3
    struck_by: str = "tip"
    source: str = ""

    def __post_init__(self) -> None:
        if self.kind not in (1, 2) or not (self.k_N_m > 0 and self.alpha_s_m >= 0 and self.block_mass_kg > 0):
            raise ValueError(f"environment {self.name!r}: invalid parameters")
        if not (self.maxwell_k_N_m >= 0 and self.maxwell_tau_s > 0):
            raise ValueError(f"environment {self.name!r}: Maxwell branch needs k >= 0 and tau > 0")
        if self.struck_by not in ("tip", "drum"):
            raise ValueError(f"environment {self.name!r}: struck_by must be 'tip' or 'drum', got {self.struck_by!r}")


def environment_from_sample(sample: SampleParams, name: str | None = None, **changes) -> Environment:
    """The teleoperation environment of a virtual-environment sample (``devices.sim.samples``), unchanged.

    Parameters
    ----------
    sample : SampleParams
        A half-space or block-on-foam sample (thesis Table 4.1).
    name : str or None
        Environment name (default: the sample's).
    **changes
        Further :class:`Environment` fields (a texture profile on top of the sample).
    """
    if sample.kind not in (KIND_HALFSPACE, KIND_BLOCK_ON_FOAM):
        raise ValueError(f"sample {sample.name!r} has no contact to teleoperate on")
    fields = dict(name=name or sample.name, kind=sample.kind, k_N_m=sample.contact_k_N_m,
                  alpha_s_m=sample.contact_alpha_s_m, maxwell_k_N_m=sample.maxwell_k_N_m,
                  maxwell_tau_s=sample.maxwell_tau_s, source=f"devices.sim.samples: {sample.name}")
    if sample.kind == KIND_BLOCK_ON_FOAM:
        fields.update(block_mass_kg=sample.block_mass_kg, foam_k_N_m=sample.foam_k_N_m, foam_b_Ns_m=sample.foam_b_Ns_m)
    fields.update(changes)
    return Environment(**fields)


ENVIRONMENTS = {
    # the top of the slave's force sensor (sections 5.7, 5.7.2: "tap repeatedly on the hard surface of the force
    # sensor"), beneath the slave's front transmission element: aluminium on a stiff sensor
    "hard": Environment("hard", 1, 3.0e5, 10.0, struck_by="drum", source="teleop: the force sensor's top"),
    # the virtual environment's samples (one definition: devices.sim.samples)
    "wood": environment_from_sample(get_sample("wood")),
    "wood_on_foam": environment_from_sample(get_sample("wood_on_foam")),
    "foam": environment_from_sample(get_sample("foam")),
    # wood with 0.3 mm bumps every 2 mm along the stroke (section 4.3.2's rough texture)
    "texture": environment_from_sample(get_sample("wood"), name="texture", texture_amplitude_m=0.3e-3,
                                       texture_wavelength_m=2.0e-3),
}


def get_environment(name: str) -> Environment:
    """Environment by name (``ENVIRONMENTS``); ValueError naming the valid ones otherwise."""
    if name not in ENVIRONMENTS:
        raise ValueError(f"unknown environment {name!r} (valid: {', '.join(ENVIRONMENTS)})")
    return ENVIRONMENTS[name]


@dataclass(frozen=True)
class Operator:
    """Simulated operator holding the master (sections 3.4.6, 5.2, 5.6.2, 5.7.1).

    Attributes
    ----------
    k_u_N_m, b_u_Ns_m : float
        Linear grip stiffness and damping between handle and hand (Table 3.1 at 2 N grip).
    q_u_N_m5 : float
        Quintic grip stiffness (section 5.7.1: 3.125e13 N/m^5, 2 mm at maximum feedback force).
    hand_mass_kg : float
        Hand/arm mass behind the grip (0: the grip is tied directly to the voluntary path).
    muscle_k_N_m, muscle_b_Ns_m : float
        Muscle impedance driving the hand towards the (compensated) path.
    compensation_hz : float
        Bandwidth of the integral compensation of low-frequency handle deflection (section 5.6.2,
        "from steady state to about eight hertz").
    push_N : float
        Constant force the operator adds on the handle (N, positive up; e.g. -1 pushes towards the
        surface). With the grip stiffness at zero the operator is a pure force source, the free master
        of section 5.3.1.
    """

    k_u_N_m: float = 40.0
    b_u_Ns_m: float = 23.0
    q_u_N_m5: float = 3.125e13
    hand_mass_kg: float = 0.2
    muscle_k_N_m: float = 400.0
    muscle_b_Ns_m: float = 20.0
    compensation_hz: float = 1.0
    push_N: float = 0.0

    def __post_init__(self) -> None:
        if not math.isfinite(self.push_N):
            raise ValueError(f"operator: push_N must be finite, got {self.push_N!r}")
        for name in ("k_u_N_m", "b_u_Ns_m", "q_u_N_m5", "hand_mass_kg", "muscle_k_N_m", "muscle_b_Ns_m",
                     "compensation_hz"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"operator: {name} must be finite and >= 0, got {v!r}")


@dataclass(frozen=True)
class SlaveSensors:
    """Slave tip sensors.

    Attributes
    ----------
    force_bandwidth_hz, force_noise_N : float
        Tip force sensor (ATI Mini40-like): first-order low-pass and white noise per sample.
    accel_bandwidth_hz, accel_noise_m_s2, accel_range_m_s2 : float
        Tip accelerometer (ADXL321-like: +/-18 g, 1 kHz).
    """

    force_bandwidth_hz: float = 2000.0
    force_noise_N: float = 0.005
    accel_bandwidth_hz: float = 1000.0
    accel_noise_m_s2: float = 0.05
    accel_range_m_s2: float = 18 * 9.81


@dataclass(frozen=True)
class CimmModel:
    """The induced-motion model G_i,hf of the cancellation controller (sections 5.6-5.7).

    Attributes
    ----------
    params : SimParams
        The identified master (nonlinear model), never the simulator's own parameters in use.
    k_u_N_m, q_u_N_m5, b_u_Ns_m : float
        User model: linear + quintic stiffness and damper from the handle to ground (section 5.7.1).
    hand_mass_kg : float
        Effective hand mass added to the handle mass of ``params``.
    step_s : float
        Integration step (semi-implicit Euler; section 5.7.2 used forward Euler at 40 us).
    washout_hz : float
        First-order high-pass on the model output (0: none): makes the model underestimate
        low-frequency induced motion (section 5.6.2, eq. 5.14).
    source : str
        Where ``params`` came from (reported in run.json).
    """

    params: SimParams
    k_u_N_m: float = 40.0
    q_u_N_m5: float = 3.125e13
    b_u_Ns_m: float = 23.0
    hand_mass_kg: float = 0.0
    step_s: float = 40e-6
    washout_hz: float = 0.0
    source: str = ""

    def __post_init__(self) -> None:
        if self.params.model != "nonlinear":
            raise ValueError("CIMM model: params must be a nonlinear SimParams (sixth-order model)")
        if not 0 < self.step_s <= 40e-6:
            raise ValueError(f"CIMM model: step_s must be in (0, 40e-6] s, got {self.step_s!r}")


def chain_block(params: SimParams, rigid: bool = False, extra_handle_mass_kg: float = 0.0,
                backlash_m: float = 0.0) -> np.ndarray:
    """Parameter block (``teleop_kernel.CP_*``) of one joystick chain from a nonlinear SimParams.

    Parameters
    ----------
    params : SimParams
        Table 3.1-style mechanics (eq. 3.32-3.35).
    rigid : bool
        One pure mass m_m + m_d + m_h (section 5.3.1).
    extra_handle_mass_kg : float
        Added to m_h (a hand mass moving with the handle).
    backlash_m : float
        Total free play of the cable transmission between motor and drum (m, handle space; 0: none).
    """
    m = params.mechanics
    b = np.zeros(K.CP_N)
    b[K.CP_MM], b[K.CP_BM], b[K.CP_CM] = m["m_m_kg"], m["b_m_Ns_m"], m["c_m_N"]
    b[K.CP_KC], b[K.CP_BC] = m["k_c_N_m"], m["b_c_Ns_m"]
    b[K.CP_MD], b[K.CP_BD], b[K.CP_CD] = m["m_d_kg"], m["b_d_Ns_m"], m["c_d_N"]
    b[K.CP_KLP], b[K.CP_KLN], b[K.CP_FLP], b[K.CP_FLN] = m["k_lp_N_m"], m["k_ln_N_m"], m["f_lp_N"], m["f_ln_N"]
    b[K.CP_GAM], b[K.CP_BL] = m["gamma_l_rad_m"], m["b_l_Ns_m"]
    b[K.CP_MH] = m["m_h_kg"] + extra_handle_mass_kg
    b[K.CP_HYST] = 1.0 if m["hysteresis"] else 0.0
    b[K.CP_RIGID] = 1.0 if rigid else 0.0
    b[K.CP_VSTICK] = params.simulation["stick_velocity_m_s"]
    b[K.CP_GAP] = backlash_m
    return b


def pure_mass_params(mass_kg: float, name: str = "pure-mass") -> SimParams:
    """A nonlinear SimParams whose chain, run rigid, is a frictionless pure mass of ``mass_kg``."""
    return default_params().replace(name=name, mechanics={
        "m_m_kg": mass_kg / 3, "m_d_kg": mass_kg / 3, "m_h_kg": mass_kg / 3, "c_m_N": 0.0, "c_d_N": 0.0,
        "b_m_Ns_m": 0.0, "b_d_Ns_m": 0.0})


def force_constant_N_A(params: SimParams) -> float:
    """Motor force per amp in handle space, rho k_t / h (eq. 3.17)."""
    d = params.device
    return d["gear_ratio"] * d["torque_constant_Nm_A"] / d["handle_length_m"]


def tap_path(n_taps: int, fs_hz: float, *, speed_m_s: float = 0.1, approach_m: float = 0.01,
             press_m: float = 0.002, dwell_s: float = 0.4, lift_s: float = 0.2, pause_s: float = 0.1,
             start_s: float = 0.05, speeds_m_s=None) -> tuple[np.ndarray, np.ndarray]:
    """Voluntary hand path of repeated taps (below 5 Hz): descend at constant speed to ``press_m`` below
    the surface (height 0), dwell, half-cosine lift back to the approach height, pause.

    Parameters
    ----------
    n_taps : int
    fs_hz : float
        Servo rate (samples per second of the returned path).
    speed_m_s : float
        Incoming speed; ``speeds_m_s`` (one per tap) overrides it.

    Returns
    -------
    path_m : ndarray (n,)
        Desired hand position per tick (m, positive up).
    surface_ticks : ndarray of int (n_taps,)
        Tick at which each tap's path crosses the surface (the nominal impact; the slave arrives later).
    """
    speeds = [speed_m_s] * n_taps if speeds_m_s is None else list(speeds_m_s)
    seg = [np.full(int(round(start_s * fs_hz)), approach_m)]
    crossings = []
    n0 = len(seg[0])
    for v in speeds:
        if not v > 0:
            raise ValueError(f"tap speed must be > 0, got {v!r}")
        n_down = int(round((approach_m + press_m) / v * fs_hz))
        down = approach_m - v * np.arange(1, n_down + 1) / fs_hz
        crossings.append(n0 + int(round(approach_m / v * fs_hz)))
        down = np.maximum(down, -press_m)
        dwell = np.full(int(round(dwell_s * fs_hz)), -press_m)
        nl = int(round(lift_s * fs_hz))
        lift = -press_m + (approach_m + press_m) * 0.5 * (1 - np.cos(np.pi * np.arange(1, nl + 1) / nl))
        pause = np.full(int(round(pause_s * fs_hz)), approach_m)
        for part in (down, dwell, lift, pause):
            seg.append(part)
        n0 += len(down) + len(dwell) + len(lift) + len(pause)
    return np.concatenate(seg), np.asarray(crossings, dtype=np.int64)


# Figure 5.11's uncorrected backlash: the thesis gives no size; 0.1 mm at the handle (0.6 deg at the motor
# shaft through rho = 15 and h = 0.15 m), chosen before any sweep; sensitivity in docs/teleop.md
BACKLASH_FIG_5_11_M = 0.1e-3

# Viscous damping between the UNHELD slave handle and its linkage (N s/m, handle space). Table 3.1's
# b_l = 0 was identified with the handle locked or held (the user's b_u = 23 N s/m dominates there); the
# slave's handle hangs free above its drum, which rests on the force sensor (section 5.7), and its damping
# was never identified. The thesis's one datum for it is the slave's natural impact: cancellation keeps the
# settling time "to a lower value, closer to that of the slave's natural impact" (section 5.7.2, Figure 5.11),
# below Figure 5.10's lambda = 1 value ("the force transients decay in about 50 ms"). This value is that
# identification, rounded: the damping at which a tap with no force feedback (lambda = 0, taps at 0.08 and
# 0.12 m/s on the hard surface, four noise seeds each) settles in 40 ms on the mean -- below the lambda = 1
# settling time, at the lower edge of "about 50 ms" (40-60 ms) -- by the sweep's settling definition:
# renderer.teleop.calibration.calibrate_slave_handle_damping (3.16 N s/m; a test re-runs it and checks this
# value within 10 %). 0 = Table 3.1 as identified.
SLAVE_HANDLE_DAMPING_N_S_M = 3.2


@dataclass(frozen=True)
class Testbed:
    """Master, slave, operator, environment and sensors of a simulated teleoperation session.

    Attributes
    ----------
    master, slave : SimParams
        Nonlinear device parameters (Table 3.1 by default).
    operator : Operator
    environment : Environment
    sensors : SlaveSensors
    servo_rate_hz : float
        Controller rate (thesis: 5 kHz).
    substep_s : float
        Physics substep (divides the servo period).
    rigid : bool
        Master and slave as pure masses (section 5.3.1).
    backlash_m : float
        Free play in both transmissions (motor to drum, m in handle space; 0: none). Figure 5.11's
        condition ("the transmissions of both master and slave contained significant backlash");
        ``BACKLASH_FIG_5_11_M`` is the value used for it (docs/teleop.md).
    slave_handle_damping_N_s_m : float
        Viscous damping between the slave's unheld handle and its linkage (N s/m); it replaces the slave's
        b_l (Table 3.1's b_l = 0 was identified with the handle held). Default
        ``SLAVE_HANDLE_DAMPING_N_S_M``, calibrated on the slave's natural impact
        (``renderer.teleop.calibration``); 0: Table 3.1 as identified. The master keeps its own b_l.
    """

    master: SimParams
    slave: SimParams
    operator: Operator = Operator()
    environment: Environment = ENVIRONMENTS["hard"]
    sensors: SlaveSensors = SlaveSensors()
    servo_rate_hz: float = 5000.0
    substep_s: float = 10e-6
    rigid: bool = False
    backlash_m: float = 0.0
    slave_handle_damping_N_s_m: float = SLAVE_HANDLE_DAMPING_N_S_M
    __test__ = False  # not a pytest class

    def __post_init__(self) -> None:
        require_number("slave_handle_damping_N_s_m", self.slave_handle_damping_N_s_m, minimum=0.0)

    def nsub(self) -> int:
        """Substeps per servo period."""
        n = int(round(1.0 / (self.servo_rate_hz * self.substep_s)))
        if n < 1 or abs(n * self.substep_s * self.servo_rate_hz - 1) > 1e-6:
            raise ValueError(f"substep_s {self.substep_s} must divide the servo period 1/{self.servo_rate_hz}")
        return n

    def pack(self, cimm: CimmModel | None) -> np.ndarray:
        """Parameter array with the plant part filled (controller part zero, set by the caller)."""
        p = np.zeros(K.N_PARAM)
        if not (math.isfinite(self.backlash_m) and 0.0 <= self.backlash_m < 0.005):
            raise ValueError(f"backlash_m must be in [0, 5 mm), got {self.backlash_m!r}")
        p[K.PB_MASTER:K.PB_MASTER + K.CP_N] = chain_block(self.master, self.rigid, backlash_m=self.backlash_m)
        p[K.PB_SLAVE:K.PB_SLAVE + K.CP_N] = chain_block(self.slave, self.rigid, backlash_m=self.backlash_m)
        p[K.PB_SLAVE + K.CP_BL] = self.slave_handle_damping_N_s_m   # unheld handle (Table 3.1's b_l: held)
        nsub = self.nsub()
        dt = self.substep_s
        p[K.P_DT], p[K.P_NSUB], p[K.P_TICK] = dt, nsub, 1.0 / self.servo_rate_hz
        p[K.P_KF_M], p[K.P_IMAX_M] = force_constant_N_A(self.master), self.master.device["current_amplifier_A"]
        p[K.P_KF_S], p[K.P_IMAX_S] = force_constant_N_A(self.slave), self.slave.device["current_amplifier_A"]
        p[K.P_ENC_M] = self.master.device_info().position_resolution_m
        p[K.P_ENC_S] = self.slave.device_info().position_resolution_m
        o = self.operator
        p[K.P_KU], p[K.P_QU], p[K.P_BU], p[K.P_MA] = o.k_u_N_m, o.q_u_N_m5, o.b_u_Ns_m, o.hand_mass_kg
        p[K.P_KMUS], p[K.P_BMUS], p[K.P_COMP_W] = o.muscle_k_N_m, o.muscle_b_Ns_m, 2 * math.pi * o.compensation_hz
        p[K.P_PUSH] = o.push_N
        e = self.environment
        p[K.P_EKIND], p[K.P_EK], p[K.P_EALPHA] = e.kind, e.k_N_m, e.alpha_s_m
        p[K.P_EMB], p[K.P_EKF], p[K.P_EBF] = e.block_mass_kg, e.foam_k_N_m, e.foam_b_Ns_m
        p[K.P_TEX_A], p[K.P_TEX_L] = e.texture_amplitude_m, e.texture_wavelength_m
        p[K.P_EK1], p[K.P_EMXDECAY] = e.maxwell_k_N_m, math.exp(-dt / e.maxwell_tau_s)
        p[K.P_EDRUM] = 1.0 if e.struck_by == "drum" else 0.0
        se = self.sensors
        p[K.P_FS_A] = 1 - math.exp(-2 * math.pi * se.force_bandwidth_hz * dt)
        p[K.P_FS_N] = se.force_noise_N
        p[K.P_AC_A] = 1 - math.exp(-2 * math.pi * se.accel_bandwidth_hz * dt)
        p[K.P_AC_N], p[K.P_AC_R] = se.accel_noise_m_s2, se.accel_range_m_s2
        p[K.P_LINK_LOST_TICK] = -1.0
        p[K.P_MDT_N] = 1
        if cimm is not None:
            n = max(1, int(round(cimm.step_s / dt)))
            if abs(n * dt - cimm.step_s) > 1e-9 or nsub % n:
                raise ValueError(f"CIMM step {cimm.step_s} s must be a multiple of the substep {dt} s "
                                 f"dividing the servo period")
            p[K.P_MDT_N] = n
            p[K.PB_MODEL:K.PB_MODEL + K.CP_N] = chain_block(cimm.params, self.rigid, cimm.hand_mass_kg)
            p[K.P_MKU], p[K.P_MQU], p[K.P_MBU] = cimm.k_u_N_m, cimm.q_u_N_m5, cimm.b_u_Ns_m
            p[K.P_CIMM] = 1.0
            if cimm.washout_hz > 0:
                w = 2 * math.pi * cimm.washout_hz / self.servo_rate_hz
                p[K.P_WASH_A] = 1.0 / (1.0 + w)
        return p

    def initial_state(self, x_master_m: float, mu: float, v_master_m_s: float = 0.0) -> np.ndarray:
        """Initial state: master and hand at ``x_master_m`` moving at ``v_master_m_s`` (m/s, up), the slave
        tracking at ``mu`` times both (section 5.3.1: "tracking perfectly"), the CIMM model at rest at 0."""
        s = np.zeros(K.N_STATE)
        for j in (K.CS_XM, K.CS_XD, K.CS_XH):
            s[K.SB_MASTER + j] = x_master_m
            s[K.SB_SLAVE + j] = mu * x_master_m
        for j in (K.CS_VM, K.CS_VD, K.CS_VH):
            s[K.SB_MASTER + j] = v_master_m_s
            s[K.SB_SLAVE + j] = mu * v_master_m_s
        s[K.S_HA_X] = x_master_m
        s[K.S_HA_V] = v_master_m_s
        s[K.S_VM_EST] = v_master_m_s
        s[K.S_VS_EST] = mu * v_master_m_s
        s[K.S_XC] = mu * x_master_m
        return s
