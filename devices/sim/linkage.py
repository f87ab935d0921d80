"""Linkages of the 3-DOF simulated device: delta (Falcon-like) and serial arm (Phantom-like), numpy only.

A linkage makes the endpoint's impedance depend on direction: its motors' inertia and friction, seen at
the endpoint through the Jacobian ``J = dx/dq`` (m per rad), are ``M_x = J^-T M_q J^-1`` (kg) and, for a
Coulomb torque ``c_q`` per joint, a force of ``sum_j c_qj |(J^-1 e)_j|`` along the unit direction ``e``
(N). Numbers are plausible for the devices named, not measured (docs/sim.md, "3-DOF simulated device").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Linkage:
    """A linkage's geometry, joint inertias (kg m^2) and joint Coulomb friction (N m).

    ``kind``: "delta" (three rotary arms at 120 deg, parallelograms to the effector, the Novint Falcon's
    layout) or "serial" (base yaw, shoulder and elbow pitch, the Phantom Premium's). Lengths in m; the
    endpoint's device-frame position is relative to the workspace centre.
    """

    kind: str
    upper_m: float
    lower_m: float
    base_m: float
    joint_inertia_kg_m2: tuple[float, float, float]
    joint_friction_Nm: tuple[float, float, float]
    centre_offset_m: tuple[float, float, float]

    def joints(self, p_m) -> np.ndarray:
        """Joint angles (rad) that put the endpoint at device-frame ``p_m`` (inverse kinematics)."""
        p = np.asarray(p_m, float) + np.asarray(self.centre_offset_m, float)
        if self.kind == "delta":
            return np.array([_delta_arm(p, k, self.base_m, self.upper_m, self.lower_m) for k in range(3)])
        x, y, z = p
        yaw = math.atan2(y, x)
        r = math.hypot(x, y)
        d2 = r * r + z * z
        c3 = (d2 - self.upper_m ** 2 - self.lower_m ** 2) / (2 * self.upper_m * self.lower_m)
        if not -1.0 <= c3 <= 1.0:
            raise ValueError(f"point {tuple(p_m)} out of the serial arm's reach")
        elbow = -math.acos(c3)
        shoulder = math.atan2(z, r) - math.atan2(self.lower_m * math.sin(elbow),
                                                 self.upper_m + self.lower_m * math.cos(elbow))
        return np.array([yaw, shoulder, elbow])

    def jacobian(self, p_m, h_m: float = 1e-6) -> np.ndarray:
        """``J = dx/dq`` (m/rad, 3 x 3) at device-frame ``p_m``: the inverse of the inverse kinematics'
        central-difference derivative ``dq/dx``."""
        dq = np.empty((3, 3))
        for i in range(3):
            e = np.zeros(3)
            e[i] = h_m
            dq[:, i] = (self.joints(np.asarray(p_m) + e) - self.joints(np.asarray(p_m) - e)) / (2 * h_m)
        return np.linalg.inv(dq)

    def endpoint_inertia(self, p_m) -> np.ndarray:
        """The motors' inertia seen at the endpoint, ``J^-T M_q J^-1`` (kg, 3 x 3 symmetric)."""
        jinv = np.linalg.inv(self.jacobian(p_m))
        return jinv.T @ np.diag(self.joint_inertia_kg_m2) @ jinv

    def friction_along(self, p_m, e) -> float:
        """The joints' Coulomb friction seen along the unit direction ``e`` at ``p_m`` (N)."""
        jinv = np.linalg.inv(self.jacobian(p_m))
        return float(np.sum(np.asarray(self.joint_friction_Nm) * np.abs(jinv @ np.asarray(e, float))))


def _delta_arm(p, k, base, upper, lower) -> float:
    """Angle (rad) of rotary arm ``k`` of a delta whose effector centre is at ``p`` (Clavel's inverse kinematics)."""
    phi = 2.0 * math.pi * k / 3.0
    c, s = math.cos(phi), math.sin(phi)
    # into the arm's own frame: its hinge on the local x axis at ``base``, rotating in the x-z plane
    x = c * p[0] + s * p[1] - base
    y = -s * p[0] + c * p[1]
    z = p[2]
    # the elbow (base + upper cos t, 0, upper sin t) lies at distance lower from the effector: a cos + b sin = rhs
    rhs = (x * x + y * y + z * z + upper * upper - lower * lower) / (2.0 * upper)
    a, b = x, z
    r = math.hypot(a, b)
    if r < abs(rhs):
        raise ValueError(f"point {tuple(p)} out of the delta's reach")
    return math.atan2(b, a) + math.acos(rhs / r)   # the elbow outwards, as on the Falcon


LINKAGES = {
    # Novint Falcon-like: 60 mm arms, 103 mm parallelograms, 36 mm base radius; ~3e-5 kg m^2 per motor
    # through its capstan; effector 0.13 m below the base plane at the workspace centre
    "delta": Linkage("delta", upper_m=0.060, lower_m=0.103, base_m=0.036, joint_inertia_kg_m2=(3e-5, 3e-5, 3e-5),
                     joint_friction_Nm=(2e-3, 2e-3, 2e-3), centre_offset_m=(0.0, 0.0, -0.13)),
    # Phantom Premium-like: 0.14 m links, base 0.17 m behind and 0.03 m below the workspace centre
    "serial": Linkage("serial", upper_m=0.14, lower_m=0.14, base_m=0.0, joint_inertia_kg_m2=(4e-4, 4e-4, 2e-4),
                      joint_friction_Nm=(4e-3, 4e-3, 3e-3), centre_offset_m=(0.17, 0.0, 0.03)),
}
