"""The simulated participant's forced-choice judgments, from what the sim device actually rendered.

THIS TESTS THE PIPELINE AND PLANS STUDIES; IT IS NOT A VALIDATED MODEL OF HUMAN PERCEPTION. It makes a
simulated psychophysics session answer from the taps the device rendered, so that a renderer that renders the
wrong stiffness or no transient shows up in the psychometric data, with perceptual noise of the published size.

Per interval of a trial the participant forms one percept (its own taps, full-rate trace of the window):

* **Stiffness** (``discrimination``, ``vary = "stiffness_N_m"``): per tap, the force the device produced
  (``current_A * force_per_amp_N_A``, eq. 3.17) at the tap's deepest penetration, divided by that penetration;
  the median over the interval's taps, times Weber noise on force and on displacement (compliance):
  ``k_hat = k * exp(sigma_F e1 - sigma_x e2)``, ``e1, e2 ~ N(0, 1)``. The noise SDs come from the
  2-interval JNDs (75 % point, so ``ln(1 + JND) = z(0.75) sqrt(2) sigma``): force 7 % (Jones 1989, "Matching
  forces: constant errors and differential thresholds", Perception 18: 681-687; Pang, Tan & Durlach 1991,
  5-10 %), compliance 15 % (Tan, Durlach, Beauregard & Srinivasan 1995, "Manual discrimination of compliance
  using active pinch grasp: the roles of force and work cues", Perception & Psychophysics 57: 495-510;
  Jones & Hunter 1990, "A perceptual analysis of stiffness", Exp Brain Res 79: 150-156, found 23 % for
  stiffness). The stiffness Weber fraction they imply is :func:`stiffness_weber_fraction` (16.8 %).
* **Vibration strength** (``discrimination`` with a varied amplitude or gain, ``detection``): per tap the
  20-1000 Hz band-passed handle acceleration RMS of the 100 ms after the impact (:func:`study.session.rater.tap_features`)
  divided by the tap's incoming velocity (the contact's own vibration and every transient of eqs. 4.7/4.8
  scale with it, so taps at different speeds compare), the median over the interval's taps, times
  ``exp(sigma_V e)`` with ``sigma_V`` from the vibrotactile amplitude JND ``jnd_vibration_frac`` (20 %:
  intensity difference limens of 1.5-2 dB, Gescheider, Bolanowski, Verrillo, Arpajian & Ryan 1990,
  "Vibrotactile intensity discrimination measured by three methods", J Acoust Soc Am 87: 330-338). In
  detection both intervals hold the wall's own contact vibration; the click is felt where the percept is
  larger, so the detection threshold (75 % correct) is the transient that adds one JND to the contact's
  vibration.
* **Realness** (``real-virtual-2afc``): per interval the rater's spectral similarity to the real sample's own
  taps (:func:`study.session.rater.realism_score`: acceleration amplitude and spectral centroid against the real
  sample at the same velocity), plus ``N(0, realness_noise_sd)``; the interval more similar is "real".

The answer ("harder", "had the click", "real") is the interval with the larger percept (ties: interval 1);
with probability ``lapse``, or when an interval gave nothing to judge, it is a coin flip instead.
"""

from __future__ import annotations

import math

import numpy as np

from psychophysics.sdt import Z75_SQRT2

from ..session.rater import Reference, realism_score, tap_features

#: a tap's deepest penetration must exceed this to give a stiffness (encoder noise, grazing contacts)
MIN_PENETRATION_M = 2e-4


def sigma_of_jnd(jnd_frac: float) -> float:
    """Log-SD of a percept whose 2-interval JND (75 % point) is ``jnd_frac`` (e.g. 0.07 for 7 %)."""
    return math.log1p(jnd_frac) / Z75_SQRT2


def stiffness_weber_fraction(jnd_force_frac: float, jnd_compliance_frac: float) -> float:
    """The stiffness Weber fraction (75 % point re the reference) of force and displacement noise combined.

    ``k_hat = F_hat / x_hat``: log-SDs add in quadrature, ``W = exp(z75 sqrt(2) sqrt(sF^2 + sx^2)) - 1``.
    """
    s = math.hypot(sigma_of_jnd(jnd_force_frac), sigma_of_jnd(jnd_compliance_frac))
    return math.expm1(Z75_SQRT2 * s)


