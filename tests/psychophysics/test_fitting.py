"""Psychometric fits (psychophysics.fitting): agreement with statsmodels' binomial GLM and psignifit 4, recovery
and interval calibration on simulated observers, equal asymptotes; an adaptive method's data fitted back."""

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import statsmodels.api as sm

from psychophysics import fitting as pm
from psychophysics.methods import method_from_table
from psychophysics.observer import ObserverParams, SimulatedObserver
from psychophysics.psychometric import FUNCTIONS, inverse_sigmoid, psi, sigmoid

ROOT = Path(__file__).resolve().parents[2]
LEVELS = np.linspace(1.0, 8.0, 7)


def _simulate(rng, threshold, slope, guess, lapse, function="logistic", per_level=60, levels=LEVELS):
    x = np.repeat(levels, per_level)
    y = (rng.random(len(x)) < psi(x, threshold, slope, guess, lapse, function)).astype(int)
    return x, y


@pytest.mark.parametrize("function, link", [("logistic", sm.families.links.Logit()),
                                            ("normal", sm.families.links.Probit())])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lapse_fixed_at_zero_equals_a_binomial_glm(function, link, seed):
    rng = np.random.default_rng(seed)
    x, y = _simulate(rng, 4.0 + seed * 0.3, 1.3 if function == "logistic" else 0.8, 0.0, 0.0, function, 40)
    f = pm.fit(x, y, alternatives=1, function=function, lapse=0.0, bootstrap=0)
    glm = sm.GLM(y.astype(float), sm.add_constant(x), family=sm.families.Binomial(link)).fit(tol=1e-12)
    b0, b1 = glm.params
    assert f.threshold == pytest.approx(-b0 / b1, abs=1e-6)
    assert f.slope == pytest.approx(b1, abs=1e-6)
    assert f.loglik == pytest.approx(glm.llf, abs=1e-6)  # Bernoulli data: no binomial constant on either side


def test_threshold_is_where_the_unscaled_sigmoid_is_one_half():
    for function in FUNCTIONS:
        assert sigmoid(3.7, 3.7, 2.0, function) == pytest.approx(0.5, abs=1e-12)
        x = inverse_sigmoid(np.array([0.25, 0.5, 0.75]), 3.7, 2.0, function)
        assert sigmoid(x, 3.7, 2.0, function) == pytest.approx([0.25, 0.5, 0.75], abs=1e-12)
        # with guess and lapse, psi at the threshold is halfway between the guess rate and 1 - lapse
        assert psi(3.7, 3.7, 2.0, 0.5, 0.04, function) == pytest.approx(0.5 + 0.46 / 2)


#: a stiffness-discrimination design (2AFC "which was harder?", comparison stiffness against a 500 N/m
#: reference): 7 comparison levels, 60 trials each
STIFFNESS_LEVELS = np.linspace(500.0, 800.0, 7)


def _observers(rng, count, levels=STIFFNESS_LEVELS):
    """Random observers: Weber fraction 0.1-0.4 (threshold 550-700 N/m), 25-75 % width 37-110 N/m, lapse 0-4 %."""
    thr = 500.0 * (1.0 + rng.uniform(0.1, 0.4, count))
    slope = rng.uniform(0.02, 0.06, count)
    lapse = rng.uniform(0.0, 0.04, count)
    p = psi(levels[None, :], thr[:, None], slope[:, None], 0.5, lapse[:, None])
    return thr, rng.binomial(60, p).astype(float)


def test_recovery_and_interval_calibration_on_simulated_observers():
    """7 levels x 60 trials, 2AFC, random threshold, slope and lapse: the threshold within 10 % for >= 90 % of
    300 observers; its 95 % interval covers the truth for 90-99 % of them (a true 93-97 % falls there with
    probability > 0.99 at n = 300)."""
    thr, k = _observers(np.random.default_rng(2024), 300)
    fits = pm.fit_counts(STIFFNESS_LEVELS, np.full(7, 60.0), k, alternatives=2, bootstrap=0)
    est = np.array([f.threshold for f in fits])
    ci = np.array([f.threshold_ci for f in fits])
    assert np.mean(np.abs(est - thr) / thr <= 0.10) >= 0.90
    assert 0.90 <= np.mean((ci[:, 0] <= thr) & (thr <= ci[:, 1])) <= 0.99


