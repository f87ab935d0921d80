"""Every fit carries its flags: one test per flag, each on data made to raise it, and a clean fit raises none."""

import numpy as np
import pytest

from psychophysics import fitting as pm
from psychophysics.psychometric import psi

LEVELS = np.linspace(1.0, 4.0, 7)
N = np.full(7, 40.0)


def _names(fit):
    return {f.name for f in fit.flags}


def test_a_good_fit_has_no_flag():
    k = np.random.default_rng(3).binomial(60, psi(LEVELS, 2.5, 2.0, 0.5, 0.02)).astype(float)
    f = pm.fit_counts(LEVELS, np.full(7, 60.0), k, 2, bootstrap=200)[0]
    assert f.flags == () and f.as_dict()["flags"] == []


def test_lapse_at_bound():
    """20 % errors at the easiest levels: more than the 0.1 a lapse may be."""
    k = np.array([20, 22, 26, 30, 32, 32, 32.0])
    assert "lapse_at_bound" in _names(pm.fit_counts(LEVELS, N, k, 2, bootstrap=0)[0])


def test_guess_at_bound():
    """A yes/no observer answering 'yes' to 60 % of the weakest stimuli: a false-alarm rate at its bound 0.5."""
    k = np.array([24, 25, 24, 26, 30, 36, 39.0])
    f = pm.fit_counts(LEVELS, N, k, 1, lower_asymptote="free", bootstrap=0)[0]
    assert "guess_at_bound" in _names(f) and f.guess == pytest.approx(pm.GUESS_MAX)


def test_slope_at_bound_and_few_levels_on_the_slope():
    """All wrong below, all right above: a step function; no level lies on the slope."""
    k = np.array([0, 0, 0, 40, 40, 40, 40.0])
    names = _names(pm.fit_counts(LEVELS, N, k, 1, bootstrap=0)[0])
    assert {"slope_at_bound", "few_levels_on_slope"} <= names


def test_few_levels_on_the_slope_alone():
    """A steep observer tested on a coarse grid: one level on the slope."""
    k = np.random.default_rng(3).binomial(40, psi(LEVELS, 2.2, 12.0, 0.5, 0.0)).astype(float)
    f = pm.fit_counts(LEVELS, N, k, 2, bootstrap=0)[0]
    assert "few_levels_on_slope" in _names(f)


def test_threshold_outside_the_range():
    """Nearly every answer correct at every level (an observer far above threshold): the threshold lies below the
    tested range."""
    k = np.array([38, 39, 40, 40, 40, 40, 40.0])
    f = pm.fit_counts(LEVELS, N, k, 2, bootstrap=0)[0]
    assert "threshold_outside_range" in _names(f) and f.threshold < LEVELS[0]


def test_an_open_interval():
    """Every answer correct: nothing bounds the threshold from below (the interval's low end is -inf, written
    as an empty value)."""
    f = pm.fit_counts(LEVELS, N, np.full(7, 40.0), 2, bootstrap=0)[0]
    assert "threshold_interval_open" in _names(f)
    assert f.threshold_ci[0] == -np.inf and np.isfinite(f.threshold_ci[1])
    assert f.as_dict()["threshold_ci"][0] is None


def test_poor_fit():
    """A non-monotonic observer: the deviance's bootstrap p-value is below 0.05."""
    k = np.array([20, 38, 22, 38, 24, 39, 40.0])
    f = pm.fit_counts(LEVELS, N, k, 2, bootstrap=300)[0]
    assert "poor_fit" in _names(f) and f.deviance_p_bootstrap < 0.05


@pytest.mark.parametrize("value", [0.0, 40.0])
def test_one_response(value):
    """All correct or all wrong: no psychometric function in the data (and every other sign of it flagged)."""
    f = pm.fit_counts(LEVELS, N, np.full(7, value), 2, bootstrap=0)[0]
    assert "one_response" in _names(f)
    assert "threshold_outside_range" in _names(f)


def test_every_flag_name_is_documented():
    from pathlib import Path
    text = (Path(__file__).resolve().parents[2] / "docs" / "psychophysics.md").read_text()
    missing = [name for name in pm.FLAG_NAMES + ("posterior_at_grid_edge",) if f"`{name}`" not in text]
    assert not missing, missing