def tap_stiffness_N_m(trace: dict, force_per_amp_N_A: float) -> np.ndarray:
    """Rendered stiffness of each tap in a trace: force at the deepest penetration / that penetration.

    Parameters
    ----------
    trace : dict
        A tap window's arrays (``study.session.apparatus.TapResult.trace``): ``t_s``, ``position_m`` (surface at 0,
        positive up), ``current_A``, ``event_t_s``.
    force_per_amp_N_A : float
        The device's force per ampere (eq. 3.17).

    Returns
    -------
    ndarray, shape (n_taps,)
        N/m; NaN for a tap that did not penetrate ``MIN_PENETRATION_M``.
    """
    t, x, i = trace["t_s"], trace["position_m"], trace["current_A"]
    starts = np.asarray(trace["event_t_s"], float)
    out = np.full(len(starts), np.nan)
    for k, t0 in enumerate(starts):
        t1 = starts[k + 1] if k + 1 < len(starts) else t[-1] + 1.0
        sel = np.nonzero((t >= t0) & (t < t1))[0]
        if len(sel) == 0:
            continue
        j = sel[np.argmin(x[sel])]
        depth = -float(x[j])
        if depth > MIN_PENETRATION_M:
            out[k] = float(i[j]) * force_per_amp_N_A / depth
    return out


def vibration_per_velocity(trace: dict) -> np.ndarray:
    """20-1000 Hz handle-acceleration RMS of the 100 ms after each impact over the tap's incoming velocity.

    Returns
    -------
    ndarray, shape (n_taps,)
        (m/s^2) / (m/s) = 1/s; NaN for an impact whose window is incomplete.
    """
    feats = tap_features(trace["t_s"], trace["accel_m_s2"], trace["event_t_s"], float(trace["fs_hz"]))
    v = np.maximum(np.asarray(trace["event_incoming_velocity_m_s"], float), 1e-3)
    return feats[:, 0] / v


def realness(trace: dict, reference: Reference) -> float:
    """Spectral similarity (0-1) of an interval's taps to the real sample's (:func:`study.session.rater.realism_score`)."""
    feats = tap_features(trace["t_s"], trace["accel_m_s2"], trace["event_t_s"], float(trace["fs_hz"]))
    score = realism_score(feats, trace["event_incoming_velocity_m_s"], trace["event_max_penetration_m"], reference)
    return score["similarity"]


def measured(kind: str, vary: str, trace: dict, force_per_amp_N_A: float, reference: Reference | None) -> float:
    """The noise-free quantity an interval is judged by (NaN when its taps give none).

    Parameters
    ----------
    kind : str
        Experiment kind (``study.forcedchoice.experiment.KINDS``).
    vary : str
        The varied parameter (``stiffness_N_m`` judges stiffness; amplitude/gain judge the transient).
    trace : dict
        The interval's tap-window arrays.
    force_per_amp_N_A : float
    reference : study.session.rater.Reference or None
        The real sample's taps (real-virtual-2afc).
    """
    if kind == "real-virtual-2afc":
        return realness(trace, reference)
    values = tap_stiffness_N_m(trace, force_per_amp_N_A) if (kind == "discrimination" and vary == "stiffness_N_m") \
        else vibration_per_velocity(trace)
    values = values[np.isfinite(values)]
    return float(np.median(values)) if len(values) else math.nan


def choose(kind: str, vary: str, values: tuple, config, rng: np.random.Generator) -> tuple[int, tuple]:
    """The simulated participant's answer (interval 1 or 2) from the two intervals' measured values.

    Parameters
    ----------
    kind, vary : str
    values : (float, float)
        :func:`measured` of interval 1 and 2.
    config : study.session.participants.SimParticipantConfig
        ``jnd_force_frac``, ``jnd_compliance_frac``, ``jnd_vibration_frac``, ``realness_noise_sd``, ``lapse``.
    rng : numpy.random.Generator
        The trial's generator (seeded by seed, subject, trial, attempt).

    Returns
    -------
    (int, tuple)
        The interval chosen and the two percepts (after noise).
    """
    e = rng.standard_normal((2, 2))
    lapse = rng.random() < config.lapse
    coin = int(rng.integers(1, 3))
    if not all(math.isfinite(x) for x in values):
        return coin, (math.nan, math.nan)   # an interval gave nothing to judge (no tap deep enough): a guess
    v = list(values)
    if kind == "real-virtual-2afc":
        percepts = tuple(v[j] + config.realness_noise_sd * e[j, 0] for j in range(2))
    elif vary == "stiffness_N_m":
        sf, sx = sigma_of_jnd(config.jnd_force_frac), sigma_of_jnd(config.jnd_compliance_frac)
        percepts = tuple(v[j] * math.exp(sf * e[j, 0] - sx * e[j, 1]) for j in range(2))
    else:
        sv = sigma_of_jnd(config.jnd_vibration_frac)
        percepts = tuple(v[j] * math.exp(sv * e[j, 0]) for j in range(2))
    if lapse:
        return coin, percepts
    return (1 if percepts[0] >= percepts[1] else 2), percepts
