"""Test signals of successive isolation and how they are played: on a device (servo loop in Python, works on
hardware; on the simulated device the same ticks in one numba call) or on the built-up model simulation (one
numba call, the same control law).

An :class:`Experiment` is a feedforward current plus an optional PD position controller on the motor
encoder (the *virtual spring* of thesis sec. 3.5.1, 3.5.2), one sample per servo tick:

    i_k = ff_k + (kp (ref_k - x_k) - kd v_k) / (F/i),    v_k = v_{k-1} + a ((x_k - x_{k-1}) / T - v_{k-1})

with x_k the encoder position read at tick k (handle space, m), gains in handle space (N/m, N s/m) and
``a = 1 - exp(-2 pi f_v T)`` a first-order velocity filter at ``velocity_filter_hz``. Sample k of a
:class:`Trace` holds the state read at tick k, just before command k (as ``devices.identify.record.play``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ...base import Device
from ...sim import layout as K
from ._fastrun import run_pd


@dataclass(frozen=True)
class Experiment:
    """One test of a stage.

    Attributes
    ----------
    name : str
    ff_A : ndarray, shape (n,)
        Feedforward current per servo tick (A).
    ref_m : ndarray or None, shape (n,)
        PD reference position relative to the start (m); None: open loop.
    kp_N_m, kd_Ns_m : float
        Virtual spring and damper of the PD controller (handle space).
    velocity_filter_hz : float
    grip_N : float
        Grip of the (simulated or real) user during the test (0: handle free).
    """

    name: str
    ff_A: np.ndarray
    ref_m: np.ndarray | None = None
    kp_N_m: float = 0.0
    kd_Ns_m: float = 0.0
    velocity_filter_hz: float = 300.0
    grip_N: float = 0.0
    meta: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        """Number of servo ticks."""
        return int(self.ff_A.size)


@dataclass(frozen=True)
class Trace:
    """What a test recorded, one sample per servo tick.

    Attributes
    ----------
    x_m : ndarray
        Encoder (motor) position relative to the first sample, handle space (m).
    a_m_s2 : ndarray
        Handle acceleration (m/s^2).
    i_A : ndarray
        Commanded current (A) after the device's clamp.
    iamp_A : ndarray or None
        Amplifier output current (sense resistor), where the device can measure it.
    fs_hz : float
    """

    x_m: np.ndarray
    a_m_s2: np.ndarray
    i_A: np.ndarray
    fs_hz: float
    iamp_A: np.ndarray | None = None


def run_on_device(dev: Device, exp: Experiment, measure_current=None) -> Trace:
    """Play ``exp`` on a device with a plain scalar Python servo loop (hardware or sim).

    Parameters
    ----------
    dev : Device
        Open device; the user (grip) and mechanical configuration are set by the caller.
    exp : Experiment
    measure_current : callable or None
        ``measure_current() -> float`` amplifier output current after each tick (e.g. the sim's
        true state, or a current sensor), or None.

    Returns
    -------
    Trace
        Zero current is commanded afterwards, also on errors.
    """
    n = exp.n
    fs = dev.info.servo_rate_hz
    T = 1.0 / fs
    kf = dev.info.force_per_amp_N_A
    ff = exp.ff_A.tolist()
    closed = exp.ref_m is not None
    ref = exp.ref_m.tolist() if closed else None
    kp, kd = exp.kp_N_m / kf, exp.kd_Ns_m / kf
    va = 1.0 - math.exp(-2 * math.pi * exp.velocity_filter_hz * T)
    xs = np.empty(n)
    acc = np.empty(n)
    cmd = np.empty(n)
    cur = np.empty(n) if measure_current is not None else None
    read, command = dev.read, dev.command
    st = read()
    x0 = st.position_m
    x_prev = 0.0
    v = 0.0
    try:
        for k in range(n):
            st = read()
            x = st.position_m - x0
            xs[k] = x
            acc[k] = st.accel_m_s2
            i = ff[k]
            if closed:
                v += va * ((x - x_prev) * fs - v)
                i += kp * (ref[k] - x) - kd * v
            x_prev = x
            command(i)
            cmd[k] = dev.last_command_A
            if cur is not None:
                cur[k] = measure_current()
    finally:
        dev.command(0.0)
    return Trace(xs, acc, cmd, fs, cur)


def run_on_sim_device(dev, exp: Experiment, measure_current: bool = False) -> Trace | None:
    """:func:`run_on_device` on a :class:`devices.sim.SimDevice` just placed at rest (``set_user``), in one
    numba call: the same ticks, samples, clamp and delay as the Python servo loop, and the same device after
    it (tick count, pending current, noise stream, the closing zero command), about 6x faster.

    Parameters
    ----------
    dev : SimDevice
        Exactly a ``SimDevice`` whose ``set_user`` was the last thing done to it.
    exp : Experiment
    measure_current : bool
        Record the amplifier output current (the sim's sense resistor) after each tick.

    Returns
    -------
    Trace or None
        None where the compiled loop would not be the Python loop number for number (not a plain
        ``SimDevice`` at rest, no ticks, or a non-finite or huge value on the way, which the Python loop
        rejects where the compiled one clamps): the device is then as it was, for :func:`run_on_device`.
    """
    n = exp.n
    if type(dev).__name__ != "SimDevice" or n == 0:
        return None
    st = dev.read()
    res = dev.info.position_resolution_m
    # run_pd starts from the encoder reading of the state and no acceleration reading: what set_user shows
    if (dev._p[K.P_ENC_RES] != res or st.accel_m_s2 != 0.0
            or st.position_m != res * math.floor(dev._s[K.S_XM] / res)):
        return None
    fs = dev.info.servo_rate_hz
    T = 1.0 / fs
    kf = dev.info.force_per_amp_N_A
    closed = exp.ref_m is not None
    ff = np.ascontiguousarray(exp.ff_A, dtype=float)
    ref = np.ascontiguousarray(exp.ref_m, dtype=float) if closed else np.zeros(n)
    kp, kd = exp.kp_N_m / kf, exp.kd_Ns_m / kf
    va = 1.0 - math.exp(-2 * math.pi * exp.velocity_filter_hz * T)   # as run_on_device computes it
    big = 1e50      # below this every term of the control law stays finite, as in the Python loop
    if not (np.all(np.abs(ff) < big) and np.all(np.abs(ref) < big)
            and all(abs(g) < big for g in (kp, kd, va, fs))):
        return None
    traj, grip, k0 = dev.fused_plan(n + 1)
    if k0 != 0:
        return None
    s0, rs0 = dev._s.copy(), dev._rs.copy()
    xs, acc, cmd, cur = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    held = run_pd(dev._s, dev._p, dev._rs, traj, grip, ff, ref, closed, kp, kd, va, fs, dev._limit_A,
                  dev._held_A, xs, acc, cmd, cur)
    if not np.all(np.abs(xs) < big):
        dev._s[:] = s0          # a diverging device: the Python loop replays it, rejecting what it rejects
        dev._rs[:] = rs0
        return None
    dev._tick += n
    dev._held_A = held
    dev.last_command_A = held
    dev.command(0.0)            # run_on_device's closing command (it sets the whole state read shows)
    return Trace(xs, acc, cmd, fs, cur if measure_current else None)


_RUN = None


def run_on_sim_fast(dev, exp: Experiment, hand=None) -> Trace:
    """Play ``exp`` on a :class:`devices.sim.SimDevice` in one numba call (same law and timing as
    :func:`run_on_device`, used for the model side of every fit).

    Parameters
    ----------
    dev : SimDevice
        Placed at rest first (``set_user(None, grip)``).
    exp : Experiment
    hand : object or None
        The simulated person holding the handle (``set_user``'s ``hand``); None: the device's default.

    Returns
    -------
    Trace
        Including the amplifier output current.
    """
    global _RUN
    if _RUN is None:

        _RUN = run_pd
    if hand is None:
        dev.set_user(None, grip_N=exp.grip_N)
    else:
        dev.set_user(None, grip_N=exp.grip_N, hand=hand)
    n = exp.n
    fs = dev.info.servo_rate_hz
    kf = dev.info.force_per_amp_N_A
    traj = np.full(n + 2, dev._traj[0])
    grip = np.full(n + 2, float(exp.grip_N))
    ref = exp.ref_m if exp.ref_m is not None else np.zeros(n)
    xs, acc, cmd, cur = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    va = 1.0 - math.exp(-2 * math.pi * exp.velocity_filter_hz / fs)
    _RUN(dev._s, dev._p, dev._rs, traj, grip, np.ascontiguousarray(exp.ff_A, dtype=float),
         np.ascontiguousarray(ref, dtype=float), exp.ref_m is not None, exp.kp_N_m / kf, exp.kd_Ns_m / kf, va,
         fs, dev.info.current_amplifier_A, 0.0, xs, acc, cmd, cur)
    return Trace(xs, acc, cmd, fs, cur)


def virtual_spring_kd(kp_N_m: float, mass_kg: float, zeta: float = 0.1, fs_hz: float = 10000.0) -> float:
    """Damping gain for a lightly damped virtual spring: ``zeta`` of critical for ``mass_kg`` plus what the
    servo cycle's delay (about 1.5 periods, phase lag of the sampled PD law) takes away (kp * 1.5 T)."""
    return 2.0 * zeta * math.sqrt(kp_N_m * mass_kg) + kp_N_m * 1.5 / fs_hz


# ---- signal builders ------------------------------------------------------------------------------------------
def ramp_profile(fs_hz: float, distance_m: float, speed_m_s: float, dwell_s: float = 0.2):
    """Reference for slow closed-loop motion: rest, constant speed forward over ``distance_m``, dwell,
    back, rest. Returns (ref_m, mask_forward, mask_backward) with the masks covering the middle 60 % of
    each constant-speed leg (steady sliding)."""
    n_move = max(2, int(round(distance_m / speed_m_s * fs_hz)))
    n_dw = int(round(dwell_s * fs_hz))
    up = np.linspace(0.0, distance_m, n_move)
    ref = np.concatenate([np.zeros(n_dw), up, np.full(n_dw, distance_m), up[::-1], np.zeros(n_dw)])
    fwd = np.zeros(ref.size, bool)
    bwd = np.zeros(ref.size, bool)
    a, b = int(0.2 * n_move), int(0.8 * n_move)
    fwd[n_dw + a:n_dw + b] = True
    o = 2 * n_dw + n_move
    bwd[o + a:o + b] = True
    return ref, fwd, bwd


def step_sequence(fs_hz: float, steps_m, hold_s: float) -> np.ndarray:
    """Reference of successive position steps, each held ``hold_s``, starting from 0 for ``hold_s/4``.

    Parameters
    ----------
    fs_hz : float
    steps_m : sequence of float
        Step targets (m, handle space, relative to the start).
    hold_s : float

    Returns
    -------
    ndarray
        Reference position per servo tick (m).
    """
    n_h = int(round(hold_s * fs_hz))
    parts = [np.zeros(n_h // 4)] + [np.full(n_h, float(s)) for s in steps_m]
    return np.concatenate(parts)


def chirp(fs_hz: float, amplitude_A: float, f0_hz: float, f1_hz: float, duration_s: float,
          taper_s: float = 0.01) -> np.ndarray:
    """Linear swept sine (eq. 3.11-3.12) with short cosine tapers at both ends.

    Parameters
    ----------
    fs_hz : float
    amplitude_A : float
    f0_hz, f1_hz : float
        Start and end frequency.
    duration_s, taper_s : float

    Returns
    -------
    ndarray
        Current per servo tick (A).
    """
    n = int(round(duration_s * fs_hz))
    t = np.arange(n) / fs_hz
    u = amplitude_A * np.sin(2 * np.pi * (f0_hz * t + 0.5 * (f1_hz - f0_hz) / duration_s * t * t))
    m = max(1, int(taper_s * fs_hz))
    w = np.ones(n)
    w[:m] = 0.5 - 0.5 * np.cos(np.pi * np.arange(m) / m)
    w[n - m:] = w[:m][::-1]
    return u * w
