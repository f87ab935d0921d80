"""Psychophysics on its own: the psychometric function, its fits, adaptive methods and a simulated observer.

A small library in the manner of psignifit and questplus; it knows nothing of devices, renderings or
sessions (the study runs its methods, the analysis fits and draws with it)::

    from psychophysics import QuestPlus, SimulatedObserver, ObserverParams, fit

    method = QuestPlus(intensities={"min": 0.1, "max": 10, "n": 41}, thresholds={"min": 0.1, "max": 10, "n": 41},
                       slopes=[2, 3.5, 5], lapses=[0, 0.02], guess=0.5, function="weibull", max_trials=80)
    observer = SimulatedObserver(ObserverParams(threshold=1.0), seed=1)
    xs, ys = [], []
    while not method.finished:
        x = method.next_intensity()
        y = observer.respond(x)
        method.update(x, y)
        xs.append(x)
        ys.append(y)
    print(method.estimate()["threshold"], fit(xs, ys, alternatives=2, function="weibull").threshold)

Modules: ``psychometric`` (the function), ``fitting`` (maximum likelihood, profile and bootstrap intervals,
goodness of fit, flags, several conditions and their comparison), ``bayes`` (psignifit 4's Bayesian fit with
priors and overdispersion), ``sdt`` (d' and criterion), ``datasets`` (published data for checking fits), ``adaptive`` (the methods' common part: history, reversals, state and replay),
``staircase`` (up-down, weighted up-down), ``quest`` (QUEST+, Psi), ``multistair`` (interleaving, catch
trials), ``methods`` (by name, from a protocol table or a saved state), ``observer`` (the simulated
observer) and ``simulate`` (a method against an observer, R times: precision against trials).
docs/psychophysics_api.md lists every public name.

The names load on first use (``plumbing.lazy``): importing the package costs nothing until one is used.
"""

from plumbing.lazy import lazy_exports

_EXPORTS = {
    "FUNCTIONS": "psychometric", "psi": "psychometric", "sigmoid": "psychometric",
    "inverse_sigmoid": "psychometric", "intensity_at": "psychometric", "jnd": "psychometric",
    "guess_rate": "psychometric",
    "Fit": "fitting", "fit": "fitting", "fit_counts": "fitting", "aggregate": "fitting", "deviance": "fitting",
    "profile_interval": "fitting", "LAPSE_MAX": "fitting", "GUESS_MAX": "fitting", "Flag": "fitting",
    "FLAG_NAMES": "fitting", "bca_interval": "fitting", "fit_multiple": "fitting", "MultiFit": "fitting",
    "compare_models": "fitting", "ModelComparison": "fitting",
    "fit_bayes": "bayes", "fit_bayes_counts": "bayes", "BayesFit": "bayes", "default_priors": "bayes",
    "dprime": "sdt", "DATASETS": "datasets",
    "AdaptiveMethod": "adaptive", "reversals": "adaptive",
    "UpDown": "staircase", "WeightedUpDown": "staircase",
    "QuestPlus": "quest", "Psi": "quest", "make_grid": "quest",
    "Interleaved": "multistair", "Trial": "multistair",
    "METHODS": "methods", "method_from_table": "methods", "method_from_state": "methods",
    "ObserverParams": "observer", "SimulatedObserver": "observer",
    "SimulationSettings": "simulate", "precision_table": "simulate",
}

__all__ = list(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
