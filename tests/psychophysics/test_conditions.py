"""Several conditions fitted at once with shared parameters, the likelihood-ratio comparison of two models
(Palamedes' PAL_PFML_FitMultiple / PAL_PFLR_ModelComparison) against statsmodels' binomial GLMs, and d' and
criterion of yes/no data."""

import math

import numpy as np
import pytest
import statsmodels.api as sm
from scipy import stats

from psychophysics import fitting as pm
from psychophysics.psychometric import psi
from psychophysics.sdt import dprime

LEVELS = np.linspace(1.0, 4.0, 7)


def _conditions(seed, thresholds, slope=2.0, guess=0.0, lapse=0.0, per_level=60):
    rng = np.random.default_rng(seed)
    n = np.full(len(LEVELS), float(per_level))
    return [(LEVELS, n, rng.binomial(per_level, psi(LEVELS, t, slope, guess, lapse)).astype(float))
            for t in thresholds]


def _glm(data, separate_thresholds: bool):
    """Binomial logit GLM: a common slope on the stimulus, an intercept per condition (or one)."""
    x = np.concatenate([d[0] for d in data])
    n = np.concatenate([d[1] for d in data])
    k = np.concatenate([d[2] for d in data])
    cond = np.concatenate([np.full(len(d[0]), c) for c, d in enumerate(data)])
    cols = [x] + ([(cond == c).astype(float) for c in range(len(data))] if separate_thresholds else [np.ones_like(x)])
    res = sm.GLM(np.column_stack([k, n - k]), np.column_stack(cols), family=sm.families.Binomial()).fit(tol=1e-13)
    return res


def test_shared_slope_fits_equal_a_glm_with_a_common_slope():
    """Lapse fixed at 0, logistic: Palamedes' thresholds unconstrained and slopes constrained is a logit GLM
    with one intercept per condition and one slope; our thresholds are -intercept / slope."""
    data = _conditions(1, (2.0, 2.6, 3.1))
    mf = pm.fit_multiple(data, alternatives=1, lapse=0.0, names=["a", "b", "c"])
    glm = _glm(data, True)
    slope, intercepts = glm.params[0], glm.params[1:]
    assert mf.slopes == pytest.approx((slope,) * 3, rel=1e-6)
    assert mf.thresholds == pytest.approx(tuple(-intercepts / slope), rel=1e-6)
    ll_const = sum(math.log(math.comb(int(n), int(k))) for d in data for n, k in zip(d[1], d[2]))
    assert mf.loglik + ll_const == pytest.approx(glm.llf, abs=1e-6)
    for (lo, hi), t in zip(mf.threshold_ci, mf.thresholds):
        assert lo < t < hi


def test_likelihood_ratio_of_thresholds_equals_the_glms_and_detects_a_difference():
    """PAL_PFLR_ModelComparison: lesser = one threshold for all, fuller = one per condition (slope shared):
    the LR statistic equals twice the GLMs' log-likelihood difference, df = 2, p from chi-square and from
    simulated data sets of the lesser model."""
    data = _conditions(2, (2.0, 2.6, 3.1))
    cmp = pm.compare_models(data, lesser={"thresholds": "constrained"}, fuller={"thresholds": "unconstrained"},
                            alternatives=1, lapse=0.0, bootstrap=200, seed=1)
    lr = 2 * (_glm(data, True).llf - _glm(data, False).llf)
    assert cmp.lr == pytest.approx(lr, rel=1e-6) and cmp.df == 2
    assert cmp.p_chi2 == pytest.approx(stats.chi2.sf(lr, 2), rel=1e-6)
    assert cmp.p_chi2 < 1e-6 and cmp.p_bootstrap < 0.01


def test_the_model_comparison_holds_its_level_under_the_null():
    """Equal thresholds. Yes/no with no lapse (a GLM): of 400 data sets simulated from the lesser model and
    fitted by both (the bootstrap's own draws), the chi-square test at 0.05 rejects within the binomial 99.5 %
    bounds of a 5 % test. A 2AFC with a free shared lapse at 40 trials per level: the chi-square test rejects
    more often (measured 7-10 %: the lapse near its bounds), which is why the Monte Carlo p-value
    (Palamedes') is the one the command reports first."""
    glm_like = _conditions(100, (2.5, 2.5), per_level=40)
    cmp = pm.compare_models(glm_like, {"thresholds": "constrained"}, {"thresholds": "unconstrained"},
                            alternatives=1, lapse=0.0, bootstrap=400, seed=5)
    rejected = int(np.sum(cmp.lr_draws >= stats.chi2.ppf(0.95, cmp.df)))
    assert stats.binom.ppf(0.0025, 400, 0.05) <= rejected <= stats.binom.ppf(0.9975, 400, 0.05)
    assert abs(cmp.p_chi2 - cmp.p_bootstrap) < 0.06
    lapsing = _conditions(100, (2.5, 2.5), guess=0.5, lapse=0.02, per_level=40)
    cmp = pm.compare_models(lapsing, {"thresholds": "constrained"}, {"thresholds": "unconstrained"},
                            alternatives=2, bootstrap=400, seed=5)
    rate = np.mean(cmp.lr_draws >= stats.chi2.ppf(0.95, cmp.df))
    assert 0.05 < rate < 0.15


def test_a_lesser_model_must_be_nested():
    data = _conditions(3, (2.0, 2.5))
    with pytest.raises(ValueError, match="not nested"):
        pm.compare_models(data, {"slopes": "unconstrained"}, {"slopes": "constrained"}, alternatives=1,
                          bootstrap=0)


def test_dprime_and_criterion():
    """Macmillan & Creelman's worked numbers: H = 0.8, F = 0.2 gives d' = 1.683, c = 0; H = 0.9, F = 0.3 gives d'
    = 1.806, c = -0.379; rates of 0 and 1 are corrected the log-linear way (Hautus 1995)."""
    r = dprime(8, 10, 2, 10, correction="none")
    assert r["dprime"] == pytest.approx(1.683, abs=1e-3) and r["criterion"] == pytest.approx(0.0, abs=1e-12)
    r = dprime(90, 100, 30, 100, correction="none")
    assert r["dprime"] == pytest.approx(1.806, abs=1e-3) and r["criterion"] == pytest.approx(-0.3790, abs=1e-3)
    r = dprime(20, 20, 0, 20)
    assert r["hit_rate"] == pytest.approx(20.5 / 21) and r["false_alarm_rate"] == pytest.approx(0.5 / 21)
    assert np.isfinite(r["dprime"]) and r["dprime"] == pytest.approx(2 * stats.norm.ppf(20.5 / 21))
    with pytest.raises(ValueError, match="at least one stimulus trial and one blank"):
        dprime(1, 2, 0, 0)
