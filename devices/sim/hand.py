"""The simulated user: desired hand trajectories and grip force (thesis sections 3.4.6, 3.5.2).

The hand is a spring-damper between the handle and a desired hand position
x_u(t) (eq. 3.34 with ``-k_u*(x_h - x_u) - b_u*(v_h - v_u)``). Its stiffness
and damping rise linearly with grip force from zero (no user) through the
Table 3.1 values at the nominal grip (section 3.5.2, last paragraphs):
``k_u(g) = k_u * g / g_nom``, ``b_u(g) = b_u * g / g_nom``.

Trajectories are sampled once onto the servo grid when the user is set, so
the servo path only indexes arrays.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np


class TapTrajectory:
    """Desired hand motion for repeated taps on a surface at height 0.

    Each tap: start at rest at ``approach_height_m``, accelerate over
    ``ramp_s`` to the tap speed, descend at constant speed through the
    surface down to half ``press_depth_m`` below it, then decelerate
    uniformly to rest at ``press_depth_m`` (the hand "pushes through" the
    sample like a real tap, and the handle meets the surface before the hand
    slows down, so nothing but the impact disturbs it), dwell ``dwell_s``,
    lift back to the approach height in ``lift_s`` (half-cosine profile) and
    pause ``pause_s`` before the next tap.

    Parameters
    ----------
    velocities_m_s : float or sequence of float
        Tap speed(s) (> 0, m/s); a sequence gives one speed per tap.
    n_taps : int, optional
        Number of taps; defaults to ``len(velocities_m_s)`` or 1. A sequence
        shorter than ``n_taps`` is cycled.
    approach_height_m : float
        Start height above the surface (m).
    dwell_s, lift_s, pause_s, ramp_s : float
        Durations (s).
    press_depth_m : float
        How far below the surface the desired hand position comes to rest (m).
    """

    def __init__(self, velocities_m_s: float | Sequence[float], n_taps: int | None = None,
                 approach_height_m: float = 0.01, dwell_s: float = 0.3, lift_s: float = 0.2,
                 press_depth_m: float = 0.005, pause_s: float = 0.1, ramp_s: float = 0.02):
        if isinstance(velocities_m_s, (int, float)):
            vels = [float(velocities_m_s)]
        else:
            vels = [float(v) for v in velocities_m_s]
        if not vels:
            raise ValueError("TapTrajectory: velocities_m_s is empty")
        if n_taps is None:
            n_taps = len(vels)
        if int(n_taps) != n_taps or n_taps < 1:
            raise ValueError(f"TapTrajectory: n_taps must be a positive integer, got {n_taps!r}")
        for v in vels:
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"TapTrajectory: velocities must be positive finite m/s, got {v!r}")
        for key, val in (("approach_height_m", approach_height_m), ("dwell_s", dwell_s), ("lift_s", lift_s),
                         ("press_depth_m", press_depth_m), ("ramp_s", ramp_s)):
            if not (math.isfinite(val) and val > 0):
                raise ValueError(f"TapTrajectory: {key} must be > 0, got {val!r}")
        if not (math.isfinite(pause_s) and pause_s >= 0):
            raise ValueError(f"TapTrajectory: pause_s must be >= 0, got {pause_s!r}")
        self.velocities_m_s = tuple(vels[i % len(vels)] for i in range(int(n_taps)))
        self.n_taps = int(n_taps)
        self.approach_height_m = float(approach_height_m)
        self.dwell_s = float(dwell_s)
        self.lift_s = float(lift_s)
        self.press_depth_m = float(press_depth_m)
        self.pause_s = float(pause_s)
        self.ramp_s = float(ramp_s)
        self._taps = [self._tap_segments(v) for v in self.velocities_m_s]
        self._tap_arrays = {key: np.array([tp[key] for tp in self._taps])
                            for key in ("v", "ramp", "t_surface", "t_through", "t_decel", "t_rest", "t_lift")}
        starts = np.concatenate([[0.0], np.cumsum([tp["total"] for tp in self._taps])])
        self._starts = starts
        self.duration_s = float(starts[-1])
        #: times (s, from the start) at which the desired hand crosses the surface, one per tap
        self.surface_times_s = tuple(float(s0 + tp["t_surface"]) for s0, tp in zip(starts, self._taps))

    def _tap_segments(self, v: float) -> dict:
        h = self.approach_height_m
        ramp = min(self.ramp_s, h / v)         # keep the ramp distance (v*ramp/2) within the approach
        t_cruise = (h - v * ramp / 2) / v
        t_surface = ramp + t_cruise
        t_through = 0.5 * self.press_depth_m / v          # constant speed below the surface
        t_decel = self.press_depth_m / v                  # uniform deceleration over the other half
        t_rest = t_surface + t_through + t_decel
        return {"v": v, "ramp": ramp, "t_surface": t_surface, "t_through": t_through, "t_decel": t_decel,
                "t_rest": t_rest,
                "t_lift": t_rest + self.dwell_s, "total": t_rest + self.dwell_s + self.lift_s + self.pause_s}

    def position(self, t_s) -> np.ndarray:
        """Desired hand position (m) at times ``t_s`` (s, array of any order), vectorized.

        Linear in the number of samples and taps: each time is assigned to its
        tap by a binary search of the tap start times, then every segment's
        formula is evaluated once over all samples with that tap's parameters
        gathered per sample (no per-tap pass over the whole array).
        """
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        flat = t.ravel()
        return self._chunked(flat.size, lambda i, j: flat[i:j]).reshape(t.shape)

    _CHUNK = 1 << 14

    def _chunked(self, n: int, times) -> np.ndarray:
        """Positions (m) of ``n`` samples, evaluated in cache-sized chunks (the per-sample cost stays flat
        however long the run); ``times(i, j)`` gives the times (s) of samples i..j-1."""
        out = np.empty(n)
        for i in range(0, n, self._CHUNK):
            j = min(i + self._CHUNK, n)
            out[i:j] = self._position(times(i, j))
        return out

    def _position(self, t: np.ndarray) -> np.ndarray:
        h, d = self.approach_height_m, self.press_depth_m
        n_taps = len(self._taps)
        idx = np.clip(np.searchsorted(self._starts[:n_taps], t, side="right") - 1, 0, n_taps - 1)
        tau = t - self._starts[idx]
        par = self._tap_arrays
        v, ramp, t_surf = par["v"][idx], par["ramp"][idx], par["t_surface"][idx]
        t_brake = t_surf + par["t_through"][idx]
        t_rest, t_decel, t_lift = par["t_rest"][idx], par["t_decel"][idx], par["t_lift"][idx]
        x = np.full(t.shape, h)
        u = tau - t_brake
        lift_phase = (tau - t_lift) / self.lift_s
        # segment formulas, evaluated for all samples and selected by phase (later phases win)
        x = np.where((tau >= 0) & (tau < ramp), h - 0.5 * v / ramp * tau ** 2, x)
        x = np.where((tau >= ramp) & (tau < t_surf), h - v * ramp / 2 - v * (tau - ramp), x)
        x = np.where((tau >= t_surf) & (tau < t_brake), -v * (tau - t_surf), x)
        x = np.where((tau >= t_brake) & (tau < t_rest), -0.5 * d - v * u + 0.5 * (v / t_decel) * u ** 2, x)
        x = np.where((tau >= t_rest) & (tau < t_lift), -d, x)
        x = np.where((tau >= t_lift) & (lift_phase < 1.0), -d + (h + d) * 0.5 * (1 - np.cos(np.pi * lift_phase)), x)
        # before the first tap and after the last: at the approach height
        x = np.where((t < self._starts[0]) | (t >= self._starts[-1]), h, x)
        return x

    def sample(self, fs_hz: float) -> np.ndarray:
        """Desired position at ticks ``k/fs_hz`` for k = 0..ceil(duration*fs) (m), shape (n,).

        The same values as :meth:`position` at those times, bit for bit; because the times are in
        order, each tap's samples and each of its segments are contiguous, so every segment's formula
        runs once over its own slice (no per-sample gathering or selection): ~10x faster, linear in taps
        and samples (issue 21 item 2).
        """
        n = int(math.ceil(self.duration_s * fs_hz)) + 1
        out = np.full(n, self.approach_height_m)
        h, d, lift_s = self.approach_height_m, self.press_depth_m, self.lift_s
        n_taps = len(self._taps)

        def first_tick_at(t_s: float) -> int:
            # the first tick k with k / fs >= t_s, decided by the same division as the tick times
            k = max(0, min(n, int(math.ceil(t_s * fs_hz))))
            while k > 0 and (k - 1) / fs_hz >= t_s:
                k -= 1
            while k < n and k / fs_hz < t_s:
                k += 1
            return k

        # tap i owns starts[i] <= t < starts[i + 1] (the first also t < starts[0], the last all later t,
        # as position()'s clipped search); past the plan's end the hand is at the approach height
        edges = [first_tick_at(float(s0)) for s0 in self._starts[1:n_taps]]
        lo_all = [0, *edges]
        hi_all = [*edges, first_tick_at(float(self._starts[-1]))]
        for tp, s0, lo, hi in zip(self._taps, self._starts, lo_all, hi_all):
            if hi <= lo:
                continue
            tau = np.arange(lo, hi) / fs_hz - s0      # this tap's tick times only: memory linear in one tap
            v, ramp, t_surf = tp["v"], tp["ramp"], tp["t_surface"]
            t_brake = t_surf + tp["t_through"]
            t_rest, t_decel, t_lift = tp["t_rest"], tp["t_decel"], tp["t_lift"]
            a, b, c, e, f, g = np.searchsorted(tau, (0.0, ramp, t_surf, t_brake, t_rest, t_lift), side="left")
            phase = (tau[g:] - t_lift) / lift_s
            end = g + int(np.searchsorted(phase, 1.0, side="left"))
            x = out[lo:hi]
            # the segment formulas of _position, operation for operation
            x[a:b] = h - 0.5 * v / ramp * tau[a:b] ** 2
            x[b:c] = h - v * ramp / 2 - v * (tau[b:c] - ramp)
            x[c:e] = -v * (tau[c:e] - t_surf)
            u = tau[e:f] - t_brake
            x[e:f] = -0.5 * d - v * u + 0.5 * (v / t_decel) * u ** 2
            x[f:g] = -d
            x[g:end] = -d + (h + d) * 0.5 * (1 - np.cos(np.pi * phase[:end - g]))
        return out


class ScriptedTrajectory:
    """Arbitrary desired hand position, linearly interpolated.

    Parameters
    ----------
    t_s : array_like (n,)
        Strictly increasing times (s), starting at 0 or later.
    x_m : array_like (n,)
        Desired hand positions (m).
    """

    def __init__(self, t_s, x_m):
        t = np.asarray(t_s, dtype=float).ravel()
        x = np.asarray(x_m, dtype=float).ravel()
        if t.size < 1 or t.size != x.size:
            raise ValueError(f"ScriptedTrajectory: t_s and x_m must have the same non-zero length, "
                             f"got {t.size} and {x.size}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(x))):
            raise ValueError("ScriptedTrajectory: t_s and x_m must be finite")
        if t.size > 1 and not np.all(np.diff(t) > 0):
            raise ValueError("ScriptedTrajectory: t_s must be strictly increasing")
        if t[0] < 0:
            raise ValueError("ScriptedTrajectory: t_s must start at >= 0")
        self.t_s = t
        self.x_m = x
        self.duration_s = float(t[-1])

    def position(self, t_s) -> np.ndarray:
        """Hand target position (m) at ``t_s`` (s, scalar or array), linearly interpolated; shape of ``t_s`` (1-D)."""
        return np.interp(np.atleast_1d(np.asarray(t_s, dtype=float)), self.t_s, self.x_m)

    def sample(self, fs_hz: float) -> np.ndarray:
        """The target position (m) at ``fs_hz`` from 0 to the end of the script, shape (n,)."""
        n = int(math.ceil(self.duration_s * fs_hz)) + 1
        return self.position(np.arange(n) / fs_hz)


class HoldTrajectory:
    """The hand holds still at ``x_m`` (forever)."""

    def __init__(self, x_m: float = 0.0):
        self.x_m = float(x_m)
        self.duration_s = 0.0

    def position(self, t_s) -> np.ndarray:
        """The hold position (m) at every time in ``t_s``; shape of ``t_s`` (1-D)."""
        return np.full(np.shape(np.atleast_1d(t_s)), self.x_m)

    def sample(self, fs_hz: float) -> np.ndarray:
        """One sample: the hold position (m), shape (1,)."""
        return np.array([self.x_m])


def sample_grip(grip_N: float | Callable, n: int, fs_hz: float) -> np.ndarray:
    """Grip force (N) at the ``n`` ticks ``k / fs_hz``; ``grip_N`` is a constant or a callable t_s -> N.

    A callable is first tried vectorized (array in, array out), else called
    per sample; a constant needs no time grid. Returns shape (n,). Raises
    ValueError for negative or non-finite grip.
    """
    if callable(grip_N):
        t_s = np.arange(n) / fs_hz
        try:
            g = np.asarray(grip_N(t_s), dtype=float)
            if g.shape != t_s.shape:
                raise ValueError
        except Exception:
            g = np.array([float(grip_N(float(t))) for t in t_s])
    else:
        g = np.array([float(grip_N)])   # checked once, then spread
    if not np.all(np.isfinite(g)) or np.any(g < 0):
        raise ValueError("grip_N must be finite and >= 0 N")
    return g if callable(grip_N) else np.full(n, g[0])


@dataclass(frozen=True)
class ReactiveHand:
    """Optional reactive hand: a hand/arm mass, a muscle impedance and a contact reflex.

    The default simulated user (``SimDevice.set_user(..., hand=None)``) ties
    the handle to the desired trajectory x_u(t) through the grip
    spring-damper of eq. 3.34 (Table 3.1 ``k_u``, ``b_u``), so it behaves as
    a velocity source: a contact impulse barely changes where the handle
    goes, and penetration is set by how the desired trajectory stops. This
    model instead puts the grip spring-damper between the handle and a hand
    mass ``m_a``, which is itself driven towards the target by the muscles::

        m_a * a_a = -F_u + k_m (x_t - x_a) + b_m (v_t - v_a) + (m_a + m_tool) * a_t
        F_u = -k_u(g) (x_h - x_a) - b_u(g) (v_h - v_a)     (force of the hand on the handle)

    where ``(x_t, v_t, a_t)`` is the desired trajectory (the held position
    after the reflex), and the feedforward ``(m_a + m_tool) * a_t``, with
    ``m_tool`` the device's motor, drum and handle masses in handle space,
    stands for the central nervous system's internal model of arm and tool
    (free motion follows the trajectory within ~5 % of its speed). Contact
    impulses, a transient's included, now decelerate the hand mass against
    only the compliant muscle impedance, so the incoming momentum the thesis
    says the transient cancels (section 4.5.5) is real momentum. The contact
    reflex: once the hand feels the handle push up on it by more than
    ``reflex_force_N``, ``reflex_delay_s`` later the target stops descending
    and holds where it is (until the desired trajectory rises above that
    height, i.e. the lift), as a person stops pushing once they feel the
    surface. Only the nonlinear device model supports it.

    These are order-of-magnitude physiological values, not fitted to any
    user. Measured with them (docs/demo.md, "The reactive hand"): pulse over
    the firm wall cuts mean penetration by 40 %, HFAM by 19 % (default hand:
    15 %, 12-16 %) at 0.05-0.15 m/s.

    Attributes
    ----------
    arm_mass_kg : float
        Effective hand/arm mass at the handle, 0.2 kg: a tap is a wrist
        flexion; the hand's moment of inertia about the wrist is a few
        1e-3 kg m^2 (about 0.4 kg of hand with a radius of gyration of
        ~0.08 m gives ~3e-3 kg m^2), seen at ~0.12 m from the wrist (where the
        fingers hold the stylus) it is ~3e-3 / 0.12^2 = 0.2 kg. Finger-pad
        tissue alone is far lighter (a few grams, Hajian & Howe 1997 [53]),
        which is why that flesh is the grip spring-damper, not this mass.
    muscle_stiffness_N_m : float
        Muscle (wrist) stiffness towards the target, 120 N/m: relaxed-to-
        moderate wrist stiffness of ~1.5-2 N m/rad (wrist impedance studies
        such as Kuchenbecker, Park & Niemeyer 2003 [84] report values of this
        order) over (0.12 m)^2.
    muscle_damping_Ns_m : float
        Muscle damping, 2 N s/m: ~0.03 N m s/rad over (0.12 m)^2 (damping
        ratio ~0.2 with the mass and stiffness above, the lightly damped
        wrist of those studies).
    reflex_delay_s : float
        Delay from contact-force onset to the hand's target holding, 0.04 s:
        between the spinal (~30 ms) and long-latency (~50-60 ms) stretch
        reflexes of arm muscles; well under the ~140 ms voluntary reaction
        time the thesis quotes (section 4.2.2, [92]).
    reflex_force_N : float
        Upward force of the handle on the hand that counts as contact onset,
        0.3 N: ~10x the force of dragging the device through free space (its
        Coulomb friction is ~0.025 N, Table 3.1, plus the grip damper's lag),
        and above what accelerating the device at the start of a tap costs
        while the target is still accelerating (the reflex is armed only
        while it is not); reached a few ms after contact on the Table 4.1
        walls (at once with a transient).
    """

    arm_mass_kg: float = 0.2
    muscle_stiffness_N_m: float = 120.0
    muscle_damping_Ns_m: float = 2.0
    reflex_delay_s: float = 0.04
    reflex_force_N: float = 0.3

    def __post_init__(self):
        for key in ("arm_mass_kg",):
            val = getattr(self, key)
            if not (math.isfinite(val) and val > 0):
                raise ValueError(f"ReactiveHand: {key} must be > 0, got {val!r}")
        for key in ("muscle_stiffness_N_m", "muscle_damping_Ns_m", "reflex_delay_s", "reflex_force_N"):
            val = getattr(self, key)
            if not (math.isfinite(val) and val >= 0):
                raise ValueError(f"ReactiveHand: {key} must be finite and >= 0, got {val!r}")
