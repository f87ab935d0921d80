"""The simulated user: desired hand trajectories and grip force (thesis sections 3.4.6, 3.5.2).

The hand is a spring-damper between the handle and a desired hand position
x_u(t) (eq. 3.34 with ``-k_u*(x_h - x_u) - b_u*(v_h - v_u)``). Its stiffness
and damping rise linearly with grip force from zero (no user) through the
Table 3.1 values at the nominal grip (section 3.5.2, last paragraphs):
``k_u(g) = k_u * g / g_nom``, ``b_u(g) = b_u * g / g_nom``.

Trajectories are sampled onto the servo grid in fixed-size windows that the
simulated device refills between kernel calls (``sample_range``), so the servo
path only indexes arrays and memory does not grow with the plan's length.
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

    The plan is kept as its tap schedule (a few numbers per tap, ~80 bytes),
    never as samples: :meth:`sample_range` computes any stretch of servo ticks
    on demand, so a simulated device streams it (memory constant in
    the number of taps).

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
        self.n_taps = int(n_taps)
        self.approach_height_m = float(approach_height_m)
        self.dwell_s = float(dwell_s)
        self.lift_s = float(lift_s)
        self.press_depth_m = float(press_depth_m)
        self.pause_s = float(pause_s)
        self.ramp_s = float(ramp_s)
        # one entry per tap, the speeds cycled (np.resize repeats the sequence)
        self._tap_arrays = self._tap_segments(np.resize(np.array(vels), self.n_taps))
        self._starts = np.concatenate([[0.0], np.cumsum(self._tap_arrays["total"])])
        self.duration_s = float(self._starts[-1])

    @property
    def velocities_m_s(self) -> tuple:
        """The speed of every tap (m/s), one per tap (the given speeds cycled), as a tuple made on request."""
        return tuple(self._tap_arrays["v"].tolist())

    @property
    def surface_times_s(self) -> tuple:
        """Times (s, from the start) at which the desired hand crosses the surface, one per tap (a tuple
        made on request: the plan keeps only its schedule)."""
        return tuple((self._starts[:-1] + self._tap_arrays["t_surface"]).tolist())

    def _tap_segments(self, v: np.ndarray) -> dict:
        """Segment times (s, from each tap's start) of taps at speeds ``v`` (m/s, shape (n_taps,)).

        Element by element the same IEEE operations as the scalar formulas (numpy does not fuse or reorder
        them), so a tap's numbers do not depend on how many taps the plan has.
        """
        h = self.approach_height_m
        ramp = np.minimum(self.ramp_s, h / v)     # keep the ramp distance (v*ramp/2) within the approach
        t_cruise = (h - v * ramp / 2) / v
        t_surface = ramp + t_cruise
        t_through = 0.5 * self.press_depth_m / v          # constant speed below the surface
        t_decel = self.press_depth_m / v                  # uniform deceleration over the other half
        t_rest = t_surface + t_through + t_decel
        return {"v": v, "ramp": ramp, "t_surface": t_surface, "t_through": t_through, "t_decel": t_decel,
                "t_rest": t_rest, "t_lift": t_rest + self.dwell_s,
                "total": t_rest + self.dwell_s + self.lift_s + self.pause_s}

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
        n_taps = self.n_taps
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

    def n_ticks(self, fs_hz: float) -> int:
        """Number of servo ticks :meth:`sample` gives at ``fs_hz``: ``ceil(duration * fs) + 1``."""
        return int(math.ceil(self.duration_s * fs_hz)) + 1

    def sample(self, fs_hz: float) -> np.ndarray:
        """Desired position at ticks ``k/fs_hz`` for k = 0..ceil(duration*fs) (m), shape (n,).

        The same values as :meth:`position` at those times, bit for bit; because the times are in
        order, each tap's samples and each of its segments are contiguous, so every segment's formula
        runs once over its own slice (no per-sample gathering or selection): ~10x faster, linear in taps
        and samples. ``sample_range(fs_hz, 0, n_ticks(fs_hz))``.
        """
        return self.sample_range(fs_hz, 0, self.n_ticks(fs_hz))

    def sample_range(self, fs_hz: float, lo: int, hi: int) -> np.ndarray:
        """Ticks ``lo..hi-1`` of :meth:`sample` (m), shape (hi - lo,) after clipping to ``0..n_ticks``.

        Bit for bit ``sample(fs_hz)[lo:hi]``, computed only for those ticks (memory and time linear in
        ``hi - lo`` plus the taps they touch, not in the plan): every tick's value is the same per-element
        arithmetic on ``k / fs_hz`` whatever the stretch asked for. ``devices.sim.SimDevice`` streams the
        plan this way in fixed-size windows.
        """
        n = self.n_ticks(fs_hz)
        lo, hi = max(0, int(lo)), min(n, int(hi))
        out = np.full(max(hi - lo, 0), self.approach_height_m)
        if hi <= lo:
            return out
        h, d, lift_s = self.approach_height_m, self.press_depth_m, self.lift_s
        n_taps, starts, par = self.n_taps, self._starts, self._tap_arrays

        def first_tick_at(t_s: float) -> int:
            # the first tick k with k / fs >= t_s, decided by the same division as the tick times
            k = max(0, min(n, int(math.ceil(t_s * fs_hz))))
            while k > 0 and (k - 1) / fs_hz >= t_s:
                k -= 1
            while k < n and k / fs_hz < t_s:
                k += 1
            return k

        # tap i owns first_tick_at(starts[i]) <= k < first_tick_at(starts[i + 1]) (the first also the ticks
        # before, as position()'s clipped search); past the plan's end the hand is at the approach height.
        # The first tap reaching into lo..hi: the last whose first tick is <= lo, i.e. starts[i] <= lo / fs
        i = max(0, int(np.searchsorted(starts[:n_taps], lo / fs_hz, side="right")) - 1)
        t_lo = 0 if i == 0 else first_tick_at(float(starts[i]))
        while i < n_taps and t_lo < hi:
            t_hi = first_tick_at(float(starts[i + 1]))
            a0, b0 = max(t_lo, lo), min(t_hi, hi)
            if b0 > a0:
                s0 = starts[i]
                tau = np.arange(a0, b0) / fs_hz - s0      # this tap's ticks in the stretch only
                v, ramp, t_surf = par["v"][i], par["ramp"][i], par["t_surface"][i]
                t_brake = t_surf + par["t_through"][i]
                t_rest, t_decel, t_lift = par["t_rest"][i], par["t_decel"][i], par["t_lift"][i]
                a, b, c, e, f, g = np.searchsorted(tau, (0.0, ramp, t_surf, t_brake, t_rest, t_lift), side="left")
                phase = (tau[g:] - t_lift) / lift_s
                end = g + int(np.searchsorted(phase, 1.0, side="left"))
                x = out[a0 - lo:b0 - lo]
                # the segment formulas of _position, operation for operation
                x[a:b] = h - 0.5 * v / ramp * tau[a:b] ** 2
                x[b:c] = h - v * ramp / 2 - v * (tau[b:c] - ramp)
                x[c:e] = -v * (tau[c:e] - t_surf)
                u = tau[e:f] - t_brake
                x[e:f] = -0.5 * d - v * u + 0.5 * (v / t_decel) * u ** 2
                x[f:g] = -d
                x[g:end] = -d + (h + d) * 0.5 * (1 - np.cos(np.pi * phase[:end - g]))
            i += 1
            t_lo = t_hi
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

    def n_ticks(self, fs_hz: float) -> int:
        """Number of servo ticks :meth:`sample` gives at ``fs_hz``: ``ceil(duration * fs) + 1``."""
        return int(math.ceil(self.duration_s * fs_hz)) + 1

    def sample(self, fs_hz: float) -> np.ndarray:
        """The target position (m) at ``fs_hz`` from 0 to the end of the script, shape (n,)."""
        return self.sample_range(fs_hz, 0, self.n_ticks(fs_hz))

    def sample_range(self, fs_hz: float, lo: int, hi: int) -> np.ndarray:
        """Ticks ``lo..hi-1`` of :meth:`sample` (m, bit for bit: interpolation is per tick), clipped to
        ``0..n_ticks``; shape (hi - lo,)."""
        lo, hi = max(0, int(lo)), min(self.n_ticks(fs_hz), int(hi))
        return self.position(np.arange(lo, max(lo, hi)) / fs_hz)


class HoldTrajectory:
    """The hand holds still at ``x_m`` (forever)."""

    def __init__(self, x_m: float = 0.0):
        self.x_m = float(x_m)
        self.duration_s = 0.0

    def position(self, t_s) -> np.ndarray:
        """The hold position (m) at every time in ``t_s``; shape of ``t_s`` (1-D)."""
        return np.full(np.shape(np.atleast_1d(t_s)), self.x_m)

    def n_ticks(self, fs_hz: float) -> int:
        """One tick: the hold position holds for ever."""
        return 1

    def sample(self, fs_hz: float) -> np.ndarray:
        """One sample: the hold position (m), shape (1,)."""
        return np.array([self.x_m])

    def sample_range(self, fs_hz: float, lo: int, hi: int) -> np.ndarray:
        """Ticks ``lo..hi-1`` of :meth:`sample` clipped to its one tick (m), shape (0,) or (1,)."""
        return np.full(max(0, min(1, int(hi)) - max(0, int(lo))), self.x_m)


def sample_grip(grip_N: float | Callable, n: int, fs_hz: float, start: int = 0) -> np.ndarray:
    """Grip force (N) at the ``n`` ticks ``k / fs_hz``, k = start..start+n-1; ``grip_N`` is a constant or a
    callable t_s -> N.

    A callable is first tried vectorized (array in, array out), else called
    per sample; a constant needs no time grid. Returns shape (n,). Raises
    ValueError for negative or non-finite grip. ``start`` lets a simulated
    device stream the grip in windows, as the plan (the same tick times).
    """
    if callable(grip_N):
        t_s = np.arange(start, start + n) / fs_hz
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
