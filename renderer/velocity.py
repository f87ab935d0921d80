"""Velocity estimation from a quantized encoder position.

Why least squares: a 2000-line encoder on the thesis' 1-DOF joystick
(rho = 15, h = 0.15 m) resolves q = 7.9 um at the handle, while a 0.05 m/s tap
moves only 5 um per 10 kHz tick. A backward difference therefore jumps between
0 and ~0.08 m/s. Fitting a straight line to the last ``W`` positions (ordinary
least squares, uniform sample times) averages the quantization staircase:
the slope error is at most ``1.5 q / (W dt)`` and typically far smaller
(``~q / (W^1.5 dt)`` when the sub-count phase is spread over the window).

Two estimators use the same fit:

* **per tick** (logged ``velocity_m_s``, entry damping): a sliding window of
  ``velocity_window_s`` updated in O(1) with running sums (no allocation),
  see :func:`ls_constants` and the servo loop;
* **at impact** (``incoming_velocity_m_s``), computed once per event from
  the loop's position ring buffer, ending at the crossing tick
  (:class:`ImpactVelocityEstimator`):

  1. a rough speed ``v0``: the per-tick sliding estimate (the servo loop) or
     the straight-line slope over the longest window (``impact_window_s``);
  2. a window of ``W`` samples chosen so that the handle travelled about
     ``impact_counts`` encoder counts (``W = impact_counts * q / (v0 dt)``),
     clipped to ``[impact_min_window_s, impact_window_s]``: slow taps get a
     long window (quantization dominates), fast taps a short one (curvature
     dominates);
  3. a *quadratic* least-squares fit over those ``W`` samples, differentiated
     at the newest sample. A straight line would report the mean velocity
     over the window, biased when the hand decelerates just before contact
     (the sim's repeated taps do, ~20 m/s^2 at 0.4 m/s); the quadratic term
     absorbs a constant deceleration. Its weights are precomputed for every
     ``W`` (:func:`endpoint_derivative_weights`).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from types import MappingProxyType

import numpy as np


def ls_constants(window: int, dt_s: float) -> tuple[float, float]:
    """Constants of the O(1) sliding least-squares slope.

    With window samples ``y_0..y_{W-1}`` (newest last), ``S0 = sum y_k`` and
    ``S1 = sum k y_k``, the slope is ``(S1 - c_shift * S0) * c_scale``.

    Returns
    -------
    c_shift, c_scale : float
        ``(W - 1) / 2`` and ``W / (W sum k^2 - (sum k)^2) / dt_s`` (1/s).
    """
    w = int(window)
    if w < 2:
        raise ValueError(f"least-squares window must hold >= 2 samples, got {w}")
    k1 = w * (w - 1) / 2.0
    k2 = (w - 1) * w * (2 * w - 1) / 6.0
    return (w - 1) / 2.0, w / (w * k2 - k1 * k1) / dt_s


def ls_slope_ring(ring, newest: int, window: int, dt_s: float) -> float:
    """Least-squares slope (units/s) of the last ``window`` samples of a ring buffer.

    Parameters
    ----------
    ring : sequence of float
        Ring buffer (e.g. ``array.array('d')``) of length >= ``window``.
    newest : int
        Index of the newest sample in ``ring``.
    window : int
        Number of samples fitted (>= 2).
    dt_s : float
        Sample period.
    """
    n = len(ring)
    c_shift, c_scale = ls_constants(window, dt_s)
    s0 = 0.0
    s1 = 0.0
    start = newest - window + 1
    for k in range(window):
        y = ring[(start + k) % n]
        s0 += y
        s1 += k * y
    return (s1 - c_shift * s0) * c_scale


def ls_velocity(position_m: np.ndarray, fs_hz: float, window: int) -> np.ndarray:
    """Vectorised causal sliding least-squares velocity of a position record (offline use, tests).

    Returns an array of the same length; the first ``window - 1`` samples use
    the first sample repeated (as the servo loop does at start-up).
    """
    x = np.asarray(position_m, dtype=float)
    padded = np.concatenate([np.full(window - 1, x[0]), x])
    k = np.arange(window, dtype=float)
    kernel = (k - k.mean()) / np.sum((k - k.mean()) ** 2) * fs_hz
    return np.convolve(padded, kernel[::-1], mode="valid")


def endpoint_derivative_weights(window: int, dt_s: float) -> list[float]:
    """Weights ``w`` with ``v = sum_k w[k] y_k`` (oldest first): derivative at the newest sample of a
    quadratic least-squares fit to ``window`` uniformly spaced samples (1/s).

    Closed form of the fit (a Savitzky-Golay endpoint derivative, ``scipy.signal.savgol_coeffs(window,
    2, deriv=1, delta=dt_s, pos=window - 1, use="dot")``, which the tests compare against, as against
    ``np.linalg.pinv``): with the abscissa centred, ``x_k = k - (W - 1)/2``, the odd moments vanish and
    ``y = b0 + b1 x + b2 x^2`` has ``b1 = sum x y / S2`` and ``b2 = (W sum x^2 y - S2 sum y) / (W S4 -
    S2^2)``; the derivative at the newest sample ``x0 = (W - 1)/2`` is ``b1 + 2 b2 x0``. An estimator
    builds 81 windows; 81 SVDs cost ~3-7 ms of every run's start.
    """
    if window < 3:
        raise ValueError(f"quadratic fit needs >= 3 samples, got {window}")
    n = float(window)
    x = np.arange(window, dtype=float) - 0.5 * (n - 1.0)
    s2 = n * (n * n - 1.0) / 12.0
    s4 = n * (n * n - 1.0) * (3.0 * n * n - 7.0) / 240.0
    w = x / s2 + (n - 1.0) * (n * x * x - s2) / (n * s4 - s2 * s2)
    return (w / dt_s).tolist()


@functools.lru_cache(maxsize=8)
def _weight_tables(w_min: int, w_max: int, dt_s: float) -> tuple[Mapping, Mapping]:
    """:func:`endpoint_derivative_weights` for every window ``w_min..w_max`` (as tuples and as read-only
    arrays, in read-only mappings), computed once per process and shared: the 3-D loop builds an estimator
    per axis (243 windows, ~5 ms of a run's start computed three times over). Nothing in them can be changed,
    so no estimator can change another's weights."""
    weights = {w: tuple(endpoint_derivative_weights(w, dt_s)) for w in range(w_min, w_max + 1)}
    arrays = {}
    for w, v in weights.items():
        arrays[w] = np.array(v)
        arrays[w].flags.writeable = False
    return MappingProxyType(weights), MappingProxyType(arrays)


class ImpactVelocityEstimator:
    """Incoming velocity at a crossing from the position ring buffer (see the module doc).

    Parameters
    ----------
    dt_s : float
        Servo period.
    resolution_m : float
        Encoder resolution q at the handle.
    min_window_s, max_window_s : float
        Bounds of the fitted window.
    counts : float
        Target travel over the window, in encoder counts.
    """

    def __init__(self, dt_s: float, resolution_m: float, min_window_s: float = 0.002,
                 max_window_s: float = 0.010, counts: float = 100.0):
        self.dt_s = dt_s
        self.q = resolution_m
        self.counts = counts
        self.w_min = max(3, int(round(min_window_s / dt_s)))
        self.w_max = max(self.w_min, int(round(max_window_s / dt_s)))
        self.weights, self.weight_arrays = _weight_tables(self.w_min, self.w_max, float(dt_s))
        self._view = None
        self._half = 0

    def bind(self, ring2) -> None:
        """Attach a *double-written* ring (length 2N; sample i stored at i and i + N), so the
        last ``w`` samples are always contiguous and the fit is one ``numpy.dot`` (servo loop use)."""
        self._view = np.frombuffer(ring2, dtype=np.float64)
        self._half = len(ring2) // 2
        if self._half < self.w_max:
            raise ValueError(f"ring of {self._half} samples is shorter than the {self.w_max}-sample window")

    def at(self, newest: int, rough_speed_m_s: float) -> float:
        """Velocity (m/s, signed) at ring index ``newest`` of the bound ring, window sized for ``rough_speed_m_s``."""
        w = self.window_for(abs(rough_speed_m_s))
        end = newest + self._half + 1
        return float(np.dot(self.weight_arrays[w], self._view[end - w:end]))

    @property
    def history(self) -> int:
        """Samples of history the ring buffer must hold."""
        return self.w_max

    def window_for(self, speed_m_s: float) -> int:
        """Samples fitted for a rough speed (m/s)."""
        if speed_m_s <= 0.0:
            return self.w_max
        w = int(round(self.counts * self.q / (speed_m_s * self.dt_s)))
        return min(max(w, self.w_min), self.w_max)

    def __call__(self, ring, newest: int) -> float:
        """Velocity (m/s, signed, + up) at the newest sample of ``ring``."""
        rough = abs(ls_slope_ring(ring, newest, self.w_max, self.dt_s))
        w = self.window_for(rough)
        weights = self.weights[w]
        n = len(ring)
        start = newest - w + 1
        v = 0.0
        for k in range(w):
            v += weights[k] * ring[(start + k) % n]
        return v
