"""psignifit 4 on the published data sets, run once per test run (each fit takes 1-4 s)."""

import warnings

import numpy as np
import pytest

from psychophysics.datasets import BLISS_1935, PSIGNIFIT_DEMO

from tests.support.shared import shared_value

SIGMOIDS = {"logistic": "logistic", "normal": "norm", "weibull": "weibull"}
#: (data set name, data, psignifit's experiment type, our alternatives, our lower asymptote, fixed eta or None)
CASES = {"psignifit_demo": (PSIGNIFIT_DEMO, "2AFC", 2, "fixed", None),
         # yes/no with eta free takes psignifit ~35 s: the tests fix eta at 0 (the benchmark frees it)
         "bliss1935": (BLISS_1935, "yes/no", 1, "free", 0.0)}


def run_psignifit(data, experiment_type, function, eta=None):
    """psignifit 4's MAP threshold, its 95 % credible interval and its result (stimulus units)."""
    from psignifit import psignifit

    levels, n, k = data
    x = np.log(levels) if function == "weibull" else levels
    options = {} if eta is None else {"fixed_parameters": {"eta": eta}}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = psignifit(np.column_stack([x, k, n]), sigmoid=SIGMOIDS[function], experiment_type=experiment_type,
                        verbose=False, **options)
    t = res.parameter_estimate["threshold"]
    ci = np.asarray(res.confidence_intervals["threshold"]["0.95"], float)
    if function == "weibull":
        t, ci = np.exp(t), np.exp(ci)
    return float(t), ci, res


#: what the tests compare (yes/no with eta free takes psignifit ~35 s; the demo data run with eta free)
TESTED = (("psignifit_demo", "logistic"), ("psignifit_demo", "normal"), ("psignifit_demo", "weibull"),
          ("bliss1935", "logistic"))


@pytest.fixture(scope="session")
def psignifit_results(tmp_path_factory):
    """``{(data set, function): (threshold, ci, result)}``: the demo data with all three functions (eta free),
    Bliss (1935) with the logistic (eta fixed at 0). Fitted once per run for every xdist worker (~3-4 s of CPU;
    test_bayes.py and test_definitions.py read them): :mod:`tests.support.shared`."""

    def fit_all(_folder):
        out = {}
        for name, function in TESTED:
            data, etype, _, _, eta = CASES[name]
            out[(name, function)] = run_psignifit(data, etype, function, eta)
        return out

    return shared_value(tmp_path_factory, "psignifit_results", fit_all)
