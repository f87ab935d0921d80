"""The study's adaptive methods and the analysis' fits use one psychometric function (issue 34's contract):
study/psychometric.py and analysis/psychometric.py may not import each other (package arrows), so this test
holds them to the same numbers."""

import numpy as np
import pytest

from analysis import psychometric as fit_side
from study import psychometric as study_side


@pytest.mark.parametrize("function", ["logistic", "normal", "weibull"])
def test_both_packages_compute_the_same_function(function):
    rng = np.random.default_rng(0)
    x = rng.uniform(0.2, 12.0, 500)
    thr, slope = rng.uniform(2.0, 8.0, 500), rng.uniform(0.3, 6.0, 500)
    guess, lapse = rng.choice([0.0, 0.5, 1 / 3], 500), rng.uniform(0.0, 0.1, 500)
    assert np.allclose(study_side.psi(x, thr, slope, guess, lapse, function),
                       fit_side.psychometric(x, thr, slope, guess, lapse, function), rtol=0, atol=1e-12)
    f = rng.uniform(0.05, 0.95, 500)
    assert np.allclose(study_side.inverse_sigmoid(f, thr, slope, function),
                       fit_side.stimulus_at(f, thr, slope, function), rtol=1e-10, atol=1e-10)
    assert np.allclose(study_side.jnd(thr, slope, function),
                       fit_side.stimulus_at(0.75, thr, slope, function) - thr, rtol=1e-10, atol=1e-10)


def test_a_simulated_observers_staircase_data_fit_back_to_its_threshold():
    """An observer of the study's function, run by the study's QUEST+ staircase, fitted by the analysis."""
    from study.methods import method_from_table
    from study.observer import ObserverParams, SimulatedObserver

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
    fit = fit_side.fit(xs, ys, alternatives=2, function="weibull", bootstrap=0)
    assert fit.threshold == pytest.approx(0.8, rel=0.2)
    assert fit.threshold_ci[0] < 0.8 < fit.threshold_ci[1]
