"""The device interface: impedance-type haptic interfaces with one or three axes.

Every device (simulated, serial, HID, and the adapters of commercial 3-DOF
devices) implements :class:`Device`. The renderer, the identification code and
the study runner talk to devices only through this interface, so they run
unchanged on hardware and in simulation. A 1-DOF device is the one-axis case of
the same interface (``info.axes == 1``: its axis is the device frame's z, x and
y read 0), modelled on CHAI3D's ``cGenericHapticDevice``: read a state (position
and velocity 3-vectors, buttons, grip), command a force 3-vector
(:meth:`Device.command_force`), and describe what a renderer needs
(:meth:`DeviceInfo.specs`: workspace, maximum force, maximum closed-loop
stiffness, native servo rate, linear or with a Jacobian). docs/architecture.md
("Multi-axis device interface") is the adapter writer's contract.

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
* **Device frame** (every device, CHAI3D's convention): right-handed, metres,
  origin at the workspace centre, **z up** (against gravity), x towards the
  user, y to the user's right. ``DeviceState.position_m`` is z; ``x_m``,
  ``y_m`` the other two (0 on a 1-DOF device). Forces are in the same frame,
  in newtons, applied at the endpoint (the stylus tip, or the handle).

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
    axes : int
        1 (the 1-DOF testbed: one motor, the device frame's z) or 3 (a point endpoint in x, y, z).
    workspace_min_m, workspace_max_m : tuple of 3 floats or None
        Corners of the box (device frame, m) the endpoint can reach; None: the 1-DOF default
        (x = y = 0, z within +/- ``0.3 handle_length_m``).
    max_force_N, max_peak_force_N : float or None
        Largest force magnitude the device renders continuously and for short transients (N);
        None: ``current_continuous_A`` / ``current_peak_A`` times ``force_per_amp_N_A``.
    max_stiffness_N_m : float or None
        Largest closed-loop stiffness the device renders stably (N/m; CHAI3D's
        ``m_maxLinearStiffness``); None: the stiffness at which one encoder count commands the
        continuous force (``devices.limits.one_count_stiffness_N_m``).
    linear : bool
        True for a device whose endpoint moves in proportion to its motors (the 1-DOF testbed, a
        Cartesian stage); False for a linkage with a configuration-dependent Jacobian (delta,
        serial arm): its driver maps forces to motor torques with ``J^T`` (:meth:`Device.jacobian`).
    buttons : int
        Number of user buttons reported in ``DeviceState.buttons`` (bit i = button i pressed).
    lockstep_ticks : int
        0 for a device on the wall clock. Otherwise the device's clock is simulated and advances this many
        of its servo ticks per host command (INFO flags bit 1, bits 8-15; ``fw-sim``'s lockstep pace):
        a streaming host runs at ``servo_rate_hz / lockstep_ticks`` paced on the device's clock, not the
        wall clock (docs/protocol.md, "Lockstep").
    emulated : bool
        The device on the link is an emulator, not hardware (INFO flags bit 2: the project's firmware emulator,
        ``python -m devices emulator``): it has a link and the board's protocol, so the hardware path runs
        (``simulated`` stays False), but no motor, no sensor and no person. Recorded with the device in
        ``run.json`` and ``session.json`` so that an emulator's data are never taken for a person's.
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
    emulated: bool = False
    axes: int = 1
    workspace_min_m: tuple[float, float, float] | None = None
    workspace_max_m: tuple[float, float, float] | None = None
    max_force_N: float | None = None
    max_peak_force_N: float | None = None
    max_stiffness_N_m: float | None = None
    linear: bool = True
    buttons: int = 0

    def __post_init__(self) -> None:
        if self.axes not in (1, 3):
            raise ValueError(f"DeviceInfo.axes must be 1 or 3, got {self.axes!r}")
        if (self.workspace_min_m is None) != (self.workspace_max_m is None):
            raise ValueError("DeviceInfo.workspace_min_m and workspace_max_m must be given together")
        if self.workspace_min_m is not None:
            lo, hi = tuple(self.workspace_min_m), tuple(self.workspace_max_m)
            if len(lo) != 3 or len(hi) != 3 or not all(math.isfinite(a) and math.isfinite(b) and a <= b
                                                       for a, b in zip(lo, hi)):
                raise ValueError(f"DeviceInfo workspace must be two finite 3-vectors with min <= max, got {lo}, {hi}")
            object.__setattr__(self, "workspace_min_m", tuple(float(a) for a in lo))
            object.__setattr__(self, "workspace_max_m", tuple(float(b) for b in hi))
        for key in ("max_force_N", "max_peak_force_N", "max_stiffness_N_m"):
            value = getattr(self, key)
            if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"DeviceInfo.{key} must be a positive finite number or None, got {value!r}")
        if not (isinstance(self.buttons, int) and 0 <= self.buttons <= 32):
            raise ValueError(f"DeviceInfo.buttons must be a whole number in 0..32, got {self.buttons!r}")
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

    def specs(self) -> "DeviceSpecs":
        """What a renderer needs to know of the device (CHAI3D's ``cHapticDeviceInfo``), defaults filled in.

        Returns
        -------
        DeviceSpecs
        """
        kf = self.force_per_amp_N_A
        if self.workspace_min_m is None:
            half = 0.3 * self.handle_length_m
            lo, hi = (0.0, 0.0, -half), (0.0, 0.0, half)
        else:
            lo, hi = self.workspace_min_m, self.workspace_max_m
        f_c = self.max_force_N if self.max_force_N is not None else self.current_continuous_A * kf
        f_pk = self.max_peak_force_N if self.max_peak_force_N is not None else self.current_peak_A * kf
        f_pk = max(f_pk, f_c)
        k_max = (self.max_stiffness_N_m if self.max_stiffness_N_m is not None
                 else self.current_continuous_A * kf / self.position_resolution_m)
        return DeviceSpecs(axes=self.axes, workspace_min_m=lo, workspace_max_m=hi, max_force_N=f_c,
                           max_peak_force_N=f_pk, max_stiffness_N_m=k_max, servo_rate_hz=self.servo_rate_hz,
                           linear=self.linear, buttons=self.buttons, position_resolution_m=self.position_resolution_m,
                           senses_grip=self.grip_range_N[1] > self.grip_range_N[0])

    @property
    def on_device_clock(self) -> bool:
        """True when the device's own clock paces the servo loop (a simulation, or a lockstep device whose clock
        waits for the host): the host neither paces it on the wall clock nor watches it with a wall-clock
        watchdog. False for hardware on the wall clock, which the host paces every tick."""
        return self.simulated or bool(self.lockstep_ticks)

    @property
    def lockstep_rate_hz(self) -> float | None:
        """The streaming rate of a lockstep device (``servo_rate_hz / lockstep_ticks``), None on the wall clock."""
        return self.servo_rate_hz / self.lockstep_ticks if self.lockstep_ticks else None


@dataclass(frozen=True)
class DeviceSpecs:
    """The specifications a renderer needs (CHAI3D's ``cHapticDeviceInfo``), every field filled in.

    From :meth:`DeviceInfo.specs`. Device frame and units as in the module doc.

    Attributes
    ----------
    axes : int
        1 or 3.
    workspace_min_m, workspace_max_m : tuple of 3 floats
        The box the endpoint reaches (m, device frame); a scene's objects must fit in it.
    max_force_N : float
        Largest force magnitude the wall (continuous) channel may command (N).
    max_peak_force_N : float
        Largest force magnitude of wall plus transient (N), for short transients.
    max_stiffness_N_m : float
        Largest stiffness the device renders stably (N/m); a scene object stiffer than this is refused.
    servo_rate_hz : float
        Native servo rate.
    linear : bool
        False: the endpoint Jacobian depends on the configuration (:meth:`Device.jacobian`).
    buttons : int
        Buttons reported in ``DeviceState.buttons``.
    position_resolution_m : float
        Endpoint travel per encoder count (m; the coarsest axis on a linkage).
    senses_grip : bool
        ``DeviceState.grip_N`` is measured (a grip sensor or a gripper force), not a constant.
    """

    axes: int
    workspace_min_m: tuple[float, float, float]
    workspace_max_m: tuple[float, float, float]
    max_force_N: float
    max_peak_force_N: float
    max_stiffness_N_m: float
    servo_rate_hz: float
    linear: bool
    buttons: int
    position_resolution_m: float
    senses_grip: bool

    def contains(self, point_m) -> bool:
        """True if ``point_m`` (x, y, z in m) lies inside the workspace box (its edges included)."""
        return all(lo <= p <= hi for lo, p, hi in zip(self.workspace_min_m, point_m, self.workspace_max_m))


@dataclass
class DeviceState:
    """One state sample. Mutable and reused by ``Device.read()``; see module doc.

    Attributes
    ----------
    t_s : float
        Device time of the sample (s): when it was sampled, on the device's own clock where the driver knows it
        (a state read twice carries the same time), else the reply's wall-clock time. The servo laws place
        positions by it (``renderer.ring``); with a driver whose time never advances they fall back to one
        position per tick after ``max_catchup_s`` (their velocity reads 0 until then).
    position_m : float
        Endpoint z (m, up; the 1-DOF device's handle position).
    accel_m_s2 : float
        Measured acceleration (m/s^2) along the device's accelerometer axis (z on the 1-DOF device;
        on a 3-axis device the component along ``accel_axis``; NaN when there is none).
    grip_N : float
        Grip force (N): a grip sensor, or a gripper's force; 0 when not sensed.
    status : int
        :class:`Status` bits.
    extra : dict
        Driver-specific values (``contact_force_N`` of a force sensor, a link's error text).
    x_m, y_m : float
        Endpoint x and y (m, device frame); 0 on a 1-DOF device.
    vx_m_s, vy_m_s, vz_m_s : float
        Endpoint velocity (m/s) when the device measures or estimates it (a Force Dimension device
        does), else NaN: the renderer then estimates it from positions.
    buttons : int
        Bit i set while user button i is pressed.
    """

    t_s: float = 0.0
    position_m: float = 0.0
    accel_m_s2: float = 0.0
    grip_N: float = 0.0
    status: int = 0
    extra: dict = field(default_factory=dict)
    x_m: float = 0.0
    y_m: float = 0.0
    vx_m_s: float = math.nan
    vy_m_s: float = math.nan
    vz_m_s: float = math.nan
    buttons: int = 0

    @property
    def z_m(self) -> float:
        """Endpoint z (m): the same number as ``position_m``."""
        return self.position_m

    def position3(self) -> tuple[float, float, float]:
        """Endpoint (x, y, z) in m (a new tuple: not for the servo path, which reads the fields)."""
        return (self.x_m, self.y_m, self.position_m)

    def velocity3(self) -> tuple[float, float, float]:
        """Endpoint velocity (vx, vy, vz) in m/s, NaN where not measured."""
        return (self.vx_m_s, self.vy_m_s, self.vz_m_s)

    def copy(self) -> "DeviceState":
        """A copy that later reads do not change (``read()`` updates its state object in place)."""
        return DeviceState(self.t_s, self.position_m, self.accel_m_s2, self.grip_N, self.status, dict(self.extra),
                           self.x_m, self.y_m, self.vx_m_s, self.vy_m_s, self.vz_m_s, self.buttons)


class DeviceError(UserError):
    """A device could not be opened, spoke garbage, timed out or disconnected."""


class Device(ABC):
    """Abstract impedance-type haptic device, one axis (current command) or three (force command).

    Subclasses implement :meth:`_open`, :meth:`_close` and :meth:`read`, and the output hooks:
    a 1-axis device :meth:`_send_current` (the motor current; :meth:`command_force` maps the force's
    z component onto it, eq. 3.17), a 3-axis device :meth:`_send_force` and :meth:`_send_zero`. The
    base class guarantees that the output is zeroed on every exit path (``close``, context-manager
    exit, exceptions, garbage collection) and that a NaN/inf or out-of-range command never reaches a
    motor: a non-finite command becomes zero (counted in ``rejected_commands``), a finite current is
    clamped to ``info.current_amplifier_A``, a finite force's magnitude to the peak force of
    :meth:`DeviceInfo.specs` (its direction kept). The separate continuous/peak limits of a wall and
    its transient are the renderer's (``docs/renderer.md``, "Saturation"); per-motor limits after the
    Jacobian are the driver's.
    """

    info: DeviceInfo

    def __init__(self) -> None:
        self._is_open = False
        self.last_command_A = 0.0
        self.last_force_N = (0.0, 0.0, 0.0)
        self.rejected_commands = 0
        self._force_limit_N = None

    # -- lifecycle -------------------------------------------------------
    def open(self) -> "Device":
        """Open the device and zero its output; returns the device (idempotent; use as a context manager)."""
        if not self._is_open:
            self._open()
            self._is_open = True
            self._send_zero()
        return self

    def close(self) -> None:
        """Zero the output, then release the device (idempotent; the zero is sent even if closing fails).

        A SIGTERM/SIGHUP arriving meanwhile (plumbing.stopsignals) is raised after it, not in the middle."""
        if self._is_open:
            with holding():
                try:
                    self._send_zero()
                    self.last_command_A = 0.0
                    self.last_force_N = (0.0, 0.0, 0.0)
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
        """Command motor current in A (positive = force up; 1-axis devices). Safe against NaN/inf."""
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

    def command_force(self, fx_N: float, fy_N: float, fz_N: float) -> None:
        """Command the endpoint force (N, device frame) for the next servo period. Safe against NaN/inf.

        A non-finite component zeroes the whole command (counted in ``rejected_commands``); a magnitude
        above the device's peak force (:meth:`DeviceInfo.specs`) is scaled down to it, direction kept.
        A 1-axis device renders ``fz_N`` (``current = fz_N / force_per_amp_N_A``, eq. 3.17, then
        :meth:`command`'s clamp) and ignores x and y, which it cannot push. Plain scalar arithmetic
        (no allocation): the servo path calls it every tick.
        """
        limit = getattr(self, "_force_limit_N", None)
        if limit is None:
            limit = self._force_limit_N = self.info.specs().max_peak_force_N
        m2 = fx_N * fx_N + fy_N * fy_N + fz_N * fz_N
        if m2 != m2 or m2 == math.inf:
            self.rejected_commands += 1
            fx_N = fy_N = fz_N = 0.0
        elif m2 > limit * limit:
            scale = limit / math.sqrt(m2)
            fx_N *= scale
            fy_N *= scale
            fz_N *= scale
        self.last_force_N = (fx_N, fy_N, fz_N)
        self._send_force(fx_N, fy_N, fz_N)

    def zero(self) -> None:
        """Zero the output now (every motor)."""
        self.last_command_A = 0.0
        self.last_force_N = (0.0, 0.0, 0.0)
        self._send_zero()

    def jacobian(self):
        """The endpoint Jacobian at the last sample (3 x n_motors, m per motor unit), or None for a linear
        device (``info.linear``). Drivers of linkages return it; the renderer only reads it (for
        direction-dependent limits), the driver applies ``J^T`` itself."""
        return None

    # -- subclass hooks --------------------------------------------------
    @abstractmethod
    def _open(self) -> None: ...

    @abstractmethod
    def _close(self) -> None: ...

    def _send_current(self, current_A: float) -> None:
        """Send an already-validated current (1-axis devices). Simulated devices advance one servo period here."""
        raise DeviceError(f"{self.info.name}: a {self.info.axes}-axis device takes forces (command_force), "
                          "not a motor current")

    def _send_force(self, fx_N: float, fy_N: float, fz_N: float) -> None:
        """Send an already-validated force (N, device frame). 1-axis default: the z component as a current."""
        if self.info.axes != 1:
            raise NotImplementedError(f"{type(self).__name__} must implement _send_force")
        self.command(fz_N / self.info.force_per_amp_N_A)

    def _send_zero(self) -> None:
        """Zero every motor now (open, close, zero, errors). 1-axis default: ``_send_current(0.0)``."""
        if self.info.axes == 1:
            self._send_current(0.0)
        else:
            self._send_force(0.0, 0.0, 0.0)

    @property
    def simulated(self) -> bool:
        """True for a simulated device (``info.simulated``)."""
        return self.info.simulated
