"""Contact-acceleration metrics for the virtual-wall demo (thesis sections 4.4.1 "Verification", 4.4.3, 4.5.5).

Plain vectorised functions on 1-D arrays sampled at ``fs_hz``. A *contact
window* is the handle acceleration from ``pre_s`` before impact to ``post_s``
after it, with the impact sample at index ``round(pre_s * fs_hz)``; every
trace compared with another is cut with the same template so samples line up.

How traces are aligned at impact: both the rendered and the reference trace
are cut at the servo tick on which the proxy first crossed the surface (the
renderer's contact event, detected from the quantized encoder for both
virtual and real taps). Encoder quantization makes that tick jitter by up to
a few ticks at low speeds (one count of the 2000-line encoder mapped to the
handle is ~8 um, i.e. ~0.16 ms at 0.05 m/s), so :func:`compare` then refines
the alignment by the lag (at most ``max_lag_s``, 0.5 ms by default) that
maximises the cross-correlation of the band-passed traces, and reports the
lag used.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import signal

from stimuli.hfam.inversion import sosfiltfilt

#: Band of human vibrotactile perception used for every comparison (section 4.4.1).
BAND_HZ = (20.0, 1000.0)


@lru_cache(maxsize=16)
def _band_sos(fs_hz: float, lo_hz: float, hi_hz: float, order: int) -> np.ndarray:
    nyq = 0.5 * fs_hz
    if not 0.0 < lo_hz < hi_hz:
        raise ValueError(f"band must satisfy 0 < lo < hi, got ({lo_hz}, {hi_hz}) Hz")
    if hi_hz >= nyq:
        # the upper edge is at or above Nyquist: only the high-pass side is meaningful

        return signal.butter(order, lo_hz, btype="highpass", fs=fs_hz, output="sos")

    return signal.butter(order, [lo_hz, hi_hz], btype="bandpass", fs=fs_hz, output="sos")


def bandpass(x: np.ndarray, fs_hz: float, band_hz: tuple[float, float] = BAND_HZ, order: int = 2) -> np.ndarray:
    """Zero-phase Butterworth band-pass (``scipy.signal.sosfiltfilt``).

    Parameters
    ----------
    x : ndarray, shape (..., n)
        Signal(s) sampled at ``fs_hz`` along the last axis.
    fs_hz : float
        Sample rate in Hz.
    band_hz : (float, float)
        Pass band in Hz; an upper edge at or above Nyquist gives a high-pass.
    order : int
        Butterworth order of each edge; filtfilt doubles the effective order.

    Returns
    -------
    ndarray, same shape as ``x``.
    """
    x = np.asarray(x, dtype=float)
    sos = _band_sos(float(fs_hz), float(band_hz[0]), float(band_hz[1]), int(order))
    padlen = max(min(3 * (2 * len(sos) + 1), x.shape[-1] - 1), 0)
    if x.ndim != 1:
        return signal.sosfiltfilt(sos, x, axis=-1, padlen=padlen)
    # one contact window at a time: scipy's steps with the filter's steady state worked out once per filter
    return sosfiltfilt(sos, x, padlen=padlen)


def nrmse(x: np.ndarray, ref: np.ndarray) -> float:
    """Normalized RMS error ``rms(x - ref) / rms(ref)`` (0 is perfect, 1 is as bad as silence)."""
    x = np.asarray(x, dtype=float)
    ref = np.asarray(ref, dtype=float)
    den = np.sqrt(np.mean(ref * ref))
    if den == 0.0:
        return float("nan")
    return float(np.sqrt(np.mean((x - ref) ** 2)) / den)


def correlation(x: np.ndarray, ref: np.ndarray) -> float:
    """Pearson correlation coefficient of two equal-length traces (nan if either is constant)."""
    x = np.asarray(x, dtype=float) - np.mean(x)
    ref = np.asarray(ref, dtype=float) - np.mean(ref)
    den = np.sqrt(np.sum(x * x) * np.sum(ref * ref))
    if den == 0.0:
        return float("nan")
    return float(np.sum(x * ref) / den)


def dominant_frequency(x: np.ndarray, fs_hz: float, band_hz: tuple[float, float] = BAND_HZ,
                       nfft: int = 8192) -> float:
    """Frequency (Hz) of the largest spectral peak of a contact transient inside ``band_hz``.

    The trace (typically the first 100 ms after impact) is mean-removed,
    Hann-windowed and zero-padded to ``nfft`` points (~1.2 Hz bins at 10 kHz)
    before its periodogram is taken. The Hann window keeps the low-frequency
    deceleration ramp of a soft wall from leaking over the band edge.
    """
    x = np.asarray(x, dtype=float)
    if x.size < 8:
        raise ValueError(f"dominant_frequency needs at least 8 samples, got {x.size}")

    f, pxx = signal.periodogram(x, fs=fs_hz, window="hann", nfft=max(nfft, x.size), detrend="constant")
    inside = (f >= band_hz[0]) & (f <= band_hz[1])
    if not inside.any() or not np.any(pxx[inside] > 0):
        return float("nan")
    return float(f[inside][np.argmax(pxx[inside])])


def peak_abs(x: np.ndarray) -> float:
    """Largest absolute value of a trace (e.g. peak handle acceleration in m/s^2)."""
    x = np.asarray(x, dtype=float)
    return float(np.max(np.abs(x))) if x.size else float("nan")


def cut_window(t_s: np.ndarray, x: np.ndarray, t_impact_s: float, fs_hz: float,
               pre_s: float = 0.01, post_s: float = 0.1) -> np.ndarray:
    """Cut ``x`` from ``pre_s`` before to ``post_s`` after the sample nearest ``t_impact_s``.

    Parameters
    ----------
    t_s, x : ndarray, shape (n,)
        Uniformly sampled time (s) and signal.
    t_impact_s : float
        Impact time (s), on the same clock as ``t_s``.
    fs_hz : float
        Sample rate (Hz) of ``t_s``.

    Returns
    -------
    ndarray, shape (round(pre_s*fs) + round(post_s*fs),)
        Samples outside ``x`` are filled by repeating its end values, so a tap
        close to the end of a run still yields a full window.
    """
    n_pre = int(round(pre_s * fs_hz))
    n_post = int(round(post_s * fs_hz))
    i0 = int(np.searchsorted(t_s, t_impact_s - 0.5 / fs_hz))
    idx = np.clip(np.arange(i0 - n_pre, i0 + n_post), 0, len(x) - 1)
    return np.asarray(x, dtype=float)[idx]


def window_from_recording(t_rel_s: np.ndarray, accel: np.ndarray, fs_hz: float,
                          pre_s: float = 0.01, post_s: float = 0.1) -> np.ndarray:
    """Put a recorded tap (``t_rel_s`` relative to impact) on the contact-window template.

    Samples before the recording starts are zero (the recording starts just
    before impact, when the handle is in free flight), samples after its end
    are zero too (the 100 ms recording has decayed by then).
    """
    n_pre = int(round(pre_s * fs_hz))
    n_post = int(round(post_s * fs_hz))
    out = np.zeros(n_pre + n_post)
    k = np.rint(np.asarray(t_rel_s, dtype=float) * fs_hz).astype(int) + n_pre
    ok = (k >= 0) & (k < out.size)
    out[k[ok]] = np.asarray(accel, dtype=float)[ok]
    return out


@dataclass(frozen=True)
class Comparison:
    """Result of :func:`compare` (all over ``BAND_HZ``, on the post-impact part of the window)."""

    nrmse: float
    correlation: float
    lag_samples: int


def compare(x_win: np.ndarray, ref_win: np.ndarray, fs_hz: float, pre_s: float = 0.01,
            eval_s: float = 0.1, max_lag_s: float = 0.5e-3, band_hz: tuple[float, float] = BAND_HZ,
            min_lag_s: float | None = None, x_bp: np.ndarray | None = None,
            ref_bp: np.ndarray | None = None) -> Comparison:
    """Normalized RMS error and correlation of a contact window against a reference window.

    Both windows (same template: ``pre_s`` before impact) are band-passed
    over ``band_hz`` (zero-phase), shifted against each other by the lag of at
    most ``max_lag_s`` (rendered trace late) or ``-min_lag_s`` (early;
    default ``min_lag_s = -max_lag_s``) that maximises their cross-correlation
    (see module doc), and compared from impact to ``eval_s`` after it.

    Parameters
    ----------
    x_win, ref_win : ndarray, shape (n,)
        Rendered and reference acceleration windows (m/s^2).
    fs_hz : float
        Sample rate (Hz).
    x_bp, ref_bp : ndarray or None
        ``bandpass(x_win, fs_hz, band_hz)`` and ``bandpass(ref_win, fs_hz, band_hz)`` if the caller has them
        already (a reference compared with many taps, a window also measured by :func:`contact_metrics`).

    Returns
    -------
    Comparison
        ``nrmse`` = rms(x - ref)/rms(ref), ``correlation`` (Pearson), and the
        lag in samples (positive: the rendered trace was late).
    """
    x_bp = bandpass(x_win, fs_hz, band_hz) if x_bp is None else x_bp
    r_bp = bandpass(ref_win, fs_hz, band_hz) if ref_bp is None else ref_bp
    n_pre = int(round(pre_s * fs_hz))
    n_eval = min(int(round(eval_s * fs_hz)), len(r_bp) - n_pre)
    max_lag = max(int(round(max_lag_s * fs_hz)), 0)
    min_lag = -max_lag if min_lag_s is None else int(round(min_lag_s * fs_hz))
    min_lag = max(min(min_lag, max_lag), -n_pre)
    ref_seg = r_bp[n_pre:n_pre + n_eval]
    # zero-extend the rendered trace so late lags near the window end stay comparable
    x_bp = np.concatenate([x_bp, np.zeros(max_lag)])
    best = (-np.inf, 0)
    for lag in range(min_lag, max_lag + 1):
        lo = n_pre + lag
        seg = x_bp[lo:lo + n_eval]
        if seg.size < n_eval:
            continue
        c = float(np.dot(seg, ref_seg))
        if c > best[0]:
            best = (c, lag)
    lag = best[1]
    seg = x_bp[n_pre + lag:n_pre + lag + n_eval]
    return Comparison(nrmse(seg, ref_seg), correlation(seg, ref_seg), lag)


def contact_metrics(x_win: np.ndarray, fs_hz: float, pre_s: float = 0.01,
                    eval_s: float = 0.1, band_hz: tuple[float, float] = BAND_HZ,
                    x_bp: np.ndarray | None = None) -> tuple[float, float]:
    """Peak |acceleration| and dominant frequency of the contact transient in a window (``x_bp``: its
    ``bandpass(x_win, fs_hz, band_hz)`` if the caller has it already).

    Returns
    -------
    peak_m_s2 : float
        Largest |raw acceleration| (m/s^2) from impact to ``eval_s`` after it.
    dominant_hz : float
        :func:`dominant_frequency` of the band-passed window (filtered over
        the whole window, so the filter's edge transient stays before impact),
        from impact to ``eval_s`` after it.
    """
    n_pre = int(round(pre_s * fs_hz))
    n_eval = int(round(eval_s * fs_hz))
    x = np.asarray(x_win, dtype=float)
    post = x[n_pre:n_pre + n_eval]
    post_bp = (bandpass(x, fs_hz, band_hz) if x_bp is None else x_bp)[n_pre:n_pre + n_eval]
    return peak_abs(post), dominant_frequency(post_bp, fs_hz, band_hz)
