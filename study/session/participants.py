"""Who taps and rates: the simulated participant (sim mode) or a person at the keyboard (views).

The simulated participant (sim mode only) drives the sim device's hand: tap
velocities drawn from N(0.10, 0.04) m/s (the pooled mean and SD of section
4.5.4) clipped to a sane range, a grip force fixed per subject, occasional
mistakes (a rejected trial, a tap after the window that overpowers the
homing, a hard tap) at configurable rates, and ratings from the synthetic
rater of :mod:`study.session.rater`. Every random choice comes from a generator seeded
by ``(seed, subject, phase, trial, attempt)``, so a resumed session makes the
same choices as an uninterrupted one.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from plumbing.validation import load_dataclass_file

from .rng import PHASE_CODES, session_rng
from .rater import RaterProfile, rate, realism_score


@dataclass(frozen=True)
class SimParticipantConfig:
    """Simulated participant parameters (velocities in m/s, forces in N, rates per attempt).

    Attributes
    ----------
    velocity_mean_m_s, velocity_sd_m_s : float
        Normal distribution of incoming velocities (section 4.5.4: 0.10, 0.042).
    velocity_min_m_s, velocity_max_m_s : float
        Clip range.
    grip_min_N, grip_max_N : float
        Range of the per-subject grip force (uniform).
    tap_period_s : float
        Time between taps (approach + dwell + lift) used to fit the taps in the window.
    dwell_s : float
        Time the hand rests on the surface per tap.
    familiarization_taps_min, familiarization_taps_max : int
        Section 4.5.4: subjects tapped the real wood 4 to 22 times.
    p_reject : float
        Probability of rejecting an attempt ('x', e.g. let go of the stylus).
    p_overpower : float
        Probability of tapping again after the window, against the homing.
    overpower_grip_N : float
        Grip (hand stiffness rises with it) during such a late tap.
    overpower_press_depth_m : float
        How far below the surface the late tap aims (a determined push).
    p_hard_tap : float
        Probability per attempt of one hard tap at ``hard_tap_factor`` times the velocity.
    hard_tap_factor : float
    jnd_force_frac, jnd_compliance_frac : float
        Psychophysics sessions: the 2-interval JNDs (75 % point, fractions) of force (7 %) and compliance
        (15 %) that set the stiffness percept's Weber noise (:mod:`study.forcedchoice.perception`).
    jnd_vibration_frac : float
        Psychophysics: the vibrotactile amplitude JND (20 %) that sets the transient percept's noise.
    realness_noise_sd : float
        Psychophysics: SD of the noise added to an interval's spectral similarity to the real sample (0-1).
    lapse : float
        Psychophysics: probability that an answer is a coin flip (below 0.5).
    adjust_bias_frac : float
        Method of adjustment: the constant error, the fraction by which the participant's match lies above the
        reference's percept (negative: below; in (-0.5, 1)).
    adjust_reversals : int
        Method of adjustment: turns of direction in fine steps after which the participant accepts the match.
    stevens_exponent : float
        Magnitude estimation: the exponent of the participant's power law, number = k percept^exponent (0.8:
        hardness, Harper & Stevens 1964).
    magnitude_noise_frac : float
        Magnitude estimation: log-SD of the number given beyond the percept's own noise (response noise).
