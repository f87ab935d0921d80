"""LTI device models in zero-pole-gain form with a pure delay (thesis sections 3.4.4, 4.2.2).

A :class:`ZpkModel` describes one input-output relation of a held haptic
device, e.g. commanded current -> handle acceleration (H_ha) or commanded
current -> motor position (G_i)::

    H(s) = gain * prod(s - z_i) / prod(s - p_j) * exp(-s * delay_s)

with zeros and poles in rad/s. Models are stored as JSON (format in
``docs/models.md``) and loaded with :func:`load_model`, which validates the
file (stable, proper, finite, conjugate-paired) and names the file and key
of anything wrong.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from plumbing.fileio import atomic_write_text, read_json_file
from plumbing.validation import is_finite_number

INPUTS = ("current_A",)
OUTPUTS = ("accel_m_s2", "position_m")
REQUIRED_KEYS = ("kind", "zeros_rad_s", "poles_rad_s", "gain", "delay_s", "input", "output")

# relative tolerance for matching complex-conjugate pairs of roots
_CONJ_RTOL = 1e-6


class ModelError(ValueError):
    """A model (file) is malformed: carries the key that is wrong."""


def _pair_conjugates(roots: np.ndarray, what: str) -> np.ndarray:
    """Return ``roots`` with complex roots made exact conjugate pairs.

    Real-coefficient systems have complex roots in conjugate pairs; fitted or
    hand-written values are only conjugate to rounding, which breaks exact
    second-order-section factorization, so each pair is symmetrized here.

    Raises
    ------
    ModelError
        If a complex root has no conjugate partner (within a relative 1e-6).
    """
    roots = np.asarray(roots, dtype=complex).copy()
    scale = np.maximum(np.abs(roots), 1.0)
    is_real = np.abs(roots.imag) <= _CONJ_RTOL * scale
    roots[is_real] = roots[is_real].real
    upper = [i for i in np.flatnonzero(~is_real) if roots[i].imag > 0]
    lower = [i for i in np.flatnonzero(~is_real) if roots[i].imag < 0]
    if len(upper) != len(lower):
        raise ModelError(f"{what}: complex values must come in conjugate pairs "
                         f"({len(upper)} with Im>0, {len(lower)} with Im<0)")
    for i in upper:
        # nearest unmatched conjugate partner
        dist = [abs(roots[j] - np.conj(roots[i])) for j in lower]
        k = int(np.argmin(dist))
        j = lower.pop(k)
        if dist[k] > _CONJ_RTOL * scale[i]:
            raise ModelError(f"{what}: {roots[i]} has no complex-conjugate partner")
        roots[j] = np.conj(roots[i])
    return roots


@dataclass(frozen=True, eq=False)
class ZpkModel:
    """Continuous-time zero-pole-gain model with a pure output delay.

    Attributes
    ----------
    zeros_rad_s, poles_rad_s : ndarray of complex, shape (nz,), (np,)
        Zeros and poles of H(s) in rad/s (read-only arrays; complex values in
        conjugate pairs). ``nz <= np`` (proper).
    gain : float
        Gain k in ``k * prod(s - z) / prod(s - p)`` (units of output/input
        times (rad/s)^(np - nz)).
    delay_s : float
        Pure delay, >= 0.
    input, output : str
        Signal names: ``"current_A"`` -> ``"accel_m_s2"`` or ``"position_m"``.
    band_hz : tuple of float or None
        Frequency band (lo, hi) in Hz the model was fitted/validated over.
    grip_N : float or None
        User grip force the model belongs to (section 3.4.6).
    fit : dict
        Fit figures (e.g. ``rms_db``, ``rms_phase_deg``, ``worst_band_db``).
    source : str
        Free-text provenance (recordings, device, command).

    Notes
    -----
    Stability is not required to construct a model (an analytic position
    model may have poles at the origin), but :meth:`save` and
    :func:`load_model` require strictly stable poles (Re < 0).
    """

    zeros_rad_s: np.ndarray
    poles_rad_s: np.ndarray
    gain: float
    delay_s: float = 0.0
    input: str = "current_A"
    output: str = "accel_m_s2"
    band_hz: tuple[float, float] | None = None
    grip_N: float | None = None
    fit: dict = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        z = np.atleast_1d(np.asarray(self.zeros_rad_s, dtype=complex)).ravel()
        p = np.atleast_1d(np.asarray(self.poles_rad_s, dtype=complex)).ravel()
        for key, arr in (("zeros_rad_s", z), ("poles_rad_s", p)):
            if not np.all(np.isfinite(arr)):
                raise ModelError(f"{key}: values must be finite")
        if z.size > p.size:
            raise ModelError(f"zeros_rad_s: improper model ({z.size} zeros > {p.size} poles)")
        z = _pair_conjugates(z, "zeros_rad_s")
        p = _pair_conjugates(p, "poles_rad_s")
        z.flags.writeable = False
        p.flags.writeable = False
        object.__setattr__(self, "zeros_rad_s", z)
        object.__setattr__(self, "poles_rad_s", p)
        gain = _finite_float(self.gain, "gain")
        delay = _finite_float(self.delay_s, "delay_s")
        if delay < 0:
            raise ModelError(f"delay_s: must be >= 0, got {delay}")
        object.__setattr__(self, "gain", gain)
        object.__setattr__(self, "delay_s", delay)
        if self.input not in INPUTS:
            raise ModelError(f"input: must be one of {INPUTS}, got {self.input!r}")
        if self.output not in OUTPUTS:
            raise ModelError(f"output: must be one of {OUTPUTS}, got {self.output!r}")
        if self.band_hz is not None:
            band = tuple(_finite_float(v, "band_hz") for v in self.band_hz)
            if len(band) != 2 or not 0 <= band[0] < band[1]:
                raise ModelError(f"band_hz: must be [lo, hi] with 0 <= lo < hi, got {self.band_hz!r}")
            object.__setattr__(self, "band_hz", band)
        if self.grip_N is not None:
            grip = _finite_float(self.grip_N, "grip_N")
            if grip < 0:  # a grip force presses: a negative one is a typo or a sign error, not a grip level
                raise ModelError(f"grip_N: must be >= 0 N, got {grip}")
            object.__setattr__(self, "grip_N", grip)
        if not isinstance(self.fit, dict):
            raise ModelError(f"fit: must be an object, got {type(self.fit).__name__}")
        object.__setattr__(self, "fit", dict(self.fit))
        object.__setattr__(self, "source", str(self.source))

    # -- properties --------------------------------------------------------
    @property
    def order(self) -> int:
        """Number of poles."""
        return int(self.poles_rad_s.size)

    @property
    def relative_degree(self) -> int:
        """Poles minus zeros."""
        return int(self.poles_rad_s.size - self.zeros_rad_s.size)

    @property
    def is_stable(self) -> bool:
        """True if every pole has a strictly negative real part."""
        return bool(np.all(self.poles_rad_s.real < 0))

    # -- evaluation --------------------------------------------------------
    def frequency_response(self, f_hz) -> np.ndarray:
        """Complex frequency response H(j 2 pi f), delay included.

        Parameters
        ----------
        f_hz : array_like of float, shape (n,)
            Frequencies in Hz.

        Returns
        -------
        ndarray of complex, shape (n,)
        """
        f = np.asarray(f_hz, dtype=float)
        s = 2j * np.pi * f
        num = np.prod(s[..., None] - self.zeros_rad_s, axis=-1)
        den = np.prod(s[..., None] - self.poles_rad_s, axis=-1)
        return self.gain * num / den * np.exp(-s * self.delay_s)

    def to_discrete(self, fs_hz: float) -> tuple[np.ndarray, np.ndarray, float]:
        """Tustin (bilinear) discretization, delay excluded.

        Parameters
        ----------
        fs_hz : float
            Sampling rate in Hz.

        Returns
        -------
        z, p : ndarray of complex
            Discrete zeros and poles (z-plane); a model of relative degree r
            gets r extra zeros at z = -1.
        k : float
            Discrete gain.
        """
        fs = _check_fs(fs_hz)
        zd, pd, kd = _signal().bilinear_zpk(self.zeros_rad_s, self.poles_rad_s, self.gain, fs)
        return np.asarray(zd, dtype=complex), np.asarray(pd, dtype=complex), float(np.real(kd))

    def delay_samples(self, fs_hz: float) -> int:
        """The delay rounded to whole samples at ``fs_hz`` (as used by :meth:`simulate`)."""
        return int(round(self.delay_s * _check_fs(fs_hz)))

    def simulate(self, u, fs_hz: float) -> np.ndarray:
        """Response of the model to the input sequence ``u`` sampled at ``fs_hz``.

        The Tustin model is run as cascaded second-order sections
        (``scipy.signal.sosfilt``, numerically robust for high orders) from
        zero initial state; the pure delay is then applied as a shift by
        ``round(delay_s * fs_hz)`` whole samples (zeros shifted in), so a
        fractional-sample delay is rounded to the nearest sample.

        Parameters
        ----------
        u : array_like of float, shape (n,)
            Input (e.g. current in A), sample k at time k/fs.
        fs_hz : float
            Sampling rate in Hz.

        Returns
        -------
        ndarray of float, shape (n,)
            Output (e.g. acceleration in m/s^2).
        """
        u = np.asarray(u, dtype=float)
        if u.ndim != 1:
            raise ValueError(f"simulate: u must be 1-D, got shape {u.shape}")
        if not np.all(np.isfinite(u)):
            raise ValueError("simulate: u contains NaN or inf")
        zd, pd, kd = self.to_discrete(fs_hz)
        if pd.size == 0:
            y = kd * u
        else:
            signal = _signal()
            y = signal.sosfilt(signal.zpk2sos(zd, pd, kd), u)
        n = self.delay_samples(fs_hz)
        if n > 0:
            y = np.concatenate([np.zeros(min(n, y.size)), y[: max(y.size - n, 0)]])
        return y

    # -- persistence -------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready dictionary (format in docs/models.md)."""
        return {
            "kind": "zpk",
            "zeros_rad_s": [[float(v.real), float(v.imag)] for v in self.zeros_rad_s],
            "poles_rad_s": [[float(v.real), float(v.imag)] for v in self.poles_rad_s],
            "gain": self.gain,
            "delay_s": self.delay_s,
            "input": self.input,
            "output": self.output,
            "band_hz": list(self.band_hz) if self.band_hz is not None else None,
            "grip_N": self.grip_N,
            "fit": _jsonable(self.fit, "fit"),
            "source": self.source,
        }

    def save(self, path) -> Path:
        """Write the model as JSON (atomically: a temp file renamed into place).

        Raises
        ------
        ValueError
            If the model is unstable (it could not be loaded back) or ``fit``
            holds non-finite numbers.
        """
        path = Path(path)
        if not self.is_stable:
            bad = self.poles_rad_s[self.poles_rad_s.real >= 0]
            raise ValueError(f"{path}: refusing to save an unstable model (poles_rad_s with Re >= 0: {bad})")
        return atomic_write_text(path, json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n")

    @classmethod
    def from_dict(cls, data: dict, where: str = "model") -> "ZpkModel":
        """Build and validate a model from its JSON dictionary.

        Raises
        ------
        ValueError
            Naming ``where`` (usually the file) and the offending key, for a
            missing key, wrong kind, non-finite number, improper or unstable
            model.
        """
        if not isinstance(data, dict):
            raise ValueError(f"{where}: top level must be a JSON object")
        for key in REQUIRED_KEYS:
            if key not in data:
                raise ValueError(f"{where}: missing key {key!r}")
        if data["kind"] != "zpk":
            raise ValueError(f"{where}: key 'kind' must be \"zpk\", got {data['kind']!r}")
        zeros = _read_roots(data["zeros_rad_s"], where, "zeros_rad_s")
        poles = _read_roots(data["poles_rad_s"], where, "poles_rad_s")
        band = data.get("band_hz")
        if band is not None and (not isinstance(band, (list, tuple)) or len(band) != 2):
            raise ValueError(f"{where}: key 'band_hz' must be [lo, hi] or null, got {band!r}")
        try:
            model = cls(zeros, poles, data["gain"], data["delay_s"], input=data["input"],
                        output=data["output"], band_hz=None if band is None else tuple(band),
                        grip_N=data.get("grip_N"), fit=data.get("fit") or {}, source=data.get("source") or "")
        except ModelError as exc:
            raise ValueError(f"{where}: key {exc}") from None
        if not model.is_stable:
            idx = int(np.flatnonzero(model.poles_rad_s.real >= 0)[0])
            raise ValueError(f"{where}: key 'poles_rad_s'[{idx}] = {model.poles_rad_s[idx]} is not stable "
                             "(real part must be < 0)")
        return model


def load_model(path) -> ZpkModel:
    """Load and validate a model JSON file (format in docs/models.md).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        Naming the file and key for malformed JSON, missing keys, non-finite
        numbers, improper (more zeros than poles) or unstable (Re(p) >= 0)
        models.
    """
    return ZpkModel.from_dict(read_json_file(path, "model file"), where=str(path))


# -- helpers -------------------------------------------------------------------
def _finite_float(value, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ModelError(f"{key}: must be a number, got {value!r}")
    try:
        v = float(value)
    except OverflowError:  # a JSON integer with hundreds of digits
        raise ModelError(f"{key}: must be finite, got an integer too large for a float") from None
    if not math.isfinite(v):
        raise ModelError(f"{key}: must be finite, got {v}")
    return v


def _check_fs(fs_hz) -> float:
    fs = float(fs_hz)
    if not (math.isfinite(fs) and fs > 0):
        raise ValueError(f"fs_hz must be a positive finite number, got {fs_hz!r}")
    return fs


def _read_roots(value, where: str, key: str) -> np.ndarray:
    if not isinstance(value, list):
        raise ValueError(f"{where}: key {key!r} must be a list of [re, im] pairs")
    out = np.empty(len(value), dtype=complex)
    for i, item in enumerate(value):
        if (not isinstance(item, (list, tuple)) or len(item) != 2
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in item)):
            raise ValueError(f"{where}: key {key!r}[{i}] must be a [re, im] pair of numbers, got {item!r}")
        if not all(is_finite_number(x) for x in item):
            raise ValueError(f"{where}: key {key!r}[{i}] is not finite: {item!r:.80}")
        out[i] = complex(item[0], item[1])
    return out


def _jsonable(value, key: str):
    """Convert numpy scalars/arrays in ``fit`` to plain JSON types, refusing NaN/inf."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v, f"{key}.{k}") for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_jsonable(v, f"{key}[{i}]") for i, v in enumerate(list(value))]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        if not math.isfinite(float(value)):
            raise ValueError(f"{key}: must be finite, got {value}")
        return float(value)
    if value is None or isinstance(value, str):
        return value
    raise ValueError(f"{key}: cannot store {type(value).__name__} in JSON")


def _signal():
    """:mod:`scipy.signal`, loaded on first use: loading a model (e.g. the demo's cached model set) does not need it."""
    from scipy import signal  # deferred: 1.2 s CPU; loading a model file (the demo's cached model set) needs none of it

    return signal