def test_many_data_sets_at_once_equal_one_at_a_time():
    thr, k = _observers(np.random.default_rng(7), 4)
    n = np.full(7, 60.0)
    together = pm.fit_counts(STIFFNESS_LEVELS, n, k, alternatives=2, bootstrap=100, seed=3)
    for b, f in enumerate(together):
        alone = pm.fit_counts(STIFFNESS_LEVELS, n, k[b], alternatives=2, bootstrap=0)[0]
        assert f.threshold == pytest.approx(alone.threshold, rel=1e-9)
        assert f.threshold_ci == pytest.approx(alone.threshold_ci, rel=1e-6)
        assert f.threshold_ci_bootstrap[0] < f.threshold < f.threshold_ci_bootstrap[1]
        assert f.slope_ci[0] < f.slope_ci[1] and 0.0 <= f.lapse_ci[0] <= f.lapse_ci[1] <= pm.LAPSE_MAX


def test_deviance_is_zero_for_a_saturated_fit_and_flags_a_wrong_function():
    k, n = np.array([3.0, 7.0]), np.array([10.0, 10.0])
    assert pm.deviance(k, n, k / n) == pytest.approx(0.0, abs=1e-12)
    # data from a non-monotonic observer: the bootstrap says the monotonic fit is bad
    x = np.repeat(LEVELS, 80)
    p = np.interp(x, LEVELS, [0.5, 0.95, 0.55, 0.95, 0.6, 0.98, 0.99])
    y = (np.random.default_rng(0).random(len(x)) < p).astype(int)
    f = pm.fit(x, y, alternatives=2, bootstrap=300)
    assert f.deviance_p_bootstrap < 0.01 and f.deviance_p_chi2 < 0.01


def test_jnd_and_weber_fraction_of_a_which_was_harder_task():
    """Yes/no ("which was harder?"): PSE = threshold (F = 0.5), JND = x(F = .75) - x(F = .5), Weber = JND /
    reference; the JND's interval from the bootstrap, percentile and BCa."""
    # yes/no: "comparison harder" vs comparison stiffness around a 500 N/m reference
    levels = np.linspace(350.0, 650.0, 7)
    x, y = _simulate(np.random.default_rng(4), 510.0, 0.02, 0.0, 0.0, "logistic", 200, levels)
    f = pm.fit(x, y, alternatives=1, lapse=0.0, reference=500.0, bootstrap=200)
    assert f.pse == pytest.approx(510.0, rel=0.02)
    assert f.jnd == pytest.approx(np.log(3) / 0.02, rel=0.15)           # x(F=.75) - x(F=.5) of the logistic
    assert f.weber == pytest.approx(f.jnd / 500.0)
    assert f.jnd_ci[0] < f.jnd < f.jnd_ci[1] and f.jnd_ci_bca[0] < f.jnd < f.jnd_ci_bca[1]
    assert f.pse_ci == f.threshold_ci and f.weber_ci == pytest.approx((f.jnd_ci[0] / 500, f.jnd_ci[1] / 500))


def _psignifit_equal_asymptote(x, y):
    from psignifit import psignifit

    levels, n, k = pm.aggregate(x, y)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = psignifit(np.column_stack([levels, k, n]), sigmoid="logistic", experiment_type="equal asymptote",
                        verbose=False, fixed_parameters={"eta": 0.0})
    return float(res.parameter_estimate["threshold"]), float(res.parameter_estimate["lambda"])


