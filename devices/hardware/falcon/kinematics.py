"""The Novint Falcon's delta kinematics (R. E. Stamper's parallel manipulator), as libnifalcon computes them.

A re-implementation in plain scalar Python of libnifalcon's ``FalconKinematicStamper`` (BSD; Alastair
Barrow and Kyle Machulis after Stamper, "A Three Degree of Freedom Parallel Manipulator with Only
Translational Degrees of Freedom", PhD thesis, University of Maryland 1997) with the geometry of its
``FalconGeometry.h``. A contract test checks that this module agrees with what libnifalcon itself computes
on random values (vectors recorded from libnifalcon's code; tests/devices/hardware/contract/).

Frame (libnifalcon's, metres): x to the right, y up, z along the grip's axis away from the body (the
workspace centre is near z = 0.11 m; libnifalcon starts its position guess at (0, 0, 0.08)). The motor
angles ``theta1`` are in radians; an encoder count is ``getTheta``'s slot arithmetic (320 slots, x4
quadrature, 14.25 mm shaft on the 110 mm arm, 35 degrees at count 0).

Functions
---------
ik(p) -> (theta1, theta2, theta3)      each a 3-tuple (rad), Stamper's closed form (the '+' branches)
jacobian(angles) -> 3x3                dp/dtheta1 (libnifalcon's ``jacobian()``: the inverse of
                                       dtheta1/dp), so ``torque = J^T F``
fk(theta1, guess) -> p                 Newton on ik (tighter than libnifalcon's 0.01 rad stop)
motor_commands(p, F) -> (c0, c1, c2)   libnifalcon's ``getForces``: torques ``J^T F``, scaled so none
                                       exceeds 30 N m, times 10000, negated, truncated to int
force_from_commands(p, c) -> F         the inverse (what an emulated Falcon exerts for a command)
theta_from_encoder(n), encoder_from_theta(rad)
"""

from __future__ import annotations

import math

# FalconGeometry.h (metres, degrees where named)
WHEEL_SLOTS_NUMBER = 320.0
SHAFT_DIAMETER = 0.01425
SMALL_ARM_DIAMETER = 0.110
THETA_OFFSET_ANGLE = 35.0
A = 0.060
B = 0.1025
C = 0.01443
D = 0.01125
E = D
F = -0.025
R = 0.0400
S = -0.02309
PI = 3.14159265  # libnifalcon's own constant (FalconGeometry.h), not math.pi: the angles below use it
OFFSET_ANGLE = PI / 12
PHY = (PI / 2 + OFFSET_ANGLE, -PI / 6 + OFFSET_ANGLE, -5 * PI / 6 + OFFSET_ANGLE)
DEG_TO_RAD = 0.0174532925  # FalconKinematicStamper::getPosition's factor
#: libnifalcon's cap on a motor torque before scaling (getForces: "Rather random choice here")
MAX_TORQUE = 30.0
TORQUE_TO_COMMAND = 10000.0
#: the motor command a Falcon takes (int16 on the wire); libnifalcon documents forces "capped at 4096"
MAX_COMMAND = 4096
#: the workspace centre and libnifalcon's first position guess (m)
WORKSPACE_CENTRE = (0.0, 0.0, 0.11)
FK_GUESS = (0.0, 0.0, 0.08)
_COS = tuple(math.cos(p) for p in PHY)
_SIN = tuple(math.sin(p) for p in PHY)
_COUNTS_PER_DEG = ((PI * SMALL_ARM_DIAMETER) / 360.0) / ((SHAFT_DIAMETER * PI) / (WHEEL_SLOTS_NUMBER * 4))


class OutOfWorkspace(ValueError):
    """A position the linkage cannot reach (the closed form has no real solution there)."""


def theta_from_encoder(count: int) -> float:
    """Motor angle (degrees) of an encoder count (libnifalcon ``FalconKinematic::getTheta``)."""
    return count / _COUNTS_PER_DEG + THETA_OFFSET_ANGLE


def encoder_from_theta(theta_rad: float) -> int:
    """The nearest encoder count to a motor angle (rad): the inverse of :func:`theta_from_encoder`."""
    return int(round((theta_rad / DEG_TO_RAD - THETA_OFFSET_ANGLE) * _COUNTS_PER_DEG))


def ik(p) -> tuple[tuple, tuple, tuple]:
    """Leg angles ``(theta1, theta2, theta3)`` (rad, 3 legs each) at position ``p`` (m); OutOfWorkspace if none."""
    x, y, z = p
    t1, t2, t3 = [0.0] * 3, [0.0] * 3, [0.0] * 3
    for i in range(3):
        c, s = _COS[i], _SIN[i]
        u = c * x + s * y - R       # R*p + offset, with offset = (-r, -s, 0)
        v = -s * x + c * y - S
        w = z
        arg3 = (v + F) / B
        if not -1.0 <= arg3 <= 1.0:
            raise OutOfWorkspace(f"position {p} out of the Falcon's workspace (leg {i + 1})")
        th3 = math.acos(arg3)
        s3 = math.sin(th3)
        common = (w * w + u * u + 2 * C * u + A * A + C * C - D * D - E * E - B * B * s3 * s3 - 2 * B * E * s3
                  - 2 * B * D * s3 - 2 * D * E)
        l0 = common - 2 * A * u - 2 * A * C
        l1 = -4 * A * w
        l2 = common + 2 * A * u + 2 * A * C
        disc = l1 * l1 - 4 * l0 * l2
        if disc < 0 or l2 == 0:
            raise OutOfWorkspace(f"position {p} out of the Falcon's workspace (leg {i + 1})")
        th1 = 2.0 * math.atan((-l1 - math.sqrt(disc)) / (2 * l2))
        arg2 = (-u + A * math.cos(th1) - C) / (-D - E - B * s3)
        if not -1.0 <= arg2 <= 1.0:
            raise OutOfWorkspace(f"position {p} out of the Falcon's workspace (leg {i + 1})")
        t1[i], t2[i], t3[i] = th1, math.acos(arg2), th3
    return tuple(t1), tuple(t2), tuple(t3)


