"""Model inversion and filters of the HFAM build (eq. 4.6, section 4.2.2; docs/hfam_library.md).

A strictly proper model is made proper by added high-frequency zeros, its
Tustin response divided out on a long zero-padded DFT grid (the stable
two-sided inverse), then high-passed; :func:`forward_simulate` and
:func:`nrmse_corr` verify the result.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import fft as sp_fft
from scipy import signal

from .settings import BuildSettings


# ---------------------------------------------------------------------------- models
def check_model(model, where: str, fs_hz: float) -> None:
    """Refuse models the builder cannot invert; errors name ``where`` (the file).

    Raises
    ------
    ValueError
        Unstable or marginal poles, more zeros than poles, output not
        acceleration, non-finite values, or a model sample rate (``fit.fs_hz``)
        different from the recording's, or a fitted band (``band_hz``) beyond the
        recording's Nyquist frequency.
    """
    z = np.asarray(model.zeros_rad_s, dtype=complex)
    p = np.asarray(model.poles_rad_s, dtype=complex)
    if not (np.all(np.isfinite(z)) and np.all(np.isfinite(p)) and math.isfinite(float(model.gain))):
        raise ValueError(f"{where}: model has non-finite zeros, poles or gain")
    if z.size > p.size:
        raise ValueError(f"{where}: improper model ({z.size} zeros > {p.size} poles) cannot be realised")
    if np.any(p.real >= 0):
        raise ValueError(f"{where}: unstable model (poles_rad_s with Re >= 0: {p[p.real >= 0].tolist()})")
    if float(model.gain) == 0.0:
        raise ValueError(f"{where}: model gain is zero; it cannot be inverted")
    output = getattr(model, "output", "accel_m_s2")
    if output != "accel_m_s2":
        raise ValueError(f"{where}: model output is {output!r}; the builder needs current -> 'accel_m_s2'")
    band = getattr(model, "band_hz", None)
    if band is not None and float(band[1]) > 0.5 * fs_hz * (1 + 1e-9):
        raise ValueError(f"{where}: model fitted up to {band[1]:g} Hz, above the Nyquist frequency "
                         f"{0.5 * fs_hz:g} Hz of the recording's {fs_hz:g} Hz sample rate; the sample rates differ")
    fit = getattr(model, "fit", {}) or {}
    model_fs = fit.get("fs_hz", fit.get("sample_rate_hz"))
    if isinstance(model_fs, (int, float)) and abs(float(model_fs) - fs_hz) > 1e-6 * fs_hz:
        raise ValueError(f"{where}: model identified at {model_fs} Hz but the recording is sampled at "
                         f"{fs_hz:.6g} Hz; record and identify at the same rate")


def make_proper(zeros_rad_s, poles_rad_s, gain: float, zero_hz: float, zeta: float):
    """Add high-frequency zeros so the model has relative degree zero (section 4.2.2).

    Pairs ``s^2 + 2 zeta w s + w^2`` (``w = 2 pi zero_hz``), plus a real zero at
    ``-w`` if the relative degree is odd, each normalised to unit DC gain so the
    model is unchanged at low frequency.

    Returns
    -------
    zeros, poles : ndarray of complex
    gain : float
    n_added : int
    """
    z = np.asarray(zeros_rad_s, dtype=complex)
    p = np.asarray(poles_rad_s, dtype=complex)
    r = p.size - z.size
    w = 2.0 * math.pi * zero_hz
    added = []
    k = float(gain)
    pair = np.roots([1.0, 2.0 * zeta * w, w * w])  # s^2 + 2 zeta w s + w^2
    for _ in range(r // 2):
        added += list(pair)
        k /= w * w
    if r % 2:
        added.append(-w + 0j)
        k /= w
    return np.concatenate([z, np.asarray(added, dtype=complex)]), p, k, r


def _discrete(zeros, poles, gain, fs_hz):
    zd, pd, kd = signal.bilinear_zpk(np.asarray(zeros, complex), np.asarray(poles, complex), gain, fs_hz)
    return np.asarray(zd, complex), np.asarray(pd, complex), float(np.real(kd))


def forward_simulate(model, current_A: np.ndarray, fs_hz: float) -> np.ndarray:
    """Handle acceleration of ``model`` (Tustin, pure delay discarded) for a current sequence.

    Parameters
    ----------
    model : ZpkModel-like (zeros_rad_s, poles_rad_s, gain)
    current_A : ndarray, shape (n,)
        Sample k at time k/fs_hz, starting from rest.

    Returns
    -------
    ndarray, shape (n,), in m/s^2.
    """
    zd, pd, kd = _discrete(model.zeros_rad_s, model.poles_rad_s, float(model.gain), fs_hz)
    if pd.size == 0:
        return kd * np.asarray(current_A, float)
    return signal.sosfilt(signal.zpk2sos(zd, pd, kd), current_A)


def _zpk_response(zeros, poles, gain, s: np.ndarray) -> np.ndarray:
    """gain * prod(s - z) / prod(s - p) evaluated at the complex frequencies ``s``."""
    out = np.full(s.shape, complex(gain))
    for z in np.asarray(zeros, complex):
        out *= s - z
    for p in np.asarray(poles, complex):
        out /= s - p
    return out


def invert(accel_m_s2: np.ndarray, model, fs_hz: float, settings: BuildSettings,
           zero_phase_highpass: bool = False) -> tuple[np.ndarray, int]:
    """Current (A) that makes ``model`` produce ``accel_m_s2`` (eq. 4.6), high-passed; non-causal, stable.

    The model's delay is discarded and it is made proper (:func:`make_proper`,
    relative degree zero). The division is done on a zero-padded DFT grid with
    the model's Tustin frequency response (continuous response at the warped
    frequency ``2 fs tan(pi f / fs)``, i.e. exactly the discrete model the
    forward simulation runs): this is the two-sided stable inverse, causal for
    left-half-plane zeros and anti-causal for right-half-plane zeros, so no
    output is unbounded. ``accel_m_s2`` must carry enough zero padding on both
    sides for those tails (the builder pads 0.1 s before and 0.2 s after).

    The added zeros act as a low-pass in the inverse (section 4.2.2); since
    the builder runs offline, that low-pass is applied zero-phase (only its
    magnitude ``1/|Z|``), as the smoothing is, so it adds no phase lag inside
    the band. The second-order Butterworth high-pass at
    ``settings.highpass_hz`` (Tustin, prewarped) is causal, or applied as its
    magnitude only with ``zero_phase_highpass`` (its causal phase turns the
    20-60 Hz part of a tap by 43-13 deg; ``BuildSettings.highpass_phase``); its s^2 cancels the
    double pole at s = 0 that the inverse of an acceleration model has either
    way. The zero-phase inverse is non-causal at low frequency: the builder
    keeps only what starts at impact (``build._current``). A tiny
    Tikhonov term (1e-12 of the peak |H|^2) keeps a zero on the unit circle
    finite.

    Returns
    -------
    current_A : ndarray, same shape as accel_m_s2
    n_added_zeros : int
    """
    z0 = np.asarray(model.zeros_rad_s, complex)
    p0 = np.asarray(model.poles_rad_s, complex)
    zp, _, kp, n_added = make_proper(z0, p0, float(model.gain), settings.added_zero_hz, settings.added_zero_zeta)
    n = accel_m_s2.size
    nfft = sp_fft.next_fast_len(2 * n, real=True)
    f = sp_fft.rfftfreq(nfft, 1.0 / fs_hz)
    below_nyquist, s = _tustin_s(f, fs_hz)
    h = _zpk_response(zp, p0, kp, s)  # the proper model
    added = _zpk_response(zp[z0.size:], [], kp / float(model.gain), s)  # Z(s), unit DC gain
    highpass = _highpass(s, fs_hz, settings.highpass_hz)
    if zero_phase_highpass:
        highpass = np.abs(highpass)  # offline, like the smoothing: no phase turn inside the band
    mag2 = (h * np.conj(h)).real
    if settings.zero_phase_added_zeros:
        highpass = highpass * (added / np.maximum(np.abs(added), 1e-300))
    weight = highpass * np.conj(h) / (mag2 + 1e-12 * float(mag2.max()))
    spectrum = sp_fft.rfft(accel_m_s2, nfft)
    spectrum[below_nyquist] *= weight
    spectrum[~below_nyquist] = 0.0
    return sp_fft.irfft(spectrum, nfft)[:n], n_added


def highpass_target(accel_m_s2: np.ndarray, fs_hz: float, highpass_hz: float, zero_phase: bool = False) -> np.ndarray:
    """The desired acceleration as the library intends it: the 2nd-order Butterworth high-pass of ``invert``.

    Causal (Tustin) by default; with ``zero_phase`` its magnitude only, applied on a zero-padded DFT grid
    (``BuildSettings.zero_phase_highpass``; the signal needs zero padding on both sides for its tails).
    """
    if not zero_phase:
        sos = signal.butter(2, highpass_hz, btype="highpass", fs=fs_hz, output="sos")
        return signal.sosfilt(sos, accel_m_s2)
    n = accel_m_s2.size
    nfft = sp_fft.next_fast_len(2 * n, real=True)
    f = sp_fft.rfftfreq(nfft, 1.0 / fs_hz)
    below, s = _tustin_s(f, fs_hz)
    magnitude = np.zeros(f.shape)           # 0 at and above Nyquist
    magnitude[below] = np.abs(_highpass(s, fs_hz, highpass_hz))
    return sp_fft.irfft(sp_fft.rfft(accel_m_s2, nfft) * magnitude, nfft)[:n]


def _tustin_s(f_hz: np.ndarray, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Which of ``f_hz`` lie below Nyquist, and the Tustin-warped ``s = 2 fs j tan(pi f / fs)`` there."""
    below = f_hz < 0.5 * fs_hz * (1.0 - 1e-9)
    return below, 2j * fs_hz * np.tan(np.pi * f_hz[below] / fs_hz)


