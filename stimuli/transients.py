"""Parametric event-based contact transients (thesis sections 2.2.3 and 4.5.2).

Every transient maps an impact (incoming velocity magnitude, grip force) to a
force history at the handle, sampled at the servo rate: sample ``k`` of the
returned array is the force at ``t = (k + 1) / fs_hz`` after impact. The
renderer adds it to the proportional wall force for the transient's duration.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

# Table 4.1 defaults
PULSE_AMPLITUDE_NS_M = 4.55
PULSE_DURATION_S = 0.020
SINUSOID_AMPLITUDE_NS_M = 15.9
SINUSOID_DURATION_S = 0.055
SINUSOID_FREQUENCY_HZ = 55.0

# How far (in half periods) a sinusoid duration may be from a whole number of half
# periods before we warn; Table 4.1's 55 ms at 55 Hz is 6.05 half periods.
HALF_PERIOD_TOLERANCE = 0.1


@runtime_checkable
class Transient(Protocol):
    """What the renderer needs from a contact transient (docs/architecture.md "stimuli")."""

    name: str

    def waveform(self, v_in_m_s: float, grip_N: float, fs_hz: float) -> np.ndarray:
        """Force (N) for an impact at ``v_in_m_s`` (m/s) and grip ``grip_N`` (N): sample k at t = (k+1)/fs_hz."""
        ...

    def max_samples(self, fs_hz: float) -> int:
        """The longest waveform at ``fs_hz`` (samples): the size of the renderer's transient buffer."""
        ...

    def check_device(self, info, fs_hz: float) -> None:
        """ValueError if the transient cannot play on the device ``info`` at ``fs_hz`` (rate, limits)."""
        ...


def _check_positive(owner: str, key: str, value: float) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}.{key} must be a number, got {value!r}") from None
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{owner}.{key} must be a positive finite number, got {value!r}")
    return value


def _check_gain(owner: str, gain: float) -> float:
    try:
        gain = float(gain)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}.gain must be a number, got {gain!r}") from None
    if not (math.isfinite(gain) and gain >= 0.0):
        raise ValueError(f"{owner}.gain must be a finite number >= 0, got {gain!r}")
    return gain


def n_samples(duration_s: float, fs_hz: float) -> int:
    """Number of samples ``k >= 0`` with ``t = (k + 1)/fs_hz <= duration_s`` (rounding-safe)."""
    return int(math.floor(duration_s * fs_hz + 1e-9))


def _check_fs(owner: str, fs_hz: float) -> float:
    return _check_positive(owner, "fs_hz", fs_hz)


def _check_duration_vs_fs(owner: str, duration_s: float, fs_hz: float) -> None:
    if n_samples(duration_s, fs_hz) < 1:
        raise ValueError(
            f"{owner}: duration_s={duration_s} is shorter than one servo period at {fs_hz} Hz"
        )


@dataclass(frozen=True)
class Pulse:
    """Velocity-scaled fixed-width pulse, eq. 4.7: ``F = gain * A * |v_in|`` for ``0 < t <= d``.

    Parameters
    ----------
    amplitude_Ns_m : float
        Nominal amplitude A in N*s/m (force per unit incoming velocity).
    duration_s : float
        Pulse width d in s.
    gain : float
        Global gain (0.8-0.9 for users who find surfaces "active", section 4.4.1).
    """

    amplitude_Ns_m: float = PULSE_AMPLITUDE_NS_M
    duration_s: float = PULSE_DURATION_S
    gain: float = 1.0
    name: str = "pulse"

    def __post_init__(self) -> None:
        object.__setattr__(self, "amplitude_Ns_m", _check_positive("Pulse", "amplitude_Ns_m", self.amplitude_Ns_m))
        object.__setattr__(self, "duration_s", _check_positive("Pulse", "duration_s", self.duration_s))
        object.__setattr__(self, "gain", _check_gain("Pulse", self.gain))

    def max_samples(self, fs_hz: float) -> int:
        """Length of every waveform at ``fs_hz`` (samples with ``0 < t <= d``)."""
        return n_samples(self.duration_s, _check_fs("Pulse", fs_hz))

    def waveform(self, v_in_m_s: float, grip_N: float, fs_hz: float) -> np.ndarray:
        """Force in N, shape (max_samples(fs_hz),); grip is ignored (eq. 4.7)."""
        n = self.max_samples(fs_hz)
        return np.full(n, self.gain * self.amplitude_Ns_m * abs(float(v_in_m_s)))

    def check_device(self, info, fs_hz: float) -> None:
        """Raise ValueError if the pulse cannot be sampled at ``fs_hz``."""
        _check_duration_vs_fs("Pulse", self.duration_s, _check_fs("Pulse", fs_hz))


