"""The device interface: a 1-DOF impedance-type haptic interface.

Every device (simulated, serial, HID) implements :class:`Device`. The
renderer, the identification code and the study runner talk to devices only
through this interface, so they run unchanged on hardware and in simulation.

Conventions (SI units throughout)
---------------------------------
* ``position_m`` is the motor position mapped to the handle endpoint through
  the gear ratio and handle length (thesis eq. 3.2-3.4), positive *up*, zero
  at the nominal surface height. A tap comes from above, so the incoming
  velocity is negative; events report its magnitude.
* Force and current are positive *up* (away from a surface below the
  handle). Force at the handle and motor current are related by
  ``F = rho * k_t * i / h`` (thesis eq. 3.17); see
  :attr:`DeviceInfo.force_per_amp_N_A`.

A servo cycle is ``state = dev.read()`` followed by ``dev.command(i)``.
``read()`` returns the *same* mutable :class:`DeviceState` object every call,
updated in place, so the servo path allocates nothing; copy fields out if you
keep them. Simulated devices advance their physics by one servo period on each
``command()``; hardware devices block in ``read()`` until the next state frame.
"""

from __future__ import annotations

import enum
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

from plumbing.errors import UserError
from plumbing.stopsignals import holding


class Status(enum.IntFlag):
    """Status bits reported with every state sample (also the wire format)."""

    OK = 0
    FAULT = 1
    OVER_TEMPERATURE = 2
    WATCHDOG_TRIPPED = 4
    CLIPPING = 8
    SENSOR_INVALID = 16
    DISCONNECTED = 32
    UNSTABLE = 64  # the on-device wall's passivity observer stopped rendering (with FAULT; protocol 1.1)


@dataclass(frozen=True)
class DeviceInfo:
    """Static description of a device (what the hello handshake reports).

    Attributes
    ----------
    name : str
    encoder_lines : int
        Encoder lines per motor revolution (quadrature gives 4x counts,
        thesis eq. 3.2).
    gear_ratio : float
        Unitless motor-to-drum ratio rho.
    handle_length_m : float
        Drum axis to handle endpoint, h.
    torque_constant_Nm_A : float
        Motor torque constant k_t.
    current_continuous_A, current_peak_A, current_amplifier_A : float
        Continuous (thermal) limit, short-duration peak limit for transients,
        and the amplifier's hard output limit (>= peak).
    servo_rate_hz : float
        Native servo rate.
    winding_resistance_ohm, thermal_resistance_K_W, thermal_time_constant_s,
    winding_max_temp_rise_K : float
        First-order winding thermal model (I^2 R heating) parameters.
    accel_range_m_s2 : float
        Accelerometer full scale (+/-).
    grip_range_N : tuple of float
        Range the grip sensor can measure.
    capabilities : tuple of str
        e.g. ``("streaming",)`` or ``("streaming", "on_device")``.
    simulated : bool
        A simulated device (no link; one servo period per command).
    lockstep_ticks : int
        0 for a device on the wall clock. Otherwise the device's clock is simulated and advances this many
        of its servo ticks per host command (INFO flags bit 1, bits 8-15; ``fw-sim``'s lockstep pace):
        a streaming host runs at ``servo_rate_hz / lockstep_ticks`` paced on the device's clock, not the
        wall clock (docs/protocol.md, "Lockstep").
    """

    name: str
    encoder_lines: int
    gear_ratio: float
    handle_length_m: float
    torque_constant_Nm_A: float
    current_continuous_A: float
    current_peak_A: float
    current_amplifier_A: float
    servo_rate_hz: float
    winding_resistance_ohm: float = 2.0
    thermal_resistance_K_W: float = 8.0
    thermal_time_constant_s: float = 30.0
    winding_max_temp_rise_K: float = 80.0
    accel_range_m_s2: float = 490.0
    grip_range_N: tuple[float, float] = (0.0, 10.0)
    capabilities: tuple[str, ...] = ("streaming",)
    simulated: bool = False
    lockstep_ticks: int = 0

    def __post_init__(self) -> None:
        if not (isinstance(self.lockstep_ticks, int) and 0 <= self.lockstep_ticks <= 255):
            raise ValueError(f"DeviceInfo.lockstep_ticks must be a whole number in 0..255, got {self.lockstep_ticks!r}")
        positive = {
            "encoder_lines": self.encoder_lines,
            "gear_ratio": self.gear_ratio,
            "handle_length_m": self.handle_length_m,
            "torque_constant_Nm_A": self.torque_constant_Nm_A,
            "current_continuous_A": self.current_continuous_A,
            "current_peak_A": self.current_peak_A,
            "current_amplifier_A": self.current_amplifier_A,
            "servo_rate_hz": self.servo_rate_hz,
            "winding_resistance_ohm": self.winding_resistance_ohm,
            "thermal_resistance_K_W": self.thermal_resistance_K_W,
            "thermal_time_constant_s": self.thermal_time_constant_s,
            "winding_max_temp_rise_K": self.winding_max_temp_rise_K,
        }
        for key, value in positive.items():
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"DeviceInfo.{key} must be a positive finite number, got {value!r}")
        if not self.current_continuous_A <= self.current_peak_A <= self.current_amplifier_A:
            raise ValueError(
                "DeviceInfo current limits must satisfy continuous <= peak <= amplifier, got "
                f"{self.current_continuous_A}, {self.current_peak_A}, {self.current_amplifier_A}"
            )

    @property
    def force_per_amp_N_A(self) -> float:
        """Handle force per amp of motor current, rho*k_t/h (thesis eq. 3.17)."""
        return self.gear_ratio * self.torque_constant_Nm_A / self.handle_length_m

    @property
    def position_resolution_m(self) -> float:
        """Handle travel per encoder count (4x quadrature), eq. 3.2-3.3 mapped through rho and h."""
        return 2.0 * math.pi * self.handle_length_m / (4.0 * self.encoder_lines * self.gear_ratio)

    @property
    def lockstep_rate_hz(self) -> float | None:
        """The streaming rate of a lockstep device (``servo_rate_hz / lockstep_ticks``), None on the wall clock."""
        return self.servo_rate_hz / self.lockstep_ticks if self.lockstep_ticks else None


