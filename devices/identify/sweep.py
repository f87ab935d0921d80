"""Swept-sine excitation (thesis section 3.4.1, eq. 3.11-3.12)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plumbing.validation import require_int, require_number, require_positive


@dataclass(frozen=True)
class SweepConfig:
    """Parameters of one swept-sine trial.

    Attributes
    ----------
    amplitude_A : float
        Current amplitude i_amp (eq. 3.11), > 0.
    f_start_hz, f_end_hz : float
        Initial and final frequencies f_i, f_f (eq. 3.12); the sweep may run
        down (f_start > f_end). Both must be below the Nyquist frequency.
    duration_s : float
        Length of one sweep (N = round(duration_s * fs_hz) samples).
    fs_hz : float
        Sampling (servo) rate, 1/T.
    repetitions : int
        The sweep is played this many times back to back (2 in the thesis:
        the second copy is analysed, free of start-up transients).
    """

    amplitude_A: float = 0.75
    f_start_hz: float = 5.0
    f_end_hz: float = 1000.0
    duration_s: float = 2.0
    fs_hz: float = 10_000.0
    repetitions: int = 2

    def __post_init__(self) -> None:
        require_positive(self, "amplitude_A", "duration_s", "fs_hz", prefix="sweep ")
        for key in ("f_start_hz", "f_end_hz"):
            value = require_number(key, getattr(self, key), minimum=0.0, prefix="sweep ")
            if value >= self.fs_hz / 2:
                raise ValueError(f"sweep {key} = {value} Hz is not below the Nyquist frequency "
                                 f"{self.fs_hz / 2} Hz (fs_hz = {self.fs_hz})")
        if self.f_start_hz == self.f_end_hz:
            raise ValueError("sweep f_start_hz and f_end_hz must differ")
        require_int("repetitions", self.repetitions, minimum=1, prefix="sweep ")
        if self.n_samples < 64:
            raise ValueError(f"sweep too short: {self.n_samples} samples (duration_s * fs_hz must be >= 64)")

    @property
    def n_samples(self) -> int:
        """N, samples per sweep."""
        return int(round(self.duration_s * self.fs_hz))

    @property
    def band_hz(self) -> tuple[float, float]:
        """(lo, hi) of the swept band."""
        return (min(self.f_start_hz, self.f_end_hz), max(self.f_start_hz, self.f_end_hz))


def swept_sine(cfg: SweepConfig, polarity: int = 1) -> np.ndarray:
    """Current command of one trial: the sweep of eq. 3.11-3.12, repeated.

    ``i_k = i_amp sin(2 pi f_k k T)`` with ``f_k = f_i + k (f_f - f_i) / (2 (N - 1))``,
    so the instantaneous frequency rises linearly from f_i to f_f over the
    N samples. The N-sample sweep is tiled ``cfg.repetitions`` times.

    Parameters
    ----------
    cfg : SweepConfig
    polarity : {1, -1}
        Sign of the command (the thesis reverses it for half the trials).

    Returns
    -------
    ndarray of float, shape (cfg.repetitions * N,)
        Current in A.
    """
    if polarity not in (1, -1):
        raise ValueError(f"polarity must be +1 or -1, got {polarity!r}")
    n = cfg.n_samples
    k = np.arange(n)
    f_k = cfg.f_start_hz + k / (2.0 * (n - 1)) * (cfg.f_end_hz - cfg.f_start_hz)
    one = polarity * cfg.amplitude_A * np.sin(2.0 * np.pi * f_k * k / cfg.fs_hz)
    return np.tile(one, cfg.repetitions)
