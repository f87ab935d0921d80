"""The psychometric function (psychophysics.psychometric): its threshold, inverse, JND, against scipy's
distributions, and its location-scale view (what the fits use) against the direct formulas."""

import math

import numpy as np
import pytest
from scipy.special import expit
from scipy.stats import norm, weibull_min

from psychophysics.psychometric import (base_cdf, base_quantile, from_axis, guess_rate, intensity_at, inverse_sigmoid,
                                        jnd, psi, sigmoid, stimulus_axis)


@pytest.mark.parametrize("function", ["logistic", "normal", "weibull"])
def test_threshold_is_where_f_is_half_and_inverse_round_trips(function):
    assert sigmoid(2.5, 2.5, 3.0, function) == pytest.approx(0.5, abs=1e-15)
    f = np.linspace(0.01, 0.99, 25)
    np.testing.assert_allclose(sigmoid(inverse_sigmoid(f, 2.5, 3.0, function), 2.5, 3.0, function), f, rtol=1e-12)
    x = intensity_at(0.8, 2.5, 3.0, guess=0.5, lapse=0.02, function=function)
    assert psi(x, 2.5, 3.0, 0.5, 0.02, function) == pytest.approx(0.8, rel=1e-12)


def test_functions_equal_scipy_distributions():
    x = np.linspace(0.05, 6.0, 60)
    np.testing.assert_allclose(sigmoid(x, 2.0, 1.7, "logistic"), expit(1.7 * (x - 2.0)), rtol=1e-13)
    np.testing.assert_allclose(sigmoid(x, 2.0, 1.7, "normal"), norm.cdf(x, loc=2.0, scale=1 / 1.7), rtol=1e-12)
    # the contract's Weibull: F = 1 - exp(-ln2 (x/alpha)^beta) is weibull_min with scale alpha / ln2^(1/beta)
    np.testing.assert_allclose(sigmoid(x, 2.0, 3.5, "weibull"),
                               weibull_min.cdf(x, 3.5, scale=2.0 / math.log(2) ** (1 / 3.5)), rtol=1e-12)
    # JND of the contract: x(F=0.75) - x(F=0.5); logistic: ln(3)/beta, normal: z(0.75)/beta
    assert jnd(10.0, 0.5, "logistic") == pytest.approx(math.log(3) / 0.5, rel=1e-12)
    assert jnd(10.0, 0.5, "normal") == pytest.approx(norm.ppf(0.75) / 0.5, rel=1e-12)


@pytest.mark.parametrize("function", ["logistic", "normal", "weibull"])
def test_the_location_scale_view_is_the_same_function(function):
    """The fits work on ``G(beta (u - a))`` on the stimulus axis (ln x for the Weibull): the same numbers as
    the direct formulas, and its quantile the same inverse."""
    rng = np.random.default_rng(0)
    x = rng.uniform(0.2, 12.0, 500)
    thr, slope = rng.uniform(2.0, 8.0, 500), rng.uniform(0.3, 6.0, 500)
    direct = sigmoid(x, thr, slope, function)
    scaled = base_cdf(slope * (stimulus_axis(x, function) - stimulus_axis(thr, function)), function)
    np.testing.assert_allclose(scaled, direct, rtol=0, atol=1e-12)
    f = rng.uniform(0.05, 0.95, 500)
    via_axis = from_axis(stimulus_axis(thr, function) + base_quantile(f, function) / slope, function)
    np.testing.assert_allclose(via_axis, inverse_sigmoid(f, thr, slope, function), rtol=1e-10, atol=1e-10)


def test_guess_rate_of_n_alternatives_and_yes_no():
    assert guess_rate(1) == 0.0 and guess_rate(2) == 0.5 and guess_rate(4) == 0.25
    for bad in (0, 2.0, True):
        with pytest.raises(ValueError, match="--alternatives must be a whole number >= 1"):
            guess_rate(bad)
