"""WoodenHaptics' USB HID reports and kinematics: pure functions, no I/O.

Sources (read and cited, not copied: the firmware is GPL v3, the host driver BSD; the formulas below are
restated in this module's own code):

* Firmware ``mbed-code/WoodenHapticsHID/main.cpp`` of github.com/WoodenHaptics/woody-experimental
  ("WoodenHaptics 1.5 USB HID interface", Jordi Solsona and Jonas Forsslund, 2015-2019). The board is an
  mbed USB HID device (vendor 0x1234, product 0x0006) with 8-byte input and output reports. The input report
  carries the three encoder counters (x4 quadrature) as signed 16-bit integers and an unsigned 16-bit
  counter the firmware increments before every report; the output report carries three signed 16-bit motor
  commands in the firmware's milliampere units and a 16-bit debug field. The firmware turns a command of
  ``n`` into a current of ``n / 1000`` A, its sign choosing the direction, and drives the amplifier's PWM at
  ``0.1 + 0.8 |i| / 3`` (saturating at 0.9 above 3 A). A watchdog re-armed by every command disables the
  ESCON amplifiers after 0.5 s without one. The LPC1768 is little-endian: low byte first.
* Host driver ``chai3d-3.0.0-woody/src/devices/CWoodenDevice.cpp`` of the same repository (CHAI3D's BSD
  licence). It opens the board by those ids and writes a 9-byte buffer (report id 0 and the 8 bytes). It
  negates the first encoder; a joint angle is ``2 pi counts / cpr`` divided by a signed gear ratio
  (body diameter over capstan diameter, negative for joint B). Its forward kinematics (the variant dated
  2016-05-30) replaces ``tC`` by ``pi/2 - tC`` (with pi written as 3.141592) and puts the end effector at
  ``r cos tA - ox``, ``r sin tA - oy``, ``La + Lb cos tB - Lc cos tC - oz`` with ``r = Lb sin tB + Lc sin tC``.
  The joint torques are ``J^T f`` plus a gravity term from the masses and centre-of-mass distances of bodies
  B and C; each is scaled by capstan over body diameter (B and C negated) and divided by the motor's torque
  constant, clamped to 3 A, and sent as ``3000 x`` the current, truncated to an integer (its comment: the
  wire's 90 % is 3 A in the firmware, but the ESCON is configured so that 90 % is 1 A: the wire's 3000 is
  the amplifier's full scale, 1 A of motor current). The default dimensions are those of its
  ``default_woody()`` configuration (below).

Frame: CHAI3D's (x towards the user, y right, z up), metres, origin at the configuration's workspace origin:
already the device frame.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

VID, PID = 0x1234, 0x0006
REPORT_SIZE = 8
REPORT = struct.Struct("<hhhH")
FIRMWARE_WATCHDOG_S = 0.5
FIRMWARE_FULL_SCALE_A = 3.0       # the firmware's |f| above which the PWM saturates (90 %)
WIRE_MA_PER_HOST_A = 3000.0       # CWoodenDevice: short(motorAmpere * 1000 * 3)
HOST_CURRENT_LIMIT_A = 3.0        # CWoodenDevice's clamp before scaling (the wire then saturates at 1 A)
PI_CHAI = 3.141592                # the constant CWoodenDevice.cpp writes for pi/2 in its kinematics


@dataclass(frozen=True)
class Config:
    """``cWoodenDevice::configuration`` (SI units); defaults are ``default_woody()``'s."""

    diameter_capstan_a: float = 0.010
    diameter_capstan_b: float = 0.010
    diameter_capstan_c: float = 0.010
    length_body_a: float = 0.080
    length_body_b: float = 0.205
    length_body_c: float = 0.200
    diameter_body_a: float = 0.160
    diameter_body_b: float = 0.120
    diameter_body_c: float = 0.120
    workspace_origin_x: float = 0.220
    workspace_origin_y: float = 0.000
    workspace_origin_z: float = 0.080
    workspace_radius: float = 0.100
    torque_constant_motor_a: float = 0.0603
    torque_constant_motor_b: float = 0.0603
    torque_constant_motor_c: float = 0.0603
    current_for_10_v_signal: float = 3.0
    cpr_encoder_a: float = 4096.0
    cpr_encoder_b: float = 2000.0
    cpr_encoder_c: float = 2000.0
    max_linear_force: float = 12.0
    max_linear_stiffness: float = 5000.0
    max_linear_damping: float = 8.0
    mass_body_b: float = 0.170
    mass_body_c: float = 0.110
    length_cm_body_b: float = 0.051
    length_cm_body_c: float = 0.091
    g_constant: float = 9.81

    @property
    def gear(self) -> tuple[float, float, float]:
        """``gearRatio`` of calculate_pose (signed)."""
        return (self.diameter_body_a / self.diameter_capstan_a, -self.diameter_body_b / self.diameter_capstan_b,
                self.diameter_body_c / self.diameter_capstan_c)

    @property
    def kt(self) -> tuple[float, float, float]:
        """Motor torque constants (N m/A)."""
        return (self.torque_constant_motor_a, self.torque_constant_motor_b, self.torque_constant_motor_c)


