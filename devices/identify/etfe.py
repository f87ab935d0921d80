"""Empirical transfer function estimates from swept-sine recordings (thesis section 3.4.2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d

from .recording import Recording, analysed_slice

OUTPUT_COLUMNS = ("accel_m_s2", "position_m")
# output amplitude below this many quantization steps is not resolvable (see Etfe.resolvable_hi_hz)
RESOLVABLE_LSB = 2.0


@dataclass(frozen=True, eq=False)
class Etfe:
    """An ETFE curve of one condition (several trials complex-averaged).

    Attributes
    ----------
    f_hz : ndarray, shape (m,)
        DFT bin frequencies n fs / N inside the swept band (eq. 3.16, in Hz).
    H : ndarray of complex, shape (m,)
        Smoothed estimate: magnitude and unwrapped phase each passed through a
        ``smooth``-sample boxcar.
    H_raw : ndarray of complex, shape (m,)
        Unsmoothed estimate.
    coherence : ndarray, shape (m,)
        Magnitude-squared coherence across trials, |sum Y U*|^2 / (sum|U|^2 sum|Y|^2),
        boxcar-smoothed; 1 means all trials agree (identically 1 for one trial).
    output : str
        ``"accel_m_s2"`` (H_ha) or ``"position_m"`` (G_i).
    n_trials : int
    grip_N : float
        Mean grip over the analysed sweeps, N.
    label : str
        Condition label (e.g. ``"grip 2 N"``).
    resolvable_hi_hz : float
        Highest bin where the output amplitude (|H| times the input
        amplitude) is at least ``RESOLVABLE_LSB`` quantization steps of the
        output signal; above it the estimate is quantization noise (typical
        of encoder position at high frequency). ``inf`` if the output is not
        visibly quantized.
    """

    f_hz: np.ndarray
    H: np.ndarray
    H_raw: np.ndarray
    coherence: np.ndarray
    output: str
    n_trials: int
    grip_N: float
    label: str = ""
    resolvable_hi_hz: float = float("inf")

    @property
    def band_hz(self) -> tuple[float, float]:
        """``(lowest, highest)`` frequency of the estimate, Hz."""
        return float(self.f_hz[0]), float(self.f_hz[-1])


def detrend_ramp(y: np.ndarray) -> np.ndarray:
    """Subtract the ramp through the first and last samples (eq. 3.13-3.14).

    Parameters
    ----------
    y : ndarray, shape (N,)

    Returns
    -------
    ndarray, shape (N,)
        ``y_k - y_0 - k/(N-1) (y_{N-1} - y_0)``: zero at both ends.
    """
    n = y.size
    k = np.arange(n)
    return y - y[0] - k / (n - 1) * (y[-1] - y[0])


def detrend_periodic(y: np.ndarray, y_prev_end: float) -> np.ndarray:
    """Remove only the drift between two sweep copies (an option beside eq. 3.13).

    ``y_prev_end`` is the last sample of the previous copy. For a response in
    periodic steady state ``y_{N-1}`` equals it and nothing but the mean is
    removed; a slow drift ``y_{N-1} - y_prev_end`` per period is removed as a
    ramp. Unlike eq. 3.13 this does not force ``y_0 = y_{N-1}``, which
    distorts the lowest bins when the response legitimately differs at the
    two ends (it does at the sweep's high-frequency end).
    """
    n = y.size
    k = np.arange(n)
    drift = y[-1] - y_prev_end
    return y - y.mean() - (k / n - 0.5) * drift


def boxcar(x: np.ndarray, width: int) -> np.ndarray:
    """Centred moving average of ``width`` samples (edges use the nearest sample)."""
    if width <= 1:
        return np.asarray(x, dtype=float)
    # deferred: scipy.ndimage takes ~0.3 s to import, and `python -m devices identify` imports this module
    # before it forks its recording process, which must not wait for scipy (see pipeline.identify_device)

    return uniform_filter1d(np.asarray(x, dtype=float), size=width, mode="nearest")


def smooth_complex(H: np.ndarray, width: int) -> np.ndarray:
    """Boxcar-smooth magnitude and phase separately (section 3.4.2).

    The phase is averaged as a circular mean (the angle of the boxcar mean of
    unit phasors): identical to a boxcar on the unwrapped phase where the
    phase changes little over ``width`` bins, but a noisy bin near +-180 deg
    cannot slip the unwrapping of everything above it by whole turns.
    """
    mag = boxcar(np.abs(H), width)
    unit = H / np.maximum(np.abs(H), np.finfo(float).tiny)
    phasor = boxcar(unit.real, width) + 1j * boxcar(unit.imag, width)
    return mag * np.exp(1j * np.angle(phasor))


DETRENDS = ("ramp", "periodic")


def etfe(recordings: list[Recording], output: str = "accel_m_s2", smooth: int = 5, label: str = "",
         detrend: str = "ramp") -> Etfe:
    """ETFE of ``output`` over commanded current from one or more trials (section 3.4.2).

    For each trial the second sweep copy is isolated, the output is ramp
    detrended (eq. 3.13-3.14) and input and output are transformed with an
    N-point DFT (eq. 3.15; the 1/N and the (k+1) phase factor cancel in the
    ratio). The outputs are complex-averaged across trials and divided by
    the input, written as the cross-spectral ratio
    ``sum_k Y_k conj(U_k) / sum_k |U_k|^2``, which equals the thesis'
    ``mean(Y) / U`` when every trial has the same input and also handles
    trials with reversed polarity or another amplitude. Only bins inside
    [f_i, f_f] are kept; magnitude and phase are then smoothed by a
    ``smooth``-sample boxcar.

    Parameters
    ----------
    recordings : list of Recording
        Trials of one condition; all with the same ``fs_hz``, sweep length
        and band.
    output : {"accel_m_s2", "position_m"}
    smooth : int
        Boxcar width in bins (5 in the thesis).
    label : str
    detrend : {"ramp", "periodic"}
        ``"ramp"``: eq. 3.13-3.14 (thesis). ``"periodic"``: only the drift
        between the first and second copy (:func:`detrend_periodic`; needs
        ``repetitions >= 2``), more accurate in the lowest bins.

    Returns
    -------
    Etfe
    """
    if output not in OUTPUT_COLUMNS:
        raise ValueError(f"ETFE output must be one of {OUTPUT_COLUMNS}, got {output!r}")
    if not recordings:
        raise ValueError("ETFE needs at least one recording")
    if detrend not in DETRENDS:
        raise ValueError(f"detrend must be one of {DETRENDS}, got {detrend!r}")
    ref = recordings[0].sweep
    for rec in recordings[1:]:
        s = rec.sweep
        if (s.fs_hz, s.n_samples, s.band_hz) != (ref.fs_hz, ref.n_samples, ref.band_hz):
            raise ValueError(f"{rec.label}: sweep (fs_hz {s.fs_hz}, {s.n_samples} samples, band {s.band_hz}) "
                             f"differs from {recordings[0].label} (fs_hz {ref.fs_hz}, {ref.n_samples} samples, "
                             f"band {ref.band_hz}); average only trials of one sweep")
    n = ref.n_samples
    f_all = np.fft.rfftfreq(n, d=1.0 / ref.fs_hz)
    lo_hz, hi_hz = ref.band_hz
    # two extra bins each side so the boxcar has real neighbours at the band edges
    idx = np.flatnonzero((f_all >= lo_hz) & (f_all <= hi_hz))
    if idx.size < 2 * smooth:
        raise ValueError(f"{recordings[0].label}: band {lo_hz}-{hi_hz} Hz holds only {idx.size} DFT bins")
    pad = smooth // 2
    lo_i, hi_i = max(idx[0] - pad, 1), min(idx[-1] + pad, f_all.size - 1)
    sel = slice(lo_i, hi_i + 1)
    syu = np.zeros(hi_i + 1 - lo_i, dtype=complex)
    suu = np.zeros(hi_i + 1 - lo_i)
    syy = np.zeros(hi_i + 1 - lo_i)
    grips = []
    for rec in recordings:
        a, b = analysed_slice(rec)
        u = rec.current_A[a:b]
        full = rec.signal(output)
        y = detrend_periodic(full[a:b], full[a - 1]) if detrend == "periodic" and a > 0 else detrend_ramp(full[a:b])
        U = np.fft.rfft(u)[sel] / n
        Y = np.fft.rfft(y)[sel] / n
        syu += Y * np.conj(U)
        suu += np.abs(U) ** 2
        syy += np.abs(Y) ** 2
        grips.append(float(np.mean(rec.grip_N[a:b])))
    if np.any(suu == 0):
        raise ValueError(f"{recordings[0].label}: the input has no energy at some swept frequencies")
    H_raw = syu / suu
    coh = np.abs(syu) ** 2 / np.maximum(suu * syy, np.finfo(float).tiny)
    H = smooth_complex(H_raw, smooth)
    coh = np.clip(boxcar(coh, smooth), 0.0, 1.0)
    f = f_all[sel]
    keep = (f >= lo_hz) & (f <= hi_hz)
    f, H, H_raw, coh = f[keep], H[keep], H_raw[keep], coh[keep]
    lsb = min(quantization_step(rec.signal(output)) for rec in recordings)
    amp = min(rec.sweep.amplitude_A for rec in recordings)
    resolvable = f[np.abs(H) * amp >= RESOLVABLE_LSB * lsb]
    hi_ok = float(resolvable[-1]) if lsb > 0 and resolvable.size else (float("inf") if lsb == 0 else float(f[0]))
    return Etfe(f, H, H_raw, coh, output, len(recordings), float(np.mean(grips)), label, hi_ok)


def quantization_step(y: np.ndarray) -> float:
    """The signal's quantization step: the smallest non-zero change between samples.

    Returns 0 when the signal does not look quantized (steps below 1e-9 of its range).
    """
    d = np.abs(np.diff(np.asarray(y, dtype=float)))
    d = d[d > 0]
    if d.size == 0:
        return 0.0
    step = float(d.min())
    span = float(np.ptp(y))
    return step if step > 1e-9 * span else 0.0
