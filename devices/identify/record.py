"""Recording swept-sine trials on any :class:`devices.base.Device` (thesis section 3.4.1, 3.4.6)."""

from __future__ import annotations

import math

import numpy as np

from ..base import Device, DeviceError, Status
from ._fastplay import play_open
from .recording import Recording, check_recording
from .sweep import SweepConfig, swept_sine

# trials whose grip varies more than this (half peak-to-peak, N) are discarded and repeated (sec. 3.4.6)
GRIP_TOLERANCE_N = 0.5


def check_sweep_for_device(sweep: SweepConfig, dev: Device) -> None:
    """Refuse a sweep the device cannot play: wrong rate or amplitude above the continuous limit."""
    info = dev.info
    if abs(sweep.fs_hz - info.servo_rate_hz) > 1e-9 * info.servo_rate_hz:
        raise ValueError(f"sweep fs_hz {sweep.fs_hz} must equal the device's servo rate {info.servo_rate_hz} Hz")
    if sweep.amplitude_A > info.current_continuous_A:
        raise ValueError(f"sweep amplitude_A {sweep.amplitude_A} A exceeds the device's continuous current limit "
                         f"{info.current_continuous_A} A")


def hold_user(dev: Device, grip_N: float, log=None, timeout_s: float = 30.0) -> None:
    """Make the user hold the handle still at ``grip_N``.

    Simulated device: its hand holds still with that grip. Hardware: ask the
    user and wait (zero current) until the grip sensor stays within
    ``GRIP_TOLERANCE_N`` of the target for 0.5 s (section 3.4.6).

    Raises
    ------
    DeviceError
        If the grip does not settle within ``timeout_s``.
    """
    set_user = getattr(dev, "set_user", None)
    if dev.simulated and set_user is not None:
        set_user(None, grip_N=grip_N)
        return
    if log:
        log(f"hold the handle still with a grip of {grip_N:g} N")
    fs = dev.info.servo_rate_hz
    need = int(0.5 * fs)
    ok = 0
    for _ in range(int(timeout_s * fs)):
        st = dev.read()
        ok = ok + 1 if abs(st.grip_N - grip_N) <= GRIP_TOLERANCE_N else 0
        dev.command(0.0)
        if ok >= need:
            return
    raise DeviceError(f"grip did not settle at {grip_N} +- {GRIP_TOLERANCE_N} N within {timeout_s} s")