@pytest.mark.parametrize("seed", [12])
def test_equal_asymptotes_agree_with_psignifit_and_remove_the_bias_of_a_lapse_only_at_the_top(seed):
    """A "which was harder?" observer who lapses 6 % of the time answers at random on those trials: the
    function runs from 0.03 to 0.97. psignifit 4's "equal asymptote" fit and ours (gamma = lambda) agree on
    the PSE; fitting gamma = 0 with the lapse only at the top pulls the PSE down (the low asymptote's
    "harder" answers are read as a shallow rise)."""
    rng = np.random.default_rng(seed)
    pse, slope, lapse = 500.0, 0.02, 0.06
    levels = np.linspace(300.0, 700.0, 9)
    x, y = _simulate(rng, pse, slope, lapse / 2, lapse / 2, "logistic", 80, levels)
    equal = pm.fit(x, y, alternatives=1, bootstrap=0, equal_asymptote=True, reference=pse)
    top_only = pm.fit(x, y, alternatives=1, bootstrap=0, reference=pse)
    thr, lam = _psignifit_equal_asymptote(x, y)
    assert equal.equal_asymptote and equal.guess == equal.lapse
    assert abs(equal.threshold - thr) < 0.1 * (levels[-1] - levels[0]) / 8, (equal.threshold, thr)
    # psignifit's lambda is a posterior estimate under its lapse prior (it can sit near 0 where the maximum
    # likelihood is 0.03): the lapse is checked against the truth instead, each asymptote at 0.03
    assert abs(equal.lapse - lapse / 2) < 0.025 and np.isfinite(lam)
    assert abs(equal.threshold - pse) < abs(top_only.threshold - pse) + 5.0


def test_equal_asymptotes_recover_the_pse_and_jnd_of_lapsing_observers_without_bias():
    """200 simulated "which was harder?" observers (PSE 500 N/m, JND 27.5 N/m, lapse 6 %): the equal-asymptote
    fits' median PSE is within 1 % and median JND within 10 % of the truth; gamma = 0 fits are biased."""
    rng = np.random.default_rng(3)
    pse, slope, lapse = 500.0, 0.04, 0.06
    levels = np.linspace(400.0, 600.0, 9)
    n = np.full(len(levels), 40.0)
    p = psi(levels, pse, slope, lapse / 2, lapse / 2)
    k = rng.binomial(40, p, size=(200, len(levels))).astype(float)
    eq = pm.fit_counts(levels, n, k, alternatives=1, bootstrap=0, equal_asymptote=True)
    zero = pm.fit_counts(levels, n, k, alternatives=1, bootstrap=0)
    true_jnd = math.log(3.0) / slope
    assert abs(np.median([f.threshold for f in eq]) - pse) < 0.01 * pse
    assert abs(np.median([f.jnd for f in eq]) - true_jnd) < 0.10 * true_jnd
    bias_zero = abs(np.median([f.threshold for f in zero]) - pse)
    assert bias_zero > 2 * abs(np.median([f.threshold for f in eq]) - pse)


def test_equal_asymptotes_are_refused_for_an_n_afc_task():
    with pytest.raises(ValueError, match="equal asymptotes .* are for a yes/no task"):
        pm.fit([1, 2, 3], [0, 1, 1], alternatives=2, equal_asymptote=True, bootstrap=0)


def test_a_simulated_observers_staircase_data_fit_back_to_its_threshold():
    """An observer of the one psychometric function, run by QUEST+, fitted back by maximum likelihood."""
    params = ObserverParams(threshold=0.8, slope=3.5, lapse=0.02, guess=0.5, function="weibull")
    obs = SimulatedObserver(params, seed=3)
    method = method_from_table({"method": "quest+", "intensities": {"min": 0.08, "max": 8.0, "n": 41},
                                "thresholds": {"min": 0.08, "max": 8.0, "n": 41}, "slopes": [2, 3.5, 5],
                                "lapses": [0, 0.02, 0.04], "guess": 0.5, "max_trials": 200}, "staircase.")
    xs, ys = [], []
    while not method.finished:
        x = method.next_intensity()
        y = obs.respond(x)
        method.update(x, y)
        xs.append(x)
        ys.append(int(y))
    fit = pm.fit(xs, ys, alternatives=2, function="weibull", bootstrap=0)
    assert fit.threshold == pytest.approx(0.8, rel=0.2)
    assert fit.threshold_ci[0] < 0.8 < fit.threshold_ci[1]