@dataclass(frozen=True)
class DecayingSinusoid:
    """Velocity-scaled decaying sinusoid, eq. 4.8.

    ``F = gain * A * |v_in| * exp(ln(0.01) * t / d) * sin(2 pi f t)`` for ``0 < t <= d``:
    the envelope decays to 1 % at ``t = d``, so ``d`` is the total duration and the decay time
    constant of Okamura et al.'s ``A v e^(-t/tau) sin(2 pi f t)`` form [114] is ``tau = d / ln(100)``
    (11.9 ms for Table 4.1's 55 ms). Positive (out of the surface) for the first half period; its net
    impulse per unit velocity is ``A [w - e^(-b d)(b sin wd + w cos wd)] / (b^2 + w^2)`` with
    ``b = ln(100)/d``, ``w = 2 pi f``: 0.0430 N s per m/s for Table 4.1, 47 % of the pulse's ``A d``.
    Warns (UserWarning) when ``d`` is not
    within ``HALF_PERIOD_TOLERANCE`` of a whole number of half periods ``1/(2f)``
    (the thesis picks whole half periods for a smooth overlay).

    Parameters
    ----------
    amplitude_Ns_m : float
        Nominal amplitude A in N*s/m.
    duration_s : float
        Duration d in s.
    frequency_hz : float
        Oscillation frequency f in Hz.
    gain : float
        Global gain.
    """

    amplitude_Ns_m: float = SINUSOID_AMPLITUDE_NS_M
    duration_s: float = SINUSOID_DURATION_S
    frequency_hz: float = SINUSOID_FREQUENCY_HZ
    gain: float = 1.0
    name: str = "sinusoid"

    def __post_init__(self) -> None:
        owner = "DecayingSinusoid"
        object.__setattr__(self, "amplitude_Ns_m", _check_positive(owner, "amplitude_Ns_m", self.amplitude_Ns_m))
        object.__setattr__(self, "duration_s", _check_positive(owner, "duration_s", self.duration_s))
        object.__setattr__(self, "frequency_hz", _check_positive(owner, "frequency_hz", self.frequency_hz))
        object.__setattr__(self, "gain", _check_gain(owner, self.gain))
        half_periods = self.duration_s * 2.0 * self.frequency_hz
        if abs(half_periods - round(half_periods)) > HALF_PERIOD_TOLERANCE:
            warnings.warn(
                f"DecayingSinusoid: duration_s={self.duration_s} is {half_periods:.3f} half periods of "
                f"{self.frequency_hz} Hz, not a whole number; the transient ends on a non-zero sample",
                UserWarning,
                stacklevel=3,
            )

    def max_samples(self, fs_hz: float) -> int:
        """Length of every waveform at ``fs_hz``."""
        return n_samples(self.duration_s, _check_fs("DecayingSinusoid", fs_hz))

    def waveform(self, v_in_m_s: float, grip_N: float, fs_hz: float) -> np.ndarray:
        """Force in N, shape (max_samples(fs_hz),); grip is ignored (eq. 4.8)."""
        n = self.max_samples(fs_hz)
        t = np.arange(1, n + 1) / float(fs_hz)
        scale = self.gain * self.amplitude_Ns_m * abs(float(v_in_m_s))
        return scale * np.exp(math.log(0.01) * t / self.duration_s) * np.sin(2.0 * math.pi * self.frequency_hz * t)

    def check_device(self, info, fs_hz: float) -> None:
        """Raise ValueError if the sinusoid cannot be sampled at ``fs_hz`` (needs f < fs/2)."""
        fs_hz = _check_fs("DecayingSinusoid", fs_hz)
        _check_duration_vs_fs("DecayingSinusoid", self.duration_s, fs_hz)
        if self.frequency_hz >= fs_hz / 2.0:
            raise ValueError(
                f"DecayingSinusoid: frequency_hz={self.frequency_hz} is not below the Nyquist "
                f"frequency {fs_hz / 2.0} Hz of the servo rate"
            )


@dataclass(frozen=True)
class NoTransient:
    """No transient: proportional feedback only (and the real samples)."""

    name: str = "none"
    gain: float = 1.0

    def max_samples(self, fs_hz: float) -> int:
        """0: no transient plays."""
        return 0

    def waveform(self, v_in_m_s: float, grip_N: float, fs_hz: float) -> np.ndarray:
        """An empty waveform (N), shape (0,)."""
        return np.zeros(0)

    def check_device(self, info, fs_hz: float) -> None:
        """Nothing to check: plays on any device."""
        return None
