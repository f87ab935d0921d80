"""Synthetic rater for sim sessions: ratings 1-7 from contact features.

THIS TESTS THE PIPELINE; IT IS NOT A MODEL OF HUMAN PERCEPTION. It exists so a
simulated session produces ratings that depend on what the device actually did
(so analysis code sees structure, and a broken renderer shows up as changed
ratings), nothing more. Its weights are arbitrary choices, documented in
docs/study.md.

The reference is the thesis's: the participants "were asked to rate, on an scale from one to seven, how well
each sample represented the experience of tapping on the real piece of wood" (section 4.5.3), after tapping "on
the real wooden sample to become familiar with its response" -- the *real wood* (:data:`REFERENCE_SAMPLE`), not
the wood on foam the transients were tuned to (section 4.5.2). The inputs are the criteria the subjects named
(section 4.5.5): "First among these was whether the stylus came to a sudden stop after contact", then "the
presence of a high-frequency transient at the moment of contact".

Features per tap (100 ms after each impact, handle acceleration band-passed
20-1000 Hz, the band of section 4.4):

* amplitude ratio ``r_a = rms / rms_ref(v)`` and spectral-centroid ratio
  ``r_f = centroid / centroid_ref`` against the real wood reference at the
  same incoming velocity (power-law fit ``rms_ref = a v^b`` over reference
  taps);
* ``similarity = exp(-|ln r_a| / ln 3) * exp(-|ln r_f| / ln 2)``;
* penetration term ``exp(-penetration / 3 mm)`` (the sudden stop: soft surfaces feel less like wood);
* transient present: ``r_a > 0.2``.

Latent realism ``1 + 6 (0.55 similarity + 0.25 penetration + 0.20 transient)``
plus a per-subject bias and per-rating Gaussian noise whose SD depends on
experience (novices noisier, section 4.5.5), rounded and clipped to 1..7.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

#: the sample the rater compares with: the real wood the subjects were asked about (section 4.5.3)
REFERENCE_SAMPLE = "wood"
BAND_HZ = (20.0, 1000.0)
WINDOW_S = 0.1
NOISE_SD = {"none": 1.0, "few": 0.6, "regular": 0.35}


def _scipy_signal():
    """:mod:`scipy.signal`, loaded on first use: only a simulated participant's ratings need it, and a lab's keyboard
    session and its servo process start without it."""
    from scipy import signal  # deferred: 1.0 s of CPU to import

    return signal


@functools.lru_cache(maxsize=4)
def _band_sos(fs_hz: float) -> np.ndarray:
    """The features' band-pass (2nd-order Butterworth, :data:`BAND_HZ`, at most 0.45 ``fs_hz``) as second-order
    sections; designed once per rate (every attempt's taps use it). The cached array is shared: callers take a
    copy (scipy's ``sosfilt`` wants a writable one)."""
    signal = _scipy_signal()
    nyq = 0.5 * fs_hz
    hi = min(BAND_HZ[1], 0.45 * fs_hz)
    sos = signal.butter(2, [BAND_HZ[0] / nyq, hi / nyq], btype="bandpass", output="sos")
    return sos


def tap_features(t_s: np.ndarray, accel_m_s2: np.ndarray, impact_times_s, fs_hz: float) -> np.ndarray:
    """HF RMS (m/s^2) and spectral centroid (Hz) of the 100 ms after each impact.

    Parameters
    ----------
    t_s, accel_m_s2 : ndarray, shape (n,)
        Full-rate time and handle acceleration.
    impact_times_s : sequence of float
        Impact times on the same clock.
    fs_hz : float

    Returns
    -------
    ndarray, shape (n_impacts, 2)
        Columns: rms, centroid; NaN for an impact whose window is incomplete.
    """
    signal = _scipy_signal()
    hi = min(BAND_HZ[1], 0.45 * fs_hz)
    sos = _band_sos(float(fs_hz)).copy()
    n_win = int(round(WINDOW_S * fs_hz))
    out = np.full((len(impact_times_s), 2), np.nan)
    if len(t_s) == 0:
        return out
    starts = np.searchsorted(t_s, np.asarray(impact_times_s, float))
    pre = int(0.02 * fs_hz)  # filter warm-up before the impact
    freqs = np.fft.rfftfreq(n_win, 1.0 / fs_hz)
    band = (freqs >= BAND_HZ[0]) & (freqs <= hi)
    for k, s in enumerate(starts):
        a = s - pre
        b = s + n_win
        if a < 0 or b > len(accel_m_s2):
            continue
        seg = accel_m_s2[a:b] - accel_m_s2[a]
        y = signal.sosfilt(sos, seg)[pre:]
        rms = float(np.sqrt(np.mean(y * y)))
        p = np.abs(np.fft.rfft(y * np.hanning(n_win))) ** 2
        total = p[band].sum()
        centroid = float((freqs[band] * p[band]).sum() / total) if total > 0 else float("nan")
        out[k] = rms, centroid
    return out


@dataclass(frozen=True)
class Reference:
    """The real reference sample's taps (:data:`REFERENCE_SAMPLE`): rms = a * v**b, centroid constant (Hz)."""

    a: float
    b: float
    centroid_hz: float
    n_taps: int

    @classmethod
    def fit(cls, velocities_m_s, features: np.ndarray) -> "Reference":
        """Fit the reference from real-sample taps: log RMS linear in log velocity, centroid their median.

        Parameters
        ----------
        velocities_m_s : array, shape (n,)
            Incoming velocities of the taps (m/s).
        features : ndarray, shape (n, 2)
            Per tap: high-pass acceleration RMS (m/s^2) and spectral centroid (Hz) (:func:`tap_features`).

        Raises
        ------
        ValueError
            Fewer than 2 usable taps.
        """
        v = np.asarray(velocities_m_s, float)
        ok = np.isfinite(features).all(axis=1) & (v > 0) & (features[:, 0] > 0)
        if ok.sum() < 2:
            raise ValueError("synthetic rater: fewer than 2 usable taps on the reference sample")
        b, log_a = np.polyfit(np.log(v[ok]), np.log(features[ok, 0]), 1)
        return cls(a=float(math.exp(log_a)), b=float(b), centroid_hz=float(np.median(features[ok, 1])),
                   n_taps=int(ok.sum()))

    def rms(self, v_m_s: float) -> float:
        """The reference's acceleration RMS (m/s^2) at incoming velocity ``v_m_s`` (m/s; at least 1 mm/s)."""
        return self.a * max(v_m_s, 1e-3) ** self.b


@dataclass(frozen=True)
class RaterProfile:
    """Per-subject rating tendencies: additive bias and noise SD (rating points)."""

    bias: float
    noise_sd: float

    @classmethod
    def for_subject(cls, experience: str, rng: np.random.Generator) -> "RaterProfile":
        """A subject's profile: bias drawn from N(0, 0.4) rating points, noise SD by ``experience``."""
        if experience not in NOISE_SD:
            raise ValueError(f"experience must be one of {list(NOISE_SD)}, got {experience!r}")
        return cls(bias=float(rng.normal(0.0, 0.4)), noise_sd=NOISE_SD[experience])


def realism_score(features: np.ndarray, velocities_m_s, penetrations_m, reference: Reference) -> dict:
    """Noise-free latent realism (1..7) and its parts for one attempt (see module doc)."""
    v = np.asarray(velocities_m_s, float)
    pen = np.asarray(penetrations_m, float)
    n = min(len(v), len(features))
    sims, present = [], []
    for k in range(n):
        rms, centroid = features[k]
        if not (math.isfinite(rms) and math.isfinite(v[k])):
            continue
        ra = max(rms, 1e-9) / reference.rms(v[k])
        rf = centroid / reference.centroid_hz if math.isfinite(centroid) and centroid > 0 else 1e-3
        sims.append(math.exp(-abs(math.log(ra)) / math.log(3.0)) * math.exp(-abs(math.log(rf)) / math.log(2.0)))
        present.append(ra > 0.2)
    similarity = float(np.mean(sims)) if sims else 0.0
    transient = float(np.mean(present)) if present else 0.0
    pen_mean = float(np.nanmean(pen)) if len(pen) else 0.0
    pen_term = math.exp(-max(pen_mean, 0.0) / 0.003)
    latent = 1.0 + 6.0 * (0.55 * similarity + 0.25 * pen_term + 0.20 * transient)
    return {"latent": latent, "similarity": similarity, "penetration_term": pen_term, "transient": transient}


def rate(score: dict, profile: RaterProfile, rng: np.random.Generator) -> int:
    """Integer rating 1..7 from a latent score with subject bias and noise."""
    value = score["latent"] + profile.bias + rng.normal(0.0, profile.noise_sd)
    return int(min(7, max(1, round(value))))
