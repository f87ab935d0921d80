"""Model inversion and filters of the HFAM build (eq. 4.6, section 4.2.2; docs/hfam_library.md).

A strictly proper model is made proper by added high-frequency zeros, its
Tustin response divided out on a long zero-padded DFT grid (the stable
two-sided inverse), then high-passed; :func:`forward_simulate` and
:func:`nrmse_corr` verify the result.
"""

from __future__ import annotations

import functools
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
    sos, kd = _forward_sos(*_zpk_key(model), float(fs_hz))
    if sos is None:
        return kd * np.asarray(current_A, float)
    return signal.sosfilt(sos.copy(), current_A)     # a writable copy: sosfilt's compiled loop wants one


def _zpk_key(model) -> tuple[bytes, bytes, float]:
    """A model's zeros, poles (complex, as bytes) and gain: what its filters depend on, as a cache key."""
    return (np.asarray(model.zeros_rad_s, complex).tobytes(), np.asarray(model.poles_rad_s, complex).tobytes(),
            float(model.gain))


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False      # shared by every call that hits the cache
    return a


# The builder and the refinement run the same few models (one per grip level) through forward_simulate and
# invert hundreds of times per library; the filter design (zpk2sos) and the model's frequency response cost more
# than the filtering itself. Both are pure functions of the model and the sizes: kept, so every call computes
# what it computed before, from the same numbers.
@functools.lru_cache(maxsize=64)
def _forward_sos(zeros: bytes, poles: bytes, gain: float, fs_hz: float):
    """The Tustin model's second-order sections (None if it has no poles) and its discrete gain."""
    zd, pd, kd = _discrete(np.frombuffer(zeros, complex), np.frombuffer(poles, complex), gain, fs_hz)
    if pd.size == 0:
        return None, kd
    return _read_only(signal.zpk2sos(zd, pd, kd)), kd


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
    n = accel_m_s2.size
    nfft, below_nyquist, weight, n_added = _inverse_weight(
        *_zpk_key(model), float(fs_hz), n, float(settings.added_zero_hz), float(settings.added_zero_zeta),
        float(settings.highpass_hz), bool(settings.zero_phase_added_zeros), bool(zero_phase_highpass))
    spectrum = sp_fft.rfft(accel_m_s2, nfft)
    spectrum[below_nyquist] *= weight
    spectrum[~below_nyquist] = 0.0
    return sp_fft.irfft(spectrum, nfft)[:n], n_added


@functools.lru_cache(maxsize=64)
def _inverse_weight(zeros: bytes, poles: bytes, gain: float, fs_hz: float, n: int, added_zero_hz: float,
                    added_zero_zeta: float, highpass_hz: float, zero_phase_added_zeros: bool,
                    zero_phase_highpass: bool):
    """What :func:`invert` multiplies the spectrum by: the DFT length, which bins lie below Nyquist, the
    weight there (high-pass over the proper model, Tikhonov-regularised) and the number of added zeros."""
    z0, p0 = np.frombuffer(zeros, complex), np.frombuffer(poles, complex)
    zp, _, kp, n_added = make_proper(z0, p0, gain, added_zero_hz, added_zero_zeta)
    nfft = sp_fft.next_fast_len(2 * n, real=True)
    f = sp_fft.rfftfreq(nfft, 1.0 / fs_hz)
    below_nyquist, s = _tustin_s(f, fs_hz)
    h = _zpk_response(zp, p0, kp, s)  # the proper model
    added = _zpk_response(zp[z0.size:], [], kp / gain, s)  # Z(s), unit DC gain
    highpass = _highpass(s, fs_hz, highpass_hz)
    if zero_phase_highpass:
        highpass = np.abs(highpass)  # offline, like the smoothing: no phase turn inside the band
    mag2 = (h * np.conj(h)).real
    if zero_phase_added_zeros:
        highpass = highpass * (added / np.maximum(np.abs(added), 1e-300))
    weight = highpass * np.conj(h) / (mag2 + 1e-12 * float(mag2.max()))
    return nfft, _read_only(below_nyquist), _read_only(weight), n_added


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


def sosfiltfilt(sos: np.ndarray, x: np.ndarray, padlen: int | None = None) -> np.ndarray:
    """``scipy.signal.sosfiltfilt(sos, x, padlen=padlen)`` (odd padding; ``None``: scipy's default length) with the
    filter's initial state worked out once per filter.

    scipy solves for the steady-state initial conditions (``sosfilt_zi``) on every call, which costs more than
    the filtering of a tap-long signal; the HFAM builder and refinement, and the demo's contact metrics, run the
    same few filters over thousands of signals. The steps are scipy's, on the same numbers, so the result is the
    same to the bit. Anything but a 1-D float64 signal and float64 sections, a ``padlen`` of 0, or a signal too
    short for the padding (scipy's error) goes to scipy itself.
    """
    x = np.asarray(x)
    sos = np.asarray(sos)
    if x.ndim != 1 or x.dtype != np.float64 or sos.ndim != 2 or sos.dtype != np.float64:
        return signal.sosfiltfilt(sos, x, padlen=padlen)
    zi, edge = _filtfilt_state(sos.tobytes(), sos.shape[0])
    if padlen is not None:
        edge = int(padlen)
    if not 0 < edge < x.shape[0]:
        return signal.sosfiltfilt(sos, x, padlen=padlen)
    # scipy's odd extension (scipy.signal._arraytools.odd_ext), then forwards and backwards from steady state
    ext = np.concatenate((2 * x[0:1] - x[edge:0:-1], x, 2 * x[-1:] - x[-2:-(edge + 2):-1]))
    y = signal.sosfilt(sos, ext, zi=zi * ext[0:1])[0]
    y = signal.sosfilt(sos, y[::-1], zi=zi * y[-1:])[0]
    return y[::-1][edge:-edge]


@functools.lru_cache(maxsize=64)
def _filtfilt_state(sos: bytes, n_sections: int) -> tuple[np.ndarray, int]:
    """For :func:`sosfiltfilt`: the sections' steady-state initial conditions and scipy's padding length."""
    s = np.frombuffer(sos, np.float64).reshape(n_sections, 6)
    ntaps = 2 * n_sections + 1 - min(int(np.sum(s[:, 2] == 0)), int(np.sum(s[:, 5] == 0)))
    return _read_only(signal.sosfilt_zi(s)), 3 * ntaps


def band_sos(fs_hz: float, band_hz: tuple[float, float], order: int = 4):
    """Butterworth band-pass (4th order for verification; the refinement uses the demo's 2nd); the upper
    edge is kept below 0.45 fs."""
    lo, hi = band_hz
    hi = min(hi, 0.45 * fs_hz)
    return signal.butter(order, [lo, hi], btype="bandpass", fs=fs_hz, output="sos")
