"""A 3-DOF endpoint with a tapping hand: the physics behind the emulators of the 3-DOF research devices.

The handle is a point mass ``m`` in the device's Cartesian frame, pushed by the device's force and held by
a simulated hand: a spring-damper (``k_h``, ``b_h``, thesis eq. 3.34 in three axes) towards a desired hand
position. Along the device's vertical axis the desired position taps, over and over, through the height
``centre + 0`` (the 1-DOF scenes' surface) from ``approach_height_m`` above it at the tap speeds given,
down to ``press_depth_m`` below it, dwells, lifts and pauses, as :class:`devices.sim.TapTrajectory` does
for the 1-DOF sim; along the other two axes it holds the workspace centre. Gravity is left out: every
device here compensates it (or the hand holds it).

Plain scalar Python (no numpy): an emulator steps it once per device tick (semi-implicit Euler), and the
whole state is a handful of floats, so an emulator thread costs a few microseconds per tick.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class TapPlan:
    """The hand's vertical plan (SI units; see module doc)."""

    velocities_m_s: tuple = (0.05, 0.1, 0.2)
    approach_height_m: float = 0.01
    press_depth_m: float = 0.005
    dwell_s: float = 0.3
    lift_s: float = 0.2
    pause_s: float = 0.1

    def __post_init__(self) -> None:
        if not self.velocities_m_s or any(not (isinstance(v, (int, float)) and 0 < v <= 2.0)
                                          for v in self.velocities_m_s):
            raise ValueError(f"tap velocities must be numbers in (0, 2] m/s, got {self.velocities_m_s!r}")

    def tap_duration_s(self, v_m_s: float) -> float:
        """Length (s) of one tap at ``v_m_s``: descent, dwell, lift, pause."""
        return (self.approach_height_m + self.press_depth_m) / v_m_s + self.dwell_s + self.lift_s + self.pause_s

    def height(self, t_s: float) -> float:
        """Desired hand height (m, relative to the surface) at ``t_s`` (the taps repeat forever)."""
        period = sum(self.tap_duration_s(v) for v in self.velocities_m_s)
        t = t_s % period
        for v in self.velocities_m_s:
            d = self.tap_duration_s(v)
            if t >= d:
                t -= d
                continue
            h0, depth = self.approach_height_m, self.press_depth_m
            t_down = (h0 + depth) / v
            if t < t_down:
                return h0 - v * t
            t -= t_down
            if t < self.dwell_s:
                return -depth
            t -= self.dwell_s
            if t < self.lift_s:  # half-cosine back up
                return -depth + (h0 + depth) * 0.5 * (1.0 - math.cos(math.pi * t / self.lift_s))
            return h0
        return self.approach_height_m  # pragma: no cover - rounding at the period's end


class Endpoint:
    """The handle (a point mass) and the hand, in a device's Cartesian frame.

    Parameters
    ----------
    centre_m : sequence of 3 float
        Workspace centre (m, device frame): the hand holds it along the two horizontal axes and taps
        through it along ``vertical``.
    vertical : int
        Index of the device frame's vertical (up) axis.
    plan : TapPlan or None
        The taps; None: the hand holds the handle still ``hold_height_m`` above the centre.
    mass_kg, hand_stiffness_N_m, hand_damping_N_s_m : float
        Moving mass at the handle and the hand's spring-damper.
    """

    def __init__(self, centre_m: Sequence[float], vertical: int, plan: TapPlan | None = TapPlan(),
                 mass_kg: float = 0.15, hand_stiffness_N_m: float = 800.0, hand_damping_N_s_m: float = 8.0,
                 hold_height_m: float = 0.01) -> None:
        if vertical not in (0, 1, 2):
            raise ValueError(f"vertical axis must be 0, 1 or 2, got {vertical!r}")
        self.centre = [float(c) for c in centre_m]
        self.vertical = vertical
        self.plan = plan
        self.m = float(mass_kg)
        self.k_h = float(hand_stiffness_N_m)
        self.b_h = float(hand_damping_N_s_m)
        self.hold_height_m = float(hold_height_m)
        self.t_s = 0.0
        h = plan.approach_height_m if plan is not None else self.hold_height_m
        self.pos = list(self.centre)
        self.pos[vertical] += h
        self.vel = [0.0, 0.0, 0.0]
        self.force = [0.0, 0.0, 0.0]  # the device's force being applied (N)

    def hand_target(self, axis: int) -> float:
        """Desired hand position along ``axis`` now (m)."""
        if axis != self.vertical:
            return self.centre[axis]
        h = self.plan.height(self.t_s) if self.plan is not None else self.hold_height_m
        return self.centre[axis] + h

    def step(self, dt_s: float) -> None:
        """Advance ``dt_s`` under ``self.force`` and the hand (semi-implicit Euler)."""
        m, k, b = self.m, self.k_h, self.b_h
        pos, vel, f = self.pos, self.vel, self.force
        for i in range(3):
            a = (f[i] - k * (pos[i] - self.hand_target(i)) - b * vel[i]) / m
            vel[i] += a * dt_s
            pos[i] += vel[i] * dt_s
        self.t_s += dt_s

    def set_force(self, fx: float, fy: float, fz: float) -> None:
        """The device's force (N) from now on; a non-finite component is taken as 0 (a motor never sees NaN)."""
        f = self.force
        for i, v in enumerate((fx, fy, fz)):
            f[i] = v if v == v and v not in (math.inf, -math.inf) else 0.0