@dataclass
class DeviceState:
    """One state sample. Mutable and reused by ``Device.read()``; see module doc."""

    t_s: float = 0.0
    position_m: float = 0.0
    accel_m_s2: float = 0.0
    grip_N: float = 0.0
    status: int = 0
    extra: dict = field(default_factory=dict)

    def copy(self) -> "DeviceState":
        """A copy that later reads do not change (``read()`` updates its state object in place)."""
        return DeviceState(self.t_s, self.position_m, self.accel_m_s2, self.grip_N, self.status, dict(self.extra))


class DeviceError(UserError):
    """A device could not be opened, spoke garbage, timed out or disconnected."""


class Device(ABC):
    """Abstract 1-DOF impedance-type haptic device.

    Subclasses implement :meth:`_open`, :meth:`_close`, :meth:`read` and
    :meth:`_send_current`. The base class guarantees that the output is zeroed
    on every exit path (``close``, context-manager exit, exceptions,
    garbage collection) and that a NaN/inf or out-of-range command never
    reaches the motor: non-finite commands become zero and raise a FAULT
    status bit, finite ones are clamped to ``info.current_amplifier_A``.
    """

    info: DeviceInfo

    def __init__(self) -> None:
        self._is_open = False
        self.last_command_A = 0.0
        self.rejected_commands = 0

    # -- lifecycle -------------------------------------------------------
    def open(self) -> "Device":
        """Open the device and command 0 A; returns the device (idempotent; use as a context manager)."""
        if not self._is_open:
            self._open()
            self._is_open = True
            self._send_current(0.0)
        return self

    def close(self) -> None:
        """Command 0 A, then release the device (idempotent; the zero is sent even if closing fails).

        A SIGTERM/SIGHUP arriving meanwhile (plumbing.stopsignals) is raised after it, not in the middle."""
        if self._is_open:
            with holding():
                try:
                    self._send_current(0.0)
                    self.last_command_A = 0.0
                finally:
                    self._is_open = False
                    self._close()

    def __enter__(self) -> "Device":
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:  # last line of defence; close() is idempotent
        try:
            self.close()
        except Exception:
            pass

    @property
    def is_open(self) -> bool:
        """True between ``open()`` and ``close()``."""
        return self._is_open

    # -- servo cycle -----------------------------------------------------
    @abstractmethod
    def read(self) -> DeviceState:
        """Return the current state sample (the same object, updated in place)."""

    def command(self, current_A: float) -> None:
        """Command motor current in A (positive = force up). Safe against NaN/inf."""
        limit = self.info.current_amplifier_A
        if current_A != current_A or current_A in (math.inf, -math.inf):
            self.rejected_commands += 1
            current_A = 0.0
        elif current_A > limit:
            current_A = limit
        elif current_A < -limit:
            current_A = -limit
        self.last_command_A = current_A
        self._send_current(current_A)

    def zero(self) -> None:
        """Command zero current now."""
        self.last_command_A = 0.0
        self._send_current(0.0)

    # -- subclass hooks --------------------------------------------------
    @abstractmethod
    def _open(self) -> None: ...

    @abstractmethod
    def _close(self) -> None: ...

    @abstractmethod
    def _send_current(self, current_A: float) -> None:
        """Send an already-validated current. Simulated devices advance one servo period here."""

    @property
    def simulated(self) -> bool:
        """True for a simulated device (``info.simulated``)."""
        return self.info.simulated
