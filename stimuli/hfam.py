"""HFAM transient library generation (thesis section 4.4.1, Figure 4.7).

Pipeline, per selected recorded tap and per device model (one per grip level):

1. **Selection**: drop taps with high pre-impact acceleration and atypical
   taps (low correlation with their velocity neighbours), then pick a nicely
   spaced subset over incoming velocity.
2. **Zero pre-padding** (and post-padding) so filters and the non-causal
   inverse have room.
3. **Zero-phase smoothing**: Butterworth low-pass run forwards and backwards
   (``scipy.signal.sosfiltfilt``), bandwidth <= 1 kHz.
4. **Model inversion** (eq. 4.6, section 4.2.2): the pure delay is discarded;
   a strictly proper model is made proper (relative degree zero) by added
   high-frequency zeros (pairs at ``added_zero_hz`` with damping
   ``added_zero_zeta``, normalised to unit DC gain), which act as a low-pass
   filter in the inverse (applied zero-phase, offline); the model's Tustin
   response (the discrete model the verification runs) is divided out on a
   long zero-padded DFT grid: the stable two-sided inverse (causal part for
   minimum-phase zeros, anti-causal part for right-half-plane zeros), so
   right-half-plane zeros never give an unbounded output.
5. **High-pass** second order (Butterworth, causal) near 10 Hz.
6. Padding removed (the current starts at the first servo sample after
   impact and realises the target delayed by ``onset_delay_s``), tail
   tapered to zero (half cosine), optional gain.
7. **Verification**: every current transient is run through its forward model
   (Tustin, no delay) and compared with the desired (smoothed, high-passed,
   delayed) acceleration over 20-1000 Hz (normalised RMS error and
   correlation); a transient above the device's peak current stops the build
   unless ``scale_to_limit``.

Details and the reasons for each choice: docs/hfam_library.md.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from scipy import fft as sp_fft
from scipy import signal

from devices import provenance

from .library import HfamLibrary
from .recordings import Tap

MAX_SMOOTH_HZ = 1000.0  # bandwidth of human vibrotactile perception (section 4.4.1)


@dataclass(frozen=True)
class BuildSettings:
    """Settings of the library builder (all in SI units).

    Attributes
    ----------
    n_velocities : int
        Number of velocities to pick (nicely spaced) from the usable taps.
    taps : tuple of int or None
        Explicit tap ids to use instead of the automatic selection.
    duration_s : float
        Transient length after impact (thesis: 100 ms).
    max_pre_impact_ratio : float
        Drop a tap whose peak |acceleration| before impact exceeds this
        fraction of its peak after impact ("high incoming acceleration").
    min_neighbour_corr : float
        Drop a tap whose median peak correlation with its (up to four) nearest
        neighbours in velocity is below this ("atypical").
    pre_pad_s, post_pad_s : float
        Zero padding before/after the recording during processing.
    smooth_hz : float
        Cut-off of the zero-phase Butterworth smoothing low-pass (<= 1000 Hz).
    smooth_order : int
        Its order (run twice by sosfiltfilt).
    added_zero_hz, added_zero_zeta : float
        Frequency and damping of the zeros added to make a strictly proper
        model proper (section 4.2.2: 800 Hz, 0.5).
    highpass_hz : float
        Cut-off of the second-order high-pass on the current (section 4.4.1: ~10 Hz).
    taper_s : float
        Length of the half-cosine taper at the end of each transient.
    onset_delay_s : float
        Constant delay accepted between impact and the realised acceleration,
        so the non-causal start of the current (zero-phase smoothing spreads
        the abrupt onset before t = 0, right-half-plane zeros need
        pre-actuation) is played rather than cut off; the thesis accepts the
        same few-sample delay from windowed smoothing (section 4.2.2). 0 cuts
        everything before impact.
    zero_phase_added_zeros : bool
        Apply the low-pass that the added zeros become in the inverse as its
        magnitude only (zero phase, offline) instead of causally (thesis, real
        time): no phase lag inside the band.
    gain : float
        Optional gain on all currents (section 4.4.1).
    verify_band_hz : (float, float)
        Band of the verification comparison (20-1000 Hz).
    peak_current_A : float or None
        Device peak current limit; None skips the check.
    scale_to_limit : bool
        Scale a transient above ``peak_current_A`` down to it (and say so)
        instead of stopping.
    max_extrapolation : float
        Stored in the library: cap of v_in/v_max above the velocity range.
    """

    n_velocities: int = 8
    taps: tuple[int, ...] | None = None
    duration_s: float = 0.1
    max_pre_impact_ratio: float = 0.2
    min_neighbour_corr: float = 0.5
    pre_pad_s: float = 0.1
    post_pad_s: float = 0.2
    smooth_hz: float = 500.0
    smooth_order: int = 4
    added_zero_hz: float = 800.0
    added_zero_zeta: float = 0.5
    highpass_hz: float = 10.0
    taper_s: float = 0.02
    onset_delay_s: float = 0.002
    zero_phase_added_zeros: bool = True
    gain: float = 1.0
    verify_band_hz: tuple[float, float] = (20.0, 1000.0)
    peak_current_A: float | None = None
    scale_to_limit: bool = False
    max_extrapolation: float = 1.5

    def __post_init__(self) -> None:
        def positive(key):
            value = getattr(self, key)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"BuildSettings.{key} must be a positive finite number, got {value!r}")

        for key in ("duration_s", "pre_pad_s", "post_pad_s", "smooth_hz", "added_zero_hz",
                    "added_zero_zeta", "highpass_hz", "max_pre_impact_ratio"):
            positive(key)
        if not (isinstance(self.n_velocities, int) and self.n_velocities >= 2):
            raise ValueError(f"BuildSettings.n_velocities must be an integer >= 2, got {self.n_velocities!r}")
        if self.smooth_hz > MAX_SMOOTH_HZ:
            raise ValueError(f"BuildSettings.smooth_hz={self.smooth_hz} exceeds {MAX_SMOOTH_HZ} Hz "
                             "(the bandwidth of human perception, section 4.4.1)")
        if not (isinstance(self.smooth_order, int) and 1 <= self.smooth_order <= 8):
            raise ValueError(f"BuildSettings.smooth_order must be an integer 1..8, got {self.smooth_order!r}")
        if not (0 <= self.onset_delay_s <= 0.01):
            raise ValueError(f"BuildSettings.onset_delay_s must be in [0, 0.01] s, got {self.onset_delay_s!r}")
        if not (0 <= self.taper_s < self.duration_s):
            raise ValueError(f"BuildSettings.taper_s must be in [0, duration_s), got {self.taper_s!r}")
        if not (math.isfinite(self.gain) and self.gain > 0):
            raise ValueError(f"BuildSettings.gain must be > 0, got {self.gain!r}")
        if not (-1 <= self.min_neighbour_corr <= 1):
            raise ValueError(f"BuildSettings.min_neighbour_corr must be in [-1, 1], got {self.min_neighbour_corr!r}")
        lo, hi = self.verify_band_hz
        if not 0 < lo < hi:
            raise ValueError(f"BuildSettings.verify_band_hz must be (lo, hi) with 0 < lo < hi, got {self.verify_band_hz!r}")
        if self.peak_current_A is not None and not (math.isfinite(self.peak_current_A) and self.peak_current_A > 0):
            raise ValueError(f"BuildSettings.peak_current_A must be > 0, got {self.peak_current_A!r}")
        if self.max_extrapolation < 1:
            raise ValueError(f"BuildSettings.max_extrapolation must be >= 1, got {self.max_extrapolation!r}")


@dataclass
class Selection:
    """Result of tap selection: the chosen taps (increasing velocity) and the dropped ones with reasons."""

    selected: list[Tap]
    dropped: list[tuple[Tap, str]] = field(default_factory=list)


@dataclass
class BuildReport:
    """What the builder did, for printing and for the library metadata."""

    selection: Selection
    verification: list[dict]
    scaled: list[str]
    model_notes: list[str]
    elapsed_s: float = 0.0


# ---------------------------------------------------------------------------- selection
def _post_impact(tap: Tap, n: int) -> np.ndarray:
    a = tap.accel_m_s2[tap.t_s > 0]
    return a[:n]


def _peak_corr(x: np.ndarray, y: np.ndarray, max_lag: int) -> float:
    """Largest normalised cross-correlation of x and y over lags |l| <= max_lag."""
    n = min(x.size, y.size)
    x = x[:n]
    y = y[:n]
    nx = np.linalg.norm(x)
    ny = np.linalg.norm(y)
    if nx == 0 or ny == 0:
        return 0.0
    best = -1.0
    for lag in range(-max_lag, max_lag + 1):
        if lag >= 0:
            c = float(np.dot(x[lag:], y[: n - lag]))
        else:
            c = float(np.dot(x[: n + lag], y[-lag:]))
        best = max(best, c)
    return best / (nx * ny)


def select_taps(taps: Sequence[Tap], fs_hz: float, settings: BuildSettings) -> Selection:
    """Choose a nicely spaced subset of usable taps over incoming velocity (section 4.4.1).

    Taps are dropped for (in this order): no acceleration after impact; high
    pre-impact acceleration (peak before impact > ``max_pre_impact_ratio`` of
    the peak after); being atypical (median peak correlation, within +/-0.5 ms
    of lag, with up to four neighbours in velocity below
    ``min_neighbour_corr``; needs >= 3 usable taps); a repeated velocity (the
    more typical one is kept); not being nearest to one of ``n_velocities``
    evenly spaced target velocities. With ``settings.taps`` the listed taps
    are used as they are (only the first two checks apply).

    Returns
    -------
    Selection
        ``selected`` in strictly increasing velocity.

    Raises
    ------
    ValueError
        If fewer than two distinct velocities survive, or a requested tap id is missing.
    """
    n_t = max(1, int(round(settings.duration_s * fs_hz)))
    dropped: list[tuple[Tap, str]] = []
    pool = list(taps)
    if settings.taps is not None:
        by_id = {tp.tap: tp for tp in pool}
        missing = [i for i in settings.taps if i not in by_id]
        if missing:
            raise ValueError(f"requested tap id(s) {missing} are not in the recording (ids {sorted(by_id)})")
        dropped = [(tp, "not in the requested --taps list") for tp in pool if tp.tap not in settings.taps]
        pool = [by_id[i] for i in settings.taps]
    usable = []
    for tp in pool:
        post = _post_impact(tp, n_t)
        pre = tp.accel_m_s2[tp.t_s <= 0]
        post_peak = float(np.max(np.abs(post))) if post.size else 0.0
        pre_peak = float(np.max(np.abs(pre))) if pre.size else 0.0
        if post_peak == 0.0:
            dropped.append((tp, "no acceleration after impact"))
        elif pre_peak > settings.max_pre_impact_ratio * post_peak:
            dropped.append((tp, f"high pre-impact acceleration: {pre_peak:.3g} m/s^2 is "
                                f"{100 * pre_peak / post_peak:.0f}% of the impact peak (limit "
                                f"{100 * settings.max_pre_impact_ratio:.0f}%)"))
        else:
            usable.append(tp)
    usable.sort(key=lambda tp: tp.v_in_m_s)
    corr = {id(tp): 1.0 for tp in usable}
    if len(usable) >= 3 and settings.taps is None:  # a hand-made selection is trusted as typical
        shapes = [_post_impact(tp, n_t) for tp in usable]
        max_lag = max(1, int(round(0.5e-3 * fs_hz)))
        typical = []
        for i, tp in enumerate(usable):
            neighbours = [j for j in range(max(0, i - 2), min(len(usable), i + 3)) if j != i]
            c = float(np.median([_peak_corr(shapes[i], shapes[j], max_lag) for j in neighbours]))
            corr[id(tp)] = c
            if c < settings.min_neighbour_corr:
                dropped.append((tp, f"atypical: correlation {c:.2f} with its velocity neighbours "
                                    f"(min {settings.min_neighbour_corr:.2f})"))
            else:
                typical.append(tp)
        usable = typical
    # one tap per velocity: keep the most typical
    unique: dict[float, Tap] = {}
    for tp in usable:
        other = unique.get(tp.v_in_m_s)
        if other is None:
            unique[tp.v_in_m_s] = tp
        else:
            keep, drop = (tp, other) if corr[id(tp)] > corr[id(other)] else (other, tp)
            unique[tp.v_in_m_s] = keep
            dropped.append((drop, f"same velocity as tap {keep.tap} (kept the more typical one)"))
    candidates = sorted(unique.values(), key=lambda tp: tp.v_in_m_s)
    if settings.taps is None and len(candidates) > settings.n_velocities:
        targets = np.linspace(candidates[0].v_in_m_s, candidates[-1].v_in_m_s, settings.n_velocities)
        chosen: list[Tap] = []
        free = list(candidates)
        for target in targets:
            best = min(free, key=lambda tp: abs(tp.v_in_m_s - target))
            chosen.append(best)
            free.remove(best)
        for tp in free:
            dropped.append((tp, f"not needed for {settings.n_velocities} evenly spaced velocities"))
        candidates = sorted(chosen, key=lambda tp: tp.v_in_m_s)
    if len(candidates) < 2:
        reasons = "; ".join(f"tap {tp.tap} ({tp.v_in_m_s} m/s): {why}" for tp, why in dropped) or "none dropped"
        raise ValueError(f"fewer than two distinct incoming velocities left after selection ({reasons})")
    return Selection(candidates, dropped)


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


def invert(accel_m_s2: np.ndarray, model, fs_hz: float, settings: BuildSettings) -> tuple[np.ndarray, int]:
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
    ``settings.highpass_hz`` is causal (Tustin), which keeps the inverse of
    an acceleration model (zeros at s = 0) causal at low frequency. A tiny
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
    below_nyquist = f < 0.5 * fs_hz * (1.0 - 1e-9)
    s = 2j * fs_hz * np.tan(np.pi * f[below_nyquist] / fs_hz)  # Tustin frequency warping
    h = _zpk_response(zp, p0, kp, s)  # the proper model
    added = _zpk_response(zp[z0.size:], [], kp / float(model.gain), s)  # Z(s), unit DC gain
    w_hp = 2.0 * np.pi * settings.highpass_hz
    w_hp = 2.0 * fs_hz * np.tan(w_hp / (2.0 * fs_hz))  # prewarped so the cut-off stays at highpass_hz
    highpass = s * s / (s * s + math.sqrt(2.0) * w_hp * s + w_hp * w_hp)
    mag2 = (h * np.conj(h)).real
    if settings.zero_phase_added_zeros:
        highpass = highpass * (added / np.maximum(np.abs(added), 1e-300))
    weight = highpass * np.conj(h) / (mag2 + 1e-12 * float(mag2.max()))
    spectrum = sp_fft.rfft(accel_m_s2, nfft)
    spectrum[below_nyquist] *= weight
    spectrum[~below_nyquist] = 0.0
    return sp_fft.irfft(spectrum, nfft)[:n], n_added


def highpass_target(accel_m_s2: np.ndarray, fs_hz: float, highpass_hz: float) -> np.ndarray:
    """The desired acceleration as the library intends it: the causal 2nd-order Butterworth high-pass of ``invert``."""
    sos = signal.butter(2, highpass_hz, btype="highpass", fs=fs_hz, output="sos")
    return signal.sosfilt(sos, accel_m_s2)


def nrmse_corr(y: np.ndarray, d: np.ndarray) -> tuple[float, float]:
    """Normalised RMS error ``rms(y - d)/rms(d)`` and Pearson correlation of two equal-length signals."""
    rd = float(np.sqrt(np.mean(d * d)))
    err = float(np.sqrt(np.mean((y - d) ** 2))) / rd if rd > 0 else float("inf")
    if np.std(y) == 0 or np.std(d) == 0:
        return err, 0.0
    return err, float(np.corrcoef(y, d)[0, 1])


def band_sos(fs_hz: float, band_hz: tuple[float, float]):
    """4th-order Butterworth band-pass for verification; the upper edge is kept below 0.45 fs."""
    lo, hi = band_hz
    hi = min(hi, 0.45 * fs_hz)
    return signal.butter(4, [lo, hi], btype="bandpass", fs=fs_hz, output="sos")


# ---------------------------------------------------------------------------- builder
def build_library(
    taps: Sequence[Tap],
    fs_hz: float,
    models: Sequence[tuple[str, object]],
    settings: BuildSettings = BuildSettings(),
    *,
    force_per_amp_N_A: float,
    log: Callable[[str], None] | None = None,
    provenance: dict | None = None,
) -> tuple[HfamLibrary, BuildReport]:
    """Build an HFAM current library from recorded taps and per-grip device models (section 4.4.1).

    Parameters
    ----------
    taps : sequence of Tap
        Recorded impacts (see ``stimuli.recordings``), all sampled at ``fs_hz``.
    fs_hz : float
        Sample rate of the recordings = servo rate the library is for.
    models : sequence of (name, model)
        Current -> handle acceleration models (``devices.model.ZpkModel``), one
        per grip level (``model.grip_N``); ``name`` (usually the file) is used
        in messages.
    settings : BuildSettings
    force_per_amp_N_A : float
        Force constant of the device (stored with the library).
    log : callable(str) or None
        Progress output.
    provenance : dict or None
        Extra metadata (source files, command line) stored in the library.

    Returns
    -------
    library : HfamLibrary
        currents [n_v, n_g, n_t] in A, with desired accelerations and metadata.
    report : BuildReport

    Raises
    ------
    ValueError
        Bad models (named), no usable taps, sample rate problems, or a
        transient above ``settings.peak_current_A`` (naming velocity and
        grip) when ``scale_to_limit`` is False.
    """
    t_start = time.perf_counter()
    say = log or (lambda msg: None)
    fs_hz = float(fs_hz)
    if not (math.isfinite(fs_hz) and fs_hz > 0):
        raise ValueError(f"sample rate must be positive, got {fs_hz!r}")
    if settings.smooth_hz >= fs_hz / 2:
        raise ValueError(f"smooth_hz={settings.smooth_hz} must be below the Nyquist frequency {fs_hz / 2} Hz")
    if settings.added_zero_hz >= fs_hz / 2:
        raise ValueError(f"added_zero_hz={settings.added_zero_hz} must be below the Nyquist frequency {fs_hz / 2} Hz")
    if not models:
        raise ValueError("at least one device model is needed")
    for name, model in models:
        check_model(model, name, fs_hz)
    grips = _grip_levels(models)
    order = np.argsort(grips)
    models = [models[i] for i in order]
    grips = [grips[i] for i in order]

    selection = select_taps(taps, fs_hz, settings)
    for tp, why in selection.dropped:
        say(f"  dropped tap {tp.tap} ({tp.v_in_m_s:.4g} m/s): {why}")
    velocities = [tp.v_in_m_s for tp in selection.selected]
    say(f"selected {len(velocities)} taps: " + ", ".join(f"{tp.tap} ({tp.v_in_m_s:.4g} m/s)" for tp in selection.selected))

    n_t = int(round(settings.duration_s * fs_hz))
    available = min(int(np.count_nonzero(tp.t_s > 0)) for tp in selection.selected)
    if available < n_t:
        say(f"  note: recordings hold only {available} samples after impact; transients are {available / fs_hz * 1e3:.1f} ms")
        n_t = available
    pre = int(round(settings.pre_pad_s * fs_hz))
    post = int(round(settings.post_pad_s * fs_hz))
    n_pad = pre + n_t + 1 + post
    t_grid = (np.arange(n_pad) - pre) / fs_hz  # index pre is t = 0
    window = slice(pre + 1, pre + 1 + n_t)  # samples at t = (k+1)/fs, k = 0..n_t-1
    lead = int(round(settings.onset_delay_s * fs_hz))
    # the current for physical sample t = (k+1)/fs is the inverse at t - onset delay
    source = slice(pre + 1 - lead, pre + 1 - lead + n_t)
    smooth = signal.butter(settings.smooth_order, settings.smooth_hz, fs=fs_hz, output="sos")
    verify = band_sos(fs_hz, settings.verify_band_hz)
    taper = np.ones(n_t)
    n_taper = int(round(settings.taper_s * fs_hz))
    if n_taper > 0:
        taper[n_t - n_taper:] = 0.5 * (1.0 + np.cos(np.pi * np.arange(1, n_taper + 1) / n_taper))

    model_notes = []
    for name, model in models:
        r = len(model.poles_rad_s) - len(model.zeros_rad_s)
        n_rhp = int(np.count_nonzero(np.asarray(model.zeros_rad_s).real > 0))
        parts = []
        if r:
            parts.append(f"added {r} zero(s) at {settings.added_zero_hz:g} Hz, zeta {settings.added_zero_zeta:g}")
        if float(getattr(model, "delay_s", 0.0)):
            parts.append(f"discarded delay {model.delay_s * 1e3:.3g} ms")
        if n_rhp:
            parts.append(f"{n_rhp} right-half-plane zero(s): non-causal stable inversion")
        note = f"model {name} (grip {model.grip_N} N): " + ("; ".join(parts) or "proper, minimum phase, no delay")
        model_notes.append(note)
        say("  " + note)

    currents = np.zeros((len(velocities), len(models), n_t))
    desired = np.zeros((len(velocities), n_t))
    verification = []
    scaled = []
    limit = settings.peak_current_A
    for i, tp in enumerate(selection.selected):
        target = np.interp(t_grid, tp.t_s, tp.accel_m_s2, left=0.0, right=0.0)
        target_s = signal.sosfiltfilt(smooth, target) * settings.gain
        desired[i] = target_s[source]
        d_band = signal.sosfiltfilt(verify, highpass_target(target_s, fs_hz, settings.highpass_hz))[source]
        for j, (name, model) in enumerate(models):
            raw, _ = invert(target_s, model, fs_hz, settings)
            cur = raw[source] * taper
            peak = float(np.max(np.abs(cur)))
            factor = 1.0
            if limit is not None and peak > limit:
                where = f"velocity {tp.v_in_m_s:.4g} m/s, grip {grips[j]:g} N (model {name})"
                if not settings.scale_to_limit:
                    raise ValueError(f"transient at {where} needs {peak:.3f} A, above the device peak limit "
                                     f"{limit:g} A; lower --gain, or use --scale-to-limit")
                factor = limit / peak
                cur = cur * factor
                msg = f"scaled transient at {where} by {factor:.3f} (peak {peak:.3f} A -> {limit:g} A)"
                scaled.append(msg)
                say("  " + msg)
            currents[i, j] = cur
            u = np.zeros(n_pad)
            u[window] = cur
            y = forward_simulate(model, u, fs_hz)
            y_band = signal.sosfiltfilt(verify, y)[window]
            err, cc = nrmse_corr(y_band, d_band)
            verification.append({"v_in_m_s": tp.v_in_m_s, "grip_N": grips[j], "tap": tp.tap,
                                 "peak_A": float(np.max(np.abs(cur))), "nrmse": err, "corr": cc,
                                 "scale": factor})
        say(f"  built velocity {i + 1}/{len(velocities)}: {tp.v_in_m_s:.4g} m/s x {len(models)} grip level(s)")

    elapsed = time.perf_counter() - t_start
    report = BuildReport(selection, verification, scaled, model_notes, elapsed)
    metadata = {
        "software_version": _software_version(),
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "settings": _settings_dict(settings),
        "models": [_model_dict(name, model) for name, model in models],
        "selection": {
            "selected": [{"tap": tp.tap, "v_in_m_s": tp.v_in_m_s} for tp in selection.selected],
            "dropped": [{"tap": tp.tap, "v_in_m_s": tp.v_in_m_s, "reason": why} for tp, why in selection.dropped],
        },
        "model_notes": model_notes,
        "scaled": scaled,
        "verification": verification,
    }
    metadata.update(provenance or {})
    library = HfamLibrary(velocities, grips, currents, fs_hz, force_per_amp_N_A,
                          max_extrapolation=settings.max_extrapolation, metadata=metadata,
                          desired_accel_m_s2=desired, source="built library")
    return library, report


def format_verification(report: BuildReport, band_hz=(20.0, 1000.0)) -> str:
    """The verification table: one row per (velocity, grip) with peak current, NRMSE and correlation."""
    lines = [f"verification through the forward models, {band_hz[0]:g}-{band_hz[1]:g} Hz:",
             f"{'v_in m/s':>9} {'grip N':>7} {'tap':>5} {'peak A':>8} {'NRMSE':>7} {'corr':>6}  note"]
    for row in report.verification:
        note = f"scaled x{row['scale']:.3f}" if row["scale"] != 1.0 else ""
        lines.append(f"{row['v_in_m_s']:>9.4g} {row['grip_N']:>7.3g} {row['tap']:>5} {row['peak_A']:>8.3f} "
                     f"{row['nrmse']:>7.3f} {row['corr']:>6.3f}  {note}")
    worst = max(report.verification, key=lambda r: r["nrmse"])
    lines.append(f"worst NRMSE {worst['nrmse']:.3f} at {worst['v_in_m_s']:.4g} m/s, grip {worst['grip_N']:g} N; "
                 f"built in {report.elapsed_s * 1e3:.0f} ms")
    return "\n".join(lines)


def _grip_levels(models) -> list[float]:
    grips = [getattr(m, "grip_N", None) for _, m in models]
    if len(models) == 1:
        return [float(grips[0]) if grips[0] is not None else 0.0]
    for (name, _), g in zip(models, grips):
        if g is None:
            raise ValueError(f"{name}: model has no grip_N; with several models each must name its grip level")
    if len(set(grips)) != len(grips):
        raise ValueError(f"models have repeated grip levels {grips}; one model per grip level")
    return [float(g) for g in grips]


def _settings_dict(settings: BuildSettings) -> dict:
    d = asdict(settings)
    d["verify_band_hz"] = list(settings.verify_band_hz)
    d["taps"] = list(settings.taps) if settings.taps is not None else None
    return d


def _model_dict(name: str, model) -> dict:
    if hasattr(model, "to_dict"):
        d = model.to_dict()
    else:
        d = {"zeros_rad_s": [[float(v.real), float(v.imag)] for v in np.asarray(model.zeros_rad_s, complex)],
             "poles_rad_s": [[float(v.real), float(v.imag)] for v in np.asarray(model.poles_rad_s, complex)],
             "gain": float(model.gain), "delay_s": float(getattr(model, "delay_s", 0.0)),
             "grip_N": getattr(model, "grip_N", None)}
    d["name"] = str(name)
    return d


def _software_version() -> str:
    return provenance.version_line()


def file_digest(path) -> str:
    """sha256 of a file, for provenance."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 16), b""):
            h.update(chunk)
    return h.hexdigest()


def source_entry(path) -> dict:
    p = Path(path)
    return {"path": str(p), "sha256": file_digest(p)}
