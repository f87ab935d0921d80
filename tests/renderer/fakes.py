"""Small test devices for the renderer tests: a point mass held by a spring-damper hand.

Not a mock: a real :class:`devices.base.Device` subclass with simple physics
(semi-implicit Euler, 10 substeps per tick), a quantized encoder (floor, like
the sim device), a one-cycle output delay, and fault injection hooks.
"""

from __future__ import annotations

import math
import os
import struct
import time

from devices.base import Device, DeviceInfo, DeviceState


def make_info(**changes) -> DeviceInfo:
    base = dict(name="test-mass", encoder_lines=2000, gear_ratio=15.0, handle_length_m=0.15,
                torque_constant_Nm_A=0.0235, current_continuous_A=1.26, current_peak_A=4.0,
                current_amplifier_A=4.0, servo_rate_hz=10000.0, winding_resistance_ohm=2.32,
                thermal_resistance_K_W=14.0, thermal_time_constant_s=30.0, winding_max_temp_rise_K=51.5,
                simulated=True)
    base.update(changes)
    return DeviceInfo(**base)


def tap_trajectory(v_m_s: float, n_taps: int = 1, height_m: float = 0.01, press_m: float = 0.003,
                   dwell_s: float = 0.15, lift_s: float = 0.1, pause_s: float = 0.05):
    """Desired hand position x(t) (m): descend at ``v_m_s`` from ``height_m`` to ``-press_m``, dwell, lift, repeat."""
    t_down = (height_m + press_m) / v_m_s
    period = t_down + dwell_s + lift_s + pause_s

    def x_d(t: float) -> float:
        k = int(t // period)
        if k >= n_taps:
            return height_m
        tt = t - k * period
        if tt < t_down:
            return height_m - v_m_s * tt
        tt -= t_down
        if tt < dwell_s:
            return -press_m
        tt -= dwell_s
        if tt < lift_s:
            return -press_m + (height_m + press_m) * 0.5 * (1.0 - math.cos(math.pi * tt / lift_s))
        return height_m

    x_d.duration_s = n_taps * period
    x_d.crossings_s = [k * period + height_m / v_m_s for k in range(n_taps)]
    return x_d


class MassDevice(Device):
    """Handle of mass ``mass_kg`` pulled by a hand spring-damper ``(k, b) = grip * (k_per_N, b_per_N)``.

    Parameters
    ----------
    trajectory : callable t_s -> desired position (m), or None (hold at ``x0_m``)
    grip_N : float
    nan_at : set of int
        Ticks at which ``read()`` reports a NaN position.
    nan_from : int or None
        From this tick on every position is NaN.
    raise_at : int or None
        ``read()`` raises RuntimeError at this tick.
    """

    def __init__(self, trajectory=None, grip_N: float = 2.0, mass_kg: float = 0.03, k_per_N: float = 100.0,
                 b_per_N: float = 2.0, x0_m: float = 0.01, info: DeviceInfo | None = None, nan_at=(),
                 nan_from: int | None = None, raise_at: int | None = None, quantize: bool = True,
                 substeps: int = 10, record: bool = True):
        super().__init__()
        self.info = info or make_info()
        self.traj = trajectory or (lambda t: x0_m)
        self.grip_N = grip_N
        self.m = mass_kg
        self.k_h = k_per_N * grip_N
        self.b_h = b_per_N * grip_N
        self.dt = 1.0 / self.info.servo_rate_hz
        self.x = float(self.traj(0.0))
        self.v = 0.0
        self.a = 0.0
        self.tick = 0
        self.pending_A = 0.0
        self.applied = []  # every current actually sent (tests only)
        self.nan_at = set(nan_at)
        self.nan_from = nan_from
        self.raise_at = raise_at
        self.quantize = quantize
        self.substeps = substeps
        self.record = record
        self.q = self.info.position_resolution_m
        self.state = DeviceState()
        self._update_state()

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _update_state(self) -> None:
        s = self.state
        s.t_s = self.tick * self.dt
        s.position_m = self.q * math.floor(self.x / self.q) if self.quantize else self.x
        if self.tick in self.nan_at or (self.nan_from is not None and self.tick >= self.nan_from):
            s.position_m = math.nan
        s.accel_m_s2 = self.a
        s.grip_N = self.grip_N

    def read(self) -> DeviceState:
        if self.raise_at is not None and self.tick == self.raise_at:
            raise RuntimeError("injected failure in read()")
        return self.state

    def _send_current(self, current_A: float) -> None:
        if self.record:
            self.applied.append(current_A)
        if self._in_command:  # a servo cycle: the previous command takes effect now (one-cycle delay)
            applied = self.pending_A
            self.pending_A = current_A
            self._step(applied)
        else:  # open/close/zero: a safety action, no time passes
            self.pending_A = current_A

    _in_command = False

    def command(self, current_A: float) -> None:
        self._in_command = True
        try:
            super().command(current_A)
        finally:
            self._in_command = False

    def _step(self, current_A: float) -> None:
        f_motor = self.info.force_per_amp_N_A * current_A
        sub = self.substeps
        h = self.dt / sub
        t = self.tick * self.dt
        for j in range(sub):
            tt = t + j * h
            xd = self.traj(tt)
            vd = (self.traj(tt + h) - xd) / h
            self.a = (f_motor + self.k_h * (xd - self.x) + self.b_h * (vd - self.v)) / self.m
            self.v += self.a * h
            self.x += self.v * h
        self.tick += 1
        self._update_state()

    @property
    def true_velocity_m_s(self) -> float:
        return self.v


class TrueVelocityProbe(Device):
    """Wraps a SimDevice and records its true motor velocity at every ``read()`` (keyed by servo tick).

    The encoder measures the motor position, so the motor velocity is the
    "true velocity" an estimator from encoder counts should find.
    """

    def __init__(self, sim):
        super().__init__()
        self.sim = sim
        self.info = sim.info
        self.true_velocity = {}
        self.fs = sim.info.servo_rate_hz

    def _open(self) -> None:
        self.sim.open()

    def _close(self) -> None:
        self.sim.close()

    def read(self):
        s = self.sim.read()
        self.true_velocity[round(s.t_s * self.fs)] = self.sim.true_state()["motor_velocity_m_s"]
        return s

    def command(self, current_A: float) -> None:
        self.sim.command(current_A)
        self.last_command_A = self.sim.last_command_A

    def _send_current(self, current_A: float) -> None:
        self.sim._send_current(current_A)


def make_tap_device():
    """Picklable factory for renderer.process tests: one 0.1 m/s tap on a MassDevice."""
    return MassDevice(tap_trajectory(0.1, n_taps=1), grip_N=2.0)


class _AnnouncingMassDevice(MassDevice):
    """A :class:`MassDevice` that sets the multiprocessing event ``made`` at its first ``read()``: the loop's
    first tick, after the child's imports and the loop's own set-up (loading compiled code can take over a
    second on a loaded machine)."""

    def __init__(self, made, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._made = made
        self._reads = 0

    def read(self) -> DeviceState:
        # the loop's priming cycle reads twice (then warms the law and asks for its real-time policy):
        # the third read is the first tick's
        self._reads += 1
        if self._made is not None and self._reads == 3:
            self._made.set()
            self._made = None
        return super().read()


def make_tap_device_announced(made):
    """:func:`make_tap_device` that sets the multiprocessing event ``made`` once the run in the child process
    has started (its first tick): a parent stops a run only after it has started."""
    return _AnnouncingMassDevice(made, tap_trajectory(0.1, n_taps=1), grip_N=2.0)


def make_failing_device():
    return MassDevice(tap_trajectory(0.1, n_taps=1), raise_at=200)


def _pressing(t: float) -> float:
    """The hand's target 5 mm under the wall at 0: the wall pushes back with a steady current (~0.3 A)."""
    return -0.005


class RecordingMassDevice(MassDevice):
    """A :class:`MassDevice` pressed into the wall that appends every current it is sent (float64, also the
    open/zero/close ones) to the file ``path``, and its process id to ``path + ".pid"``: tests that stop the
    process driving it read what reached the "motor" last. ``hang_at``: from this tick on ``read()`` blocks
    (a stalled link), so only a signal can end the run."""

    def __init__(self, path: str, hang_at: int | None = None):
        super().__init__(_pressing, grip_N=2.0, record=False)
        self.path = path
        self.hang_at = hang_at
        self._fd = None

    def _open(self) -> None:
        with open(self.path + ".pid", "w") as fh:
            fh.write(str(os.getpid()))
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)

    def _close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def _send_current(self, current_A: float) -> None:
        if self._fd is not None:
            os.write(self._fd, struct.pack("<d", current_A))
        super()._send_current(current_A)

    def read(self) -> DeviceState:
        if self.hang_at is not None and self.tick >= self.hang_at:
            while True:
                time.sleep(0.05)
        return super().read()


def make_recording_device(path: str, hang_at: int | None = None) -> RecordingMassDevice:
    """Picklable factory (with functools.partial) of a :class:`RecordingMassDevice`."""
    return RecordingMassDevice(path, hang_at)


def recorded_currents(path):
    """The currents a :class:`RecordingMassDevice` was sent, in order (A), as a numpy array."""
    import numpy as np

    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except FileNotFoundError:
        return np.zeros(0)
    return np.frombuffer(data[:8 * (len(data) // 8)], dtype="<f8")