DEFAULT = Config()


class ProtocolError(ValueError):
    """A report of the wrong size."""


def encode_command(ma, counter: int = 0) -> bytes:
    """The host's 8-byte output report: three int16 'mA' (the wire's units, see module doc) and a counter."""
    a, b, c = (int(v) for v in ma)
    for v in (a, b, c):
        if not -0x8000 <= v <= 0x7FFF:
            raise ValueError(f"motor command {v} does not fit an int16")
    return REPORT.pack(a, b, c, counter & 0xFFFF)


def decode_command(report: bytes) -> tuple[tuple[int, int, int], int]:
    """``((mA_a, mA_b, mA_c), debug)`` of an output report (the device's side)."""
    if len(report) != REPORT_SIZE:
        raise ProtocolError(f"WoodenHaptics report of {len(report)} bytes, expected {REPORT_SIZE}")
    a, b, c, d = REPORT.unpack(report)
    return (a, b, c), d


def encode_report(encoders, counter: int) -> bytes:
    """The device's 8-byte input report: encoder counts truncated to int16 (as ``short = int``), counter."""
    e = [((int(v) + 0x8000) & 0xFFFF) - 0x8000 for v in encoders]
    return REPORT.pack(e[0], e[1], e[2], counter & 0xFFFF)


def decode_report(report: bytes) -> tuple[tuple[int, int, int], int]:
    """``((enc_a, enc_b, enc_c), counter)`` of an input report."""
    if len(report) != REPORT_SIZE:
        raise ProtocolError(f"WoodenHaptics report of {len(report)} bytes, expected {REPORT_SIZE}")
    a, b, c, d = REPORT.unpack(report)
    return (a, b, c), d


def firmware_current_A(ma: int) -> float:
    """The firmware's current command ``f = mA * 0.001`` after its PWM saturation at 3.0 (A, the wire's scale)."""
    f = ma * 0.001
    return max(-FIRMWARE_FULL_SCALE_A, min(FIRMWARE_FULL_SCALE_A, f))


def joint_angles(encoders, cfg: Config = DEFAULT) -> tuple[float, float, float]:
    """``(tA, tB, tC)`` of calculate_pose from the reported encoders (the host negates encoder a)."""
    raw = (-encoders[0], encoders[1], encoders[2])
    cpr = (cfg.cpr_encoder_a, cfg.cpr_encoder_b, cfg.cpr_encoder_c)
    return tuple((2.0 * math.pi * raw[i] / cpr[i]) / cfg.gear[i] for i in range(3))


def encoders_from_angles(angles, cfg: Config = DEFAULT) -> tuple[int, int, int]:
    """The inverse of :func:`joint_angles`, rounded to counts."""
    cpr = (cfg.cpr_encoder_a, cfg.cpr_encoder_b, cfg.cpr_encoder_c)
    raw = [int(round(angles[i] * cfg.gear[i] * cpr[i] / (2.0 * math.pi))) for i in range(3)]
    return (-raw[0], raw[1], raw[2])


def forward(angles, cfg: Config = DEFAULT) -> tuple[float, float, float]:
    """Endpoint (m, device frame) of joint angles (rad), CWoodenDevice::getPosition's "Mike edition"."""
    ta, tb, tc = angles
    tc = -tc + PI_CHAI / 2
    lb, lc = cfg.length_body_b, cfg.length_body_c
    r = lb * math.sin(tb) + lc * math.sin(tc)
    return (math.cos(ta) * r - cfg.workspace_origin_x, math.sin(ta) * r - cfg.workspace_origin_y,
            cfg.length_body_a + lb * math.cos(tb) - lc * math.cos(tc) - cfg.workspace_origin_z)


