"""How many trials a participant needs for the method of adjustment's PSE (within 5 %) and magnitude
estimation's exponent (within 0.05): the counts ``python -m benchmarks scaling`` runs with, against simulated
participants analysed by the project's own estimators."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from statsmodels.stats.weightstats import DescrStatsW

from analysis import adjustment, magnitude
from analysis.scaling_design import (Z75_SQRT2, exponent_fraction_within, fraction_within, magnitude_residual_sd,
                                     repetitions_needed, trials_needed)
from benchmarks.bench_scaling import LEVELS
from study.forcedchoice import perception
from study.forcedchoice.perception import stiffness_weber_fraction
from study.session.participants import SimParticipantConfig

W = stiffness_weber_fraction(SimParticipantConfig().jnd_force_frac, SimParticipantConfig().jnd_compliance_frac)


def settings(rng, participants: int, n: int, sd_log: float, truth: float = 770.0) -> pd.DataFrame:
    """``n`` log-normal settings per participant about ``truth``, half started above and half below, as the
    adjustment sessions' rows."""
    ln = np.log(truth) + sd_log * rng.standard_normal((participants, n))
    return pd.DataFrame({"subject": np.repeat([f"P{k:04d}" for k in range(participants)], n), "condition": "700",
                         "matched": 1, "final_value": np.exp(ln.ravel()), "reference_value": 700.0,
                         "start_side": np.tile(["above", "below"] * (n // 2) + ["above"] * (n % 2), participants),
                         "position": 1, "sequence": 0})


def test_the_percept_noise_constant_is_the_simulated_participants():
    # one definition (psychophysics.sdt), the d' of 75 % correct in 2AFC: Phi(d' / sqrt 2) = 0.75
    assert Z75_SQRT2 is perception.Z75_SQRT2
    assert stats.norm.cdf(Z75_SQRT2 / math.sqrt(2.0)) == pytest.approx(0.75, abs=1e-15)


def test_the_adjustment_trial_count_puts_95_percent_of_participants_within_5_percent():
    assert W == pytest.approx(0.168, abs=5e-4)
    n = trials_needed(W)
    assert n == 44                                            # the smallest count: one fewer falls short
    assert fraction_within(W, n - 1) < 0.95 <= fraction_within(W, n)
    assert n == pytest.approx((stats.norm.ppf(0.975) * W / math.log(1.05)) ** 2, rel=0.05)   # the usual rule
    assert fraction_within(W, 8) == pytest.approx(0.600, abs=0.001)
    rng = np.random.default_rng(5)
    for trials in (n, 8):
        rows = settings(rng, 4000, trials, W)
        ln = np.log(rows["final_value"].to_numpy()).reshape(4000, trials)
        mean, half = ln.mean(1), stats.t.ppf(0.975, trials - 1) * ln.std(1, ddof=1) / math.sqrt(trials)
        # the analysis' PSE and interval are these (checked on the first 150 participants)
        s = adjustment.per_subject(rows.iloc[:150 * trials])
        assert np.allclose(s["pse"], np.exp(mean[:150])) and np.allclose(s["pse_low"], np.exp(mean - half)[:150])
        for i in range(5):                                    # statsmodels' t interval of the log settings
            lo, hi = DescrStatsW(ln[i]).tconfint_mean(0.05)
            assert (s["pse_low"].iloc[i], s["pse_high"].iloc[i]) == pytest.approx((math.exp(lo), math.exp(hi)))
        within = float((np.abs(np.expm1(mean - math.log(770.0))) < 0.05).mean())
        # the formula against simulated participants (binomial SE of the fraction: 0.3 % at 44 trials, 0.8 % at 8)
        assert within == pytest.approx(fraction_within(W, trials), abs=0.02), (trials, within)
        cover = float((np.abs(mean - math.log(770.0)) <= half).mean())
        assert 0.935 <= cover <= 0.965, (trials, cover)       # the t interval keeps 95 % at any count


def test_the_magnitude_repetitions_put_95_percent_of_exponents_within_0_05():
    cfg = SimParticipantConfig()
    residual = magnitude_residual_sd(W, cfg.stevens_exponent, cfg.magnitude_noise_frac)
    assert residual == pytest.approx(0.164, abs=0.001)
    reps = repetitions_needed(residual, LEVELS)
    assert reps == 12
    assert (exponent_fraction_within(residual, LEVELS, reps - 1) < 0.95
            <= exponent_fraction_within(residual, LEVELS, reps))
    assert exponent_fraction_within(residual, LEVELS, 5) == pytest.approx(0.811, abs=0.001)
    # the simulated participant's numbers (study.magnitude): k (percept e^(sigma e1))^beta e^(0.1 e2), two
    # significant digits; fitted per participant by the analysis' OLS
    sigma = math.log1p(W) / (0.6744897501960817 * math.sqrt(2))
    rng = np.random.default_rng(11)
    beta, m = cfg.stevens_exponent, 4000
    for r in (reps, 5):
        x = np.log(np.repeat(np.asarray(LEVELS), r))
        k = np.exp(rng.uniform(math.log(5), math.log(50), (m, 1))) / 1000.0 ** beta
        percept = np.exp(x + sigma * rng.standard_normal((m, len(x))))
        number = k * percept ** beta * np.exp(cfg.magnitude_noise_frac * rng.standard_normal((m, len(x))))
        digits = 10.0 ** (np.floor(np.log10(number)) - 1)
        y = np.log(np.round(number / digits) * digits)
        xc = x - x.mean()
        slope = (y - y.mean(1, keepdims=True)) @ xc / (xc @ xc)
        resid = y - y.mean(1, keepdims=True) - slope[:, None] * xc
        se = np.sqrt((resid ** 2).sum(1) / (len(x) - 2) / (xc @ xc))
        for i in range(100):                                  # the analysis' OLS is this one
            fit = magnitude.power_fit(x, y[i])
            assert (fit["exponent"], fit["exponent_se"]) == pytest.approx((slope[i], se[i]), rel=1e-9)
        assert np.sqrt(np.mean(se ** 2 * (xc @ xc))) == pytest.approx(residual, rel=0.03)  # two digits add little
        within = float((np.abs(slope - beta) < 0.05).mean())
        assert within == pytest.approx(exponent_fraction_within(residual, LEVELS, r), abs=0.02), (r, within)
        cover = float((np.abs(slope - beta) <= stats.t.ppf(0.975, len(x) - 2) * se).mean())
        assert 0.935 <= cover <= 0.965, (r, cover)


def test_a_modulus_adds_the_remembered_standards_noise():
    """With a modulus every 6 trials the standard's remembered percept (drawn at each showing) scales the next
    six numbers: 19 repetitions, not 12, for 95 % of exponents within 0.05 (examples/magnitude.toml)."""
    cfg = SimParticipantConfig()
    beta, sigma = cfg.stevens_exponent, math.log1p(W) / (0.6744897501960817 * math.sqrt(2))
    residual = magnitude_residual_sd(W, beta, cfg.magnitude_noise_frac, modulus=True)
    assert residual == pytest.approx(math.hypot(magnitude_residual_sd(W, beta, cfg.magnitude_noise_frac),
                                                beta * sigma))
    reps = repetitions_needed(residual, LEVELS)
    assert reps == 19
    rng = np.random.default_rng(2)
    m, x = 3000, np.log(np.repeat(np.asarray(LEVELS), reps))
    x = np.array([rng.permutation(x) for _ in range(m)])                     # a seeded random order per block
    standard = np.repeat(sigma * rng.standard_normal((m, len(LEVELS) * reps // 6)), 6, axis=1)
    y = (beta * (x + sigma * rng.standard_normal(x.shape) - standard)
         + cfg.magnitude_noise_frac * rng.standard_normal(x.shape))
    xc = x - x.mean(1, keepdims=True)
    slope = (xc * y).sum(1) / (xc ** 2).sum(1)
    assert float((np.abs(slope - beta) < 0.05).mean()) == pytest.approx(
        exponent_fraction_within(residual, LEVELS, reps), abs=0.02)