def _inv3(m):
    (a, b, c), (d, e, f), (g, h, k) = m
    det = a * (e * k - f * h) - b * (d * k - f * g) + c * (d * h - e * g)
    if det == 0 or not math.isfinite(det):
        raise OutOfWorkspace("singular Falcon Jacobian (at a workspace boundary)")
    return ((e * k - f * h) / det, (c * h - b * k) / det, (b * f - c * e) / det), \
           ((f * g - d * k) / det, (a * k - c * g) / det, (c * d - a * f) / det), \
           ((d * h - e * g) / det, (b * g - a * h) / det, (a * e - b * d) / det)


def jacobian(angles) -> tuple:
    """libnifalcon's ``jacobian(angles)``: rows i = d(theta1_i)/d(x, y, z) assembled, then inverted (dp/dtheta1)."""
    t1, t2, t3 = angles
    rows = []
    for i in range(3):
        den = -A * math.sin(t3[i]) * (math.sin(t1[i]) * math.cos(t2[i]) - math.sin(t2[i]) * math.cos(t1[i]))
        jx = _COS[i] * math.cos(t2[i]) * math.sin(t3[i]) / den - _SIN[i] * math.cos(t3[i]) / den
        jy = _SIN[i] * math.cos(t2[i]) * math.sin(t3[i]) / den + _COS[i] * math.cos(t3[i]) / den
        jz = (math.sin(t2[i]) * math.sin(t2[i])) / den
        rows.append((jx, jy, jz))
    return _inv3(rows)


def _leg_jacobian(angles) -> tuple:
    """The exact dp/dtheta1 of :func:`ik` (for Newton in :func:`fk`; not libnifalcon's :func:`jacobian`).

    Each leg in its own frame (u, v, w) is ``u = a cos t1 - c + L cos t2``, ``v = b cos t3 - f``, ``w = a sin t1
    + L sin t2`` with ``L = d + e + b sin t3`` (Stamper; the closed form :func:`ik` inverts). Eliminating dt2
    and dt3 gives ``dt1 = (cos t2 du + cot t3 dv + sin t2 dw) / (a sin(t2 - t1))``. libnifalcon's
    :func:`jacobian` has ``sin^2 t2 / sin t3`` where this has ``sin t2`` in the w term: with it Newton converges
    only linearly (about x0.3 a step), with this one quadratically.
    """
    t1, t2, t3 = angles
    rows = []
    for i in range(3):
        den = A * math.sin(t2[i] - t1[i])
        du, dv, dw = math.cos(t2[i]) / den, math.cos(t3[i]) / (math.sin(t3[i]) * den), math.sin(t2[i]) / den
        rows.append((_COS[i] * du - _SIN[i] * dv, _SIN[i] * du + _COS[i] * dv, dw))
    return _inv3(rows)


def fk(theta1, guess=FK_GUESS, tol_rad: float = 1e-10, max_iter: int = 50) -> tuple:
    """Position (m) whose leg angles are ``theta1`` (rad): Newton steps ``p += J (theta1 - ik(p).theta1)``.

    libnifalcon damps its steps with its own Jacobian and stops at 0.01 rad; this takes full Newton steps
    with the exact Jacobian (:func:`_leg_jacobian`) to ``tol_rad``: from the last sample, two or three steps.
    """
    p = list(guess)
    for _ in range(max_iter):
        angles = ik(p)
        d = [theta1[i] - angles[0][i] for i in range(3)]
        if math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) < tol_rad:
            return tuple(p)
        j = _leg_jacobian(angles)
        for r in range(3):
            p[r] += j[r][0] * d[0] + j[r][1] * d[1] + j[r][2] * d[2]
    angles = ik(p)
    if max(abs(theta1[i] - angles[0][i]) for i in range(3)) > 1e-6:
        raise OutOfWorkspace(f"no Falcon position for motor angles {theta1} (Newton did not converge)")
    return tuple(p)


def joint_torques(p, force) -> tuple:
    """Motor torques (N m, libnifalcon's scale) ``J^T F`` for a force ``F`` (N) at position ``p`` (m)."""
    j = jacobian(ik(p))
    fx, fy, fz = force
    return tuple(j[0][i] * fx + j[1][i] * fy + j[2][i] * fz for i in range(3))


def motor_commands(p, force) -> tuple[int, int, int]:
    """libnifalcon's ``getForces``: torques, scaled down together so none exceeds 30, x10000, negated, to int."""
    t = list(joint_torques(p, force))
    largest = max(abs(v) for v in t)
    if largest > MAX_TORQUE:
        scale = largest / MAX_TORQUE
        t = [v / scale for v in t]
    return tuple(int(-v * TORQUE_TO_COMMAND) for v in t)  # int(): C's truncation toward zero


def force_from_commands(p, commands) -> tuple:
    """The Cartesian force (N) that motor commands exert at ``p``: ``F = (J^T)^-1 (-c / 10000)``."""
    j = jacobian(ik(p))
    jt = tuple(tuple(j[r][c] for r in range(3)) for c in range(3))
    inv = _inv3(jt)
    tau = [-c / TORQUE_TO_COMMAND for c in commands]
    return tuple(inv[r][0] * tau[0] + inv[r][1] * tau[1] + inv[r][2] * tau[2] for r in range(3))