def jacobian(angles, cfg: Config = DEFAULT) -> tuple:
    """CWoodenDevice's 2016-05-30 Jacobian (rows x, y, z; columns tA, tB and its modified tC)."""
    ta, tb, tc = angles
    tc = -tc + PI_CHAI / 2
    lb, lc = cfg.length_body_b, cfg.length_body_c
    r = lb * math.sin(tb) + lc * math.sin(tc)
    return ((-math.sin(ta) * r, lb * math.cos(ta) * math.cos(tb), lc * math.cos(ta) * math.cos(tc)),
            (math.cos(ta) * r, lb * math.sin(ta) * math.cos(tb), lc * math.sin(ta) * math.cos(tc)),
            (0.0, -lb * math.sin(tb), lc * math.sin(tc)))


def gravity_torques(angles, cfg: Config = DEFAULT) -> tuple[float, float, float]:
    """The gravity compensation CWoodenDevice adds to ``J^T f`` (N m, joint space)."""
    _, tb, tc = angles
    tc = -tc + PI_CHAI / 2
    g = cfg.g_constant
    return (0.0, -g * (cfg.mass_body_b * cfg.length_cm_body_b * math.sin(tb)
                       + cfg.mass_body_c * (cfg.length_cm_body_b + cfg.length_cm_body_c) * math.sin(tc)),
            -g * cfg.mass_body_c * cfg.length_cm_body_c * math.sin(tc))


def motor_currents(angles, force, cfg: Config = DEFAULT, gravity: bool = True) -> tuple[float, float, float]:
    """Motor currents (A, before CWoodenDevice's +/-3 A clamp) for an endpoint force (N) at ``angles``."""
    j = jacobian(angles, cfg)
    fx, fy, fz = force
    t = [j[0][i] * fx + j[1][i] * fy + j[2][i] * fz for i in range(3)]
    if gravity:
        gt = gravity_torques(angles, cfg)
        t = [t[i] + gt[i] for i in range(3)]
    dc = (cfg.diameter_capstan_a, cfg.diameter_capstan_b, cfg.diameter_capstan_c)
    db = (cfg.diameter_body_a, cfg.diameter_body_b, cfg.diameter_body_c)
    mt = (t[0] * dc[0] / db[0], -t[1] * dc[1] / db[1], -t[2] * dc[2] / db[2])
    kt = cfg.kt
    return tuple(mt[i] / kt[i] for i in range(3))


def wire_ma(currents_A) -> tuple[int, int, int]:
    """CWoodenDevice's report values: each current clamped to +/-3 A, times 3000, truncated to a short."""
    return tuple(int(max(-HOST_CURRENT_LIMIT_A, min(HOST_CURRENT_LIMIT_A, a)) * WIRE_MA_PER_HOST_A)
                 for a in currents_A)


def inverse(p, cfg: Config = DEFAULT, guess=(0.0, 0.4, 0.4), tol_m: float = 1e-12, max_iter: int = 50):
    """Joint angles (rad) whose :func:`forward` is ``p`` (Newton on the Jacobian; ValueError if none)."""
    q = list(guess)
    for _ in range(max_iter):
        x = forward(q, cfg)
        e = [p[i] - x[i] for i in range(3)]
        if e[0] * e[0] + e[1] * e[1] + e[2] * e[2] < tol_m * tol_m:
            return tuple(q)
        j = jacobian(q, cfg)
        # the Jacobian's third column is d/d(modified tC) = -d/dtC
        jj = [[j[r][0], j[r][1], -j[r][2]] for r in range(3)]
        d = _solve3(jj, e)
        for i in range(3):
            q[i] += d[i]
    raise ValueError(f"no WoodenHaptics joint angles for position {p}")


def _solve3(m, b):
    (a, b_, c), (d, e, f), (g, h, k) = m
    det = a * (e * k - f * h) - b_ * (d * k - f * g) + c * (d * h - e * g)
    if det == 0:
        raise ValueError("singular WoodenHaptics Jacobian")
    x = (b[0] * (e * k - f * h) - b_ * (b[1] * k - f * b[2]) + c * (b[1] * h - e * b[2])) / det
    y = (a * (b[1] * k - f * b[2]) - b[0] * (d * k - f * g) + c * (d * b[2] - b[1] * g)) / det
    z = (a * (e * b[2] - b[1] * h) - b_ * (d * b[2] - b[1] * g) + b[0] * (d * h - e * g)) / det
    return (x, y, z)