def _highpass(s: np.ndarray, fs_hz: float, highpass_hz: float) -> np.ndarray:
    """The 2nd-order Butterworth high-pass at the warped ``s`` (Tustin, prewarped: the cut-off stays at
    ``highpass_hz``)."""
    w_hp = 2.0 * np.pi * highpass_hz
    w_hp = 2.0 * fs_hz * np.tan(w_hp / (2.0 * fs_hz))
    return s * s / (s * s + math.sqrt(2.0) * w_hp * s + w_hp * w_hp)


def nrmse_corr(y: np.ndarray, d: np.ndarray) -> tuple[float, float]:
    """Normalised RMS error ``rms(y - d)/rms(d)`` and Pearson correlation of two equal-length signals."""
    rd = float(np.sqrt(np.mean(d * d)))
    err = float(np.sqrt(np.mean((y - d) ** 2))) / rd if rd > 0 else float("inf")
    if np.std(y) == 0 or np.std(d) == 0:
        return err, 0.0
    return err, float(np.corrcoef(y, d)[0, 1])


def band_sos(fs_hz: float, band_hz: tuple[float, float], order: int = 4):
    """Butterworth band-pass (4th order for verification; the refinement uses the demo's 2nd); the upper
    edge is kept below 0.45 fs."""
    lo, hi = band_hz
    hi = min(hi, 0.45 * fs_hz)
    return signal.butter(order, [lo, hi], btype="bandpass", fs=fs_hz, output="sos")