"""

    velocity_mean_m_s: float = 0.10
    velocity_sd_m_s: float = 0.04
    velocity_min_m_s: float = 0.03
    velocity_max_m_s: float = 0.30
    grip_min_N: float = 1.5
    grip_max_N: float = 3.0
    tap_period_s: float = 0.7
    dwell_s: float = 0.15
    familiarization_taps_min: int = 4
    familiarization_taps_max: int = 22
    p_reject: float = 0.03
    p_overpower: float = 0.03
    overpower_grip_N: float = 8.0
    overpower_press_depth_m: float = 0.03
    p_hard_tap: float = 0.03
    hard_tap_factor: float = 3.0
    jnd_force_frac: float = 0.07
    jnd_compliance_frac: float = 0.15
    jnd_vibration_frac: float = 0.2
    realness_noise_sd: float = 0.15
    lapse: float = 0.02
    adjust_bias_frac: float = 0.0
    adjust_reversals: int = 3
    stevens_exponent: float = 0.8
    magnitude_noise_frac: float = 0.1

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "adjust_bias_frac":
                if not (isinstance(value, (int, float)) and -0.5 < value < 1.0):
                    raise ValueError(f"participant.adjust_bias_frac must be in (-0.5, 1), got {value!r}")
                continue
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"participant.{f.name} must be a finite number >= 0, got {value!r}")
        for key in ("p_reject", "p_overpower", "p_hard_tap"):
            if getattr(self, key) > 1:
                raise ValueError(f"participant.{key} is a probability (0-1), got {getattr(self, key)}")
        if self.lapse >= 0.5:
            raise ValueError(f"participant.lapse must be below 0.5 (at 0.5 every answer is a guess), got {self.lapse}")
        if not 0 < self.velocity_min_m_s < self.velocity_max_m_s:
            raise ValueError("participant velocity range must satisfy 0 < velocity_min_m_s < velocity_max_m_s")
        if not 0 < self.grip_min_N <= self.grip_max_N:
            raise ValueError("participant grip range must satisfy 0 < grip_min_N <= grip_max_N")
        if not 1 <= self.familiarization_taps_min <= self.familiarization_taps_max:
            raise ValueError("participant familiarization taps must satisfy 1 <= min <= max")
        if not 1 <= self.adjust_reversals <= 20 or self.adjust_reversals != int(self.adjust_reversals):
            raise ValueError(f"participant.adjust_reversals must be a whole number 1-20, got {self.adjust_reversals}")
        if not 0.1 <= self.stevens_exponent <= 4.0:
            raise ValueError(f"participant.stevens_exponent must be in 0.1-4 (Stevens' exponents of touch: "
                             f"0.5-1.5), got {self.stevens_exponent}")
        if self.tap_period_s <= self.dwell_s:
            raise ValueError("participant.tap_period_s must exceed dwell_s")


def load_participant_config(path) -> SimParticipantConfig:
    """Load :class:`SimParticipantConfig` from TOML/JSON (unknown keys refused, naming file and key)."""
    if path is None:
        return SimParticipantConfig()
    return load_dataclass_file(path, SimParticipantConfig, "participant")


@dataclass(frozen=True)
class TapPlan:
    """What the simulated hand does in one attempt."""

    velocities_m_s: tuple
    grip_N: float
    reject: bool
    overpower: bool
    end_familiarization: bool = False


class SimulatedParticipant:
    """Taps through the sim device's hand model and rates with the synthetic rater."""

    kind = "simulated"

    def __init__(self, subject: str, experience: str, seed: int, config: SimParticipantConfig | None = None) -> None:
        self.config = config or SimParticipantConfig()
        self.subject = subject
        self.seed = int(seed)
        base = self._rng(0, 0, 0, 0)
        cfg = self.config
        self.grip_N = float(base.uniform(cfg.grip_min_N, cfg.grip_max_N))
        self.profile = RaterProfile.for_subject(experience, base)
        self.familiarization_taps = int(base.integers(cfg.familiarization_taps_min, cfg.familiarization_taps_max + 1))
        self._fam_taps_done = 0

    def _rng(self, phase_code: int, trial: int, attempt: int, purpose: int) -> np.random.Generator:
        return session_rng(self.seed, self.subject, phase_code, trial, attempt, purpose)

    def rng(self, phase: str, trial: int, attempt: int, purpose: int) -> np.random.Generator:
        """The participant's generator for one choice of an attempt (:func:`study.session.rng.session_rng` of
        the session's seed and subject, the phase, trial, attempt and the choice's ``purpose``)."""
        return self._rng(PHASE_CODES[phase], trial, attempt, purpose)

    def taps_per_window(self, window_s: float) -> int:
        """Taps that fit in the window, the first one at t = 0 of the window."""
        return max(1, int((window_s - self.config.dwell_s) // self.config.tap_period_s) + 1)

    def plan(self, phase: str, trial: int, attempt: int, window_s: float, fam_taps_done: int = 0) -> TapPlan:
        """Decide the attempt: tap velocities, grip, whether it will be rejected or overpowered."""
        cfg = self.config
        rng = self._rng(PHASE_CODES[phase], trial, attempt, 1)
        n = self.taps_per_window(window_s)
        end = False
        if phase == "familiarization":
            remaining = self.familiarization_taps - fam_taps_done
            n = max(1, min(n, remaining))
            end = remaining <= n
        v = rng.normal(cfg.velocity_mean_m_s, cfg.velocity_sd_m_s, size=n)
        hard = rng.random() < cfg.p_hard_tap
        if hard:
            v[int(rng.integers(0, n))] *= cfg.hard_tap_factor
        v = np.clip(v, cfg.velocity_min_m_s, cfg.velocity_max_m_s * (cfg.hard_tap_factor if hard else 1.0))
        reject = phase != "familiarization" and rng.random() < cfg.p_reject
        overpower = rng.random() < cfg.p_overpower
        return TapPlan(tuple(float(x) for x in v), self.grip_N, bool(reject), bool(overpower), end)

    def rate(self, phase: str, trial: int, attempt: int, plan: TapPlan, features, velocities, penetrations,
             reference) -> tuple[int | None, bool, dict]:
        """Rating 1..7 (or rejection) for an attempt; returns (rating, rejected, score parts)."""
        if plan.reject:
            return None, True, {}
        score = realism_score(features, velocities, penetrations, reference)
        rng = self._rng(PHASE_CODES[phase], trial, attempt, 2)
        return rate(score, self.profile, rng), False, score

    def describe(self) -> dict:
        """The participant as plain data for session.json (grip, rater bias and noise, config)."""
        return {"kind": self.kind, "grip_N": self.grip_N, "rater_bias": self.profile.bias,
                "rater_noise_sd": self.profile.noise_sd, "familiarization_taps": self.familiarization_taps,
                "config": asdict(self.config)}
