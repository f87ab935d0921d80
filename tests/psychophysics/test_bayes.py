"""The Bayesian fit (psychophysics.bayes, psignifit 4's method): thresholds and credible intervals within 2 % of
psignifit's on published data sets for all three functions, the overdispersion eta absorbing extra-binomial
variance, sparse data kept off the parameter bounds."""

import math

import numpy as np
import pytest

from psychophysics import fitting as pm
from psychophysics.bayes import fit_bayes_counts
from psychophysics.psychometric import psi

from .conftest import CASES, TESTED


@pytest.mark.parametrize("name, function", TESTED)
def test_thresholds_and_credible_intervals_within_2_percent_of_psignifit(name, function, psignifit_results):
    data, _, alternatives, lower, eta = CASES[name]
    theirs, ci, res = psignifit_results[(name, function)]
    ours = fit_bayes_counts(*data, alternatives=alternatives, function=function, lower_asymptote=lower, eta=eta)
    assert ours.threshold == pytest.approx(theirs, rel=0.02)
    assert ours.threshold_ci == pytest.approx(tuple(ci), rel=0.02)
    # and the maximum-likelihood fit of the same model, without priors, within 2 % too on these data
    ml = pm.fit_counts(*data, alternatives=alternatives, function=function, lower_asymptote=lower, bootstrap=0)[0]
    assert ml.threshold == pytest.approx(theirs, rel=0.02)
    if eta is None:
        lo, hi = res.confidence_intervals["eta"]["0.95"]
        assert ours.eta_ci[0] == pytest.approx(lo, abs=0.01) and abs(ours.eta_ci[1] - hi) < 0.02


def test_eta_absorbs_overdispersion():
    """Blocks whose proportion correct varies around psi (beta-distributed, eta = 0.3: a session that drifts):
    the posterior puts eta well above 0 and widens the threshold's interval beyond the binomial fit's; on
    binomial data eta stays near 0."""
    rng = np.random.default_rng(4)
    levels = np.linspace(1.0, 4.0, 8)
    p = psi(levels, 2.5, 2.0, 0.5, 0.02)
    ep = 1 / 0.3 ** 2 - 1
    k_over = rng.binomial(100, rng.beta(p * ep, (1 - p) * ep)).astype(float)
    k_bin = rng.binomial(100, p).astype(float)
    n = np.full(8, 100.0)
    over = fit_bayes_counts(levels, n, k_over, 2)
    binom = fit_bayes_counts(levels, n, k_bin, 2)
    plain = fit_bayes_counts(levels, n, k_over, 2, eta=0.0)
    assert over.eta_ci[0] > 0.05 and over.eta > 0.15
    assert binom.eta < 0.05
    width = np.diff(over.threshold_ci)[0]
    assert width > 1.5 * np.diff(plain.threshold_ci)[0]


def test_sparse_data_do_not_end_in_a_step_function():
    """Five trials at each of four levels, all wrong below and all right above: maximum likelihood gives the
    steepest function allowed (flagged); the priors keep the Bayesian fit's slope and lapse inside their
    support with a finite, wider interval."""
    levels = np.array([1.0, 2.0, 3.0, 4.0])
    n = np.full(4, 5.0)
    k = np.array([0.0, 0.0, 5.0, 5.0])
    ml = pm.fit_counts(levels, n, k, 1, bootstrap=0)[0]
    assert "slope_at_bound" in {f.name for f in ml.flags}
    b = fit_bayes_counts(levels, n, k, 1)
    assert b.slope < 0.5 * ml.slope and 0.0 <= b.lapse < 0.2
    assert 2.0 < b.threshold < 3.0 and np.isfinite(b.threshold_ci).all()
    assert not math.isclose(b.threshold_ci[0], b.threshold_ci[1])