def play(dev: Device, current_A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Play a current sequence, one sample per servo tick, and record the state.

    Sample k holds the state read at tick k, just before ``current_A[k]`` is
    commanded (so the device's own delay appears in the model). The output is
    zeroed afterwards, also on errors.

    Returns
    -------
    t_s, accel_m_s2, position_m, grip_N : ndarray, shape (n,)
    """
    n = current_A.size
    if not np.all(np.isfinite(current_A)):
        raise ValueError("current sequence contains NaN/inf")
    if type(dev).__name__ == "SimDevice" and n > 0:
        return _play_sim(dev, np.ascontiguousarray(current_A, dtype=float))
    t = np.empty(n)
    a = np.empty(n)
    x = np.empty(n)
    g = np.empty(n)
    read = dev.read
    command = dev.command
    cur = current_A.tolist()  # plain floats: the servo path stays scalar Python
    try:
        for k in range(n):
            st = read()
            t[k] = st.t_s
            a[k] = st.accel_m_s2
            x[k] = st.position_m
            g[k] = st.grip_N
            command(cur[k])
    finally:
        dev.zero()
    return t, a, x, g


def _play_sim(dev, u: np.ndarray):
    """:func:`play` on a ``SimDevice`` in one numba call: the same ticks, clamp, delay and final state as the
    Python loop (tested tick for tick), about 4x faster."""

    n = u.size
    x, a, g = np.empty(n), np.empty(n), np.empty(n)
    st = dev.read()
    t0 = dev._tick
    traj, grip_plan, k0 = dev.fused_plan(n + 1)   # the hand's plan for these ticks (streamed: a window)
    try:
        held, pos, acc, grip, hot, clipped = play_open(
            dev._s, dev._p, dev._rs, traj, grip_plan, k0, dev._held_A, u,
            dev._limit_A, st.position_m, st.accel_m_s2, st.grip_N, x, a, g)
        dev._tick = t0 + n
        dev._held_A = held
        dev.last_command_A = held
        st.t_s = dev._tick * dev._period_s
        st.position_m, st.accel_m_s2, st.grip_N = pos, acc, grip
        st.status = (int(Status.CLIPPING) if clipped else 0) | (int(Status.OVER_TEMPERATURE) if hot else 0)
    finally:
        dev.zero()
    t = (t0 + np.arange(n)) * dev._period_s
    return t, a, x, g


def record_trial(dev: Device, sweep: SweepConfig, polarity: int = 1, grip_N: float | None = None,
                 trial: int = 0, settle_s: float = 0.1, log=None) -> Recording:
    """One swept-sine trial (``sweep.repetitions`` copies back to back) while the user holds the handle.

    Parameters
    ----------
    dev : Device
        Open device; its servo rate must equal ``sweep.fs_hz``.
    sweep : SweepConfig
    polarity : {1, -1}
    grip_N : float or None
        Grip the (simulated) user holds; on hardware the target shown to the user.
    trial : int
    settle_s : float
        Zero-current time before the sweep (the hand settles).

    Returns
    -------
    Recording
        ``t_s`` restarts at 0 at the first sweep sample.
    """
    check_sweep_for_device(sweep, dev)
    if grip_N is not None:
        if not (math.isfinite(grip_N) and grip_N >= 0):
            raise ValueError(f"grip_N must be a finite number >= 0, got {grip_N!r}")
        hold_user(dev, grip_N, log)
    n_settle = int(round(settle_s * sweep.fs_hz))
    u = np.concatenate([np.zeros(n_settle), swept_sine(sweep, polarity)])
    t, a, x, g = play(dev, u)
    sl = slice(n_settle, None)
    meta = {"polarity": polarity, "grip_target_N": grip_N, "trial": trial, "device": dev.info.name,
            "simulated": bool(dev.simulated), "grip_mean_N": float(np.mean(g[sl]))}
    return Recording(sweep, t[sl] - t[n_settle], u[sl], a[sl], x[sl], g[sl], meta)


def record_condition(dev: Device, sweep: SweepConfig, grip_N: float | None, trials: int = 4,
                     reverse_half: bool = True, grip_tolerance_N: float = GRIP_TOLERANCE_N,
                     max_attempts: int | None = None, log=None) -> list[Recording]:
    """``trials`` good trials at one grip level (section 3.4.6).

    A trial whose grip varies by more than ``grip_tolerance_N`` (half peak to
    peak over the analysed sweep) or that dropped samples is discarded and
    repeated, up to ``max_attempts`` (default 3 x trials). With
    ``reverse_half`` the second half of the trials run with reversed polarity.

    Raises
    ------
    DeviceError
        If too many trials had to be discarded.
    """
    max_attempts = max_attempts or 3 * trials
    good: list[Recording] = []
    attempts = 0
    while len(good) < trials:
        if attempts >= max_attempts:
            raise DeviceError(f"only {len(good)} of {trials} good trials at grip {grip_N} N after {attempts} "
                              f"attempts (grip must stay within +-{grip_tolerance_N} N, no dropped samples)")
        attempts += 1
        polarity = -1 if reverse_half and len(good) >= (trials + 1) // 2 else 1
        rec = record_trial(dev, sweep, polarity, grip_N, trial=len(good), log=log)
        reason = None
        try:
            check_recording(rec)
        except ValueError as exc:
            reason = str(exc)
        if reason is None and rec.grip_variation_N() > grip_tolerance_N:
            reason = f"grip varied +-{rec.grip_variation_N():.2f} N (> {grip_tolerance_N} N)"
        if reason is not None:
            if log:
                log(f"  discarded trial at grip {grip_N} N: {reason}; repeating")
            continue
        good.append(rec)
    return good
