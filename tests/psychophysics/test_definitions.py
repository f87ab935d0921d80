"""One definition of PSE, threshold at any proportion correct, JND, Weber fraction and slope at threshold
(docs/psychophysics.md, "Thresholds, PSE, JND and Weber fraction"), checked against the formulas and against
psignifit 4's ``threshold(pc)`` and ``slope_at_proportion_correct`` on its own result."""

import math

import numpy as np
import pytest

from psychophysics import fitting as pm
from psychophysics.bayes import fit_bayes_counts
from psychophysics.datasets import PSIGNIFIT_DEMO
from psychophysics.psychometric import base_pdf, intensity_at, inverse_sigmoid, psi

STIFF = np.linspace(500.0, 800.0, 7)


def _data(seed, threshold=620.0, slope=0.03, guess=0.5, lapse=0.02, function="logistic", per_level=80,
          levels=STIFF):
    rng = np.random.default_rng(seed)
    return levels, np.full(len(levels), float(per_level)), rng.binomial(
        per_level, psi(levels, threshold, slope, guess, lapse, function)).astype(float)


def test_n_afc_jnd_is_threshold_minus_reference_and_weber_is_jnd_over_reference():
    """A 2AFC stiffness discrimination against a 500 N/m reference: the outputs used to disagree (Weber
    (threshold - reference) / reference = 0.24 beside a JND, x(F=.75) - x(F=.5), of about 0.04 x reference);
    now JND = threshold - reference and Weber = JND / reference, both with the threshold's exact interval.
    An n-AFC task has no PSE."""
    f = pm.fit_counts(*_data(1), alternatives=2, reference=500.0, bootstrap=0)[0]
    assert f.jnd == pytest.approx(f.threshold - 500.0, rel=1e-12)
    assert f.weber == pytest.approx(f.jnd / 500.0, rel=1e-12)
    assert f.jnd_ci == pytest.approx((f.threshold_ci[0] - 500, f.threshold_ci[1] - 500), rel=1e-12)
    assert f.weber_ci == pytest.approx((f.jnd_ci[0] / 500, f.jnd_ci[1] / 500), rel=1e-12)
    assert math.isnan(f.pse) and f.as_dict()["pse"] is None
    no_ref = pm.fit_counts(*_data(1), alternatives=2, bootstrap=0)[0]
    assert math.isnan(no_ref.jnd) and math.isnan(no_ref.weber)


@pytest.mark.parametrize("function", ["logistic", "normal", "weibull"])
def test_threshold_at_any_proportion_and_the_slope_at_threshold(function):
    """threshold_at(pc) is where psi = pc (scaled, psignifit's default) or F = pc (unscaled); its interval is the
    exact profile where F at the point is fixed (unscaled) and the bootstrap's otherwise; slope_at_threshold is
    d psi / dx at the threshold, per stimulus unit."""
    slope = {"logistic": 0.03, "normal": 0.02, "weibull": 12.0}[function]
    f = pm.fit_counts(*_data(2, slope=slope, function=function), alternatives=2, function=function,
                      bootstrap=300)[0]
    t75 = f.threshold_at(0.75)
    assert t75["threshold"] == pytest.approx(float(intensity_at(0.75, f.threshold, f.slope, f.guess, f.lapse,
                                                                function)), rel=1e-10)
    assert t75["ci_method"] == "bootstrap percentile" and t75["ci"][0] < t75["threshold"] < t75["ci"][1]
    t80 = f.threshold_at(0.8, unscaled=True)
    assert t80["threshold"] == pytest.approx(float(inverse_sigmoid(0.8, f.threshold, f.slope, function)), rel=1e-10)
    assert t80["ci_method"] == "profile" and t80["ci"][0] < t80["threshold"] < t80["ci"][1]
    assert f.threshold_at(0.5, unscaled=True)["ci"] == pytest.approx(list(f.threshold_ci), rel=1e-6)
    h = 1e-4 * f.threshold
    numeric = (psi(f.threshold + h, f.threshold, f.slope, f.guess, f.lapse, function)
               - psi(f.threshold - h, f.threshold, f.slope, f.guess, f.lapse, function)) / (2 * h)
    assert f.slope_at_threshold == pytest.approx(numeric, rel=1e-6)
    with pytest.raises(ValueError, match="needs a proportion in"):
        f.threshold_at(0.45)


@pytest.mark.parametrize("function", ["logistic", "normal", "weibull"])
def test_threshold_at_and_slope_match_psignifits_on_its_own_result(function, psignifit_results):
    """On psignifit's demo data our Bayesian fit's threshold_at(pc) (scaled and unscaled) and slope at threshold
    equal psignifit's Result.threshold(pc) and slope_at_proportion_correct at its MAP within 2 %."""
    _, _, res = psignifit_results[("psignifit_demo", function)]
    ours = fit_bayes_counts(*PSIGNIFIT_DEMO, alternatives=2, function=function)
    for pc, unscaled in ((0.75, False), (0.9, False), (0.8, True)):
        theirs = float(res.threshold(pc, unscaled=unscaled, return_ci=False))
        theirs = math.exp(theirs) if function == "weibull" else theirs
        assert ours.threshold_at(pc, unscaled, interval=False)["threshold"] == pytest.approx(theirs, rel=0.02)
    slope = float(res.slope_at_proportion_correct(0.5, unscaled=True))   # per log unit for the Weibull
    slope = slope / ours.threshold if function == "weibull" else slope
    assert ours.slope_at_threshold == pytest.approx(slope, rel=0.02)


def test_yes_no_pse_jnd_and_weber_and_the_slope_formula():
    f = pm.fit_counts(*_data(3, threshold=650.0, slope=0.025, guess=0.0, lapse=0.0), alternatives=1,
                      reference=650.0, lapse=0.0, bootstrap=0)[0]
    assert f.pse == f.threshold and f.pse_ci == f.threshold_ci
    assert f.jnd == pytest.approx(math.log(3) / f.slope, rel=1e-10)
    assert f.weber == pytest.approx(f.jnd / 650.0, rel=1e-12)
    assert f.slope_at_threshold == pytest.approx(f.slope * float(base_pdf(0.0, "logistic")), rel=1e-12)
