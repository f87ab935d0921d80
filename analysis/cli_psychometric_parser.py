"""``python -m analysis psychometric DATA --out DIR``: psychometric fits of forced-choice data.

The parser (light: imported for ``--help``); the body is :mod:`analysis.cli_psychometric`.
"""

from __future__ import annotations

import argparse

from plumbing.cliargs import with_examples
from plumbing.dispatch import Body
from psychophysics.names import FUNCTIONS


def _lapse(text: str):
    """``--lapse``: ``free`` (fitted) or a fixed rate."""
    if text == "free":
        return None
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be 'free' or a number in [0, 0.5), got {text!r}") from None
    if not (0.0 <= value < 0.5):
        raise argparse.ArgumentTypeError(f"must be 'free' or a number in [0, 0.5), got {text!r}")
    return value


def _proportions(text: str) -> tuple:
    """``--threshold-at``: proportions in (0, 1), comma-separated."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be proportions in (0, 1) separated by commas, got {text!r}") from None
    if not values or not all(0.0 < v < 1.0 for v in values) or len(values) > 9:
        raise argparse.ArgumentTypeError(f"must be 1-9 proportions in (0, 1) separated by commas, got {text!r}")
    return values


def register(subparsers) -> None:
    """Add the ``psychometric`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m analysis`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "psychometric", help="psychometric fits (threshold, slope, lapse, PSE, JND) of forced-choice data",
        description="Fit psi(x) = gamma + (1 - gamma - lambda) F(x) by maximum likelihood to DATA: a study folder "
                    "of psychophysics sessions or a CSV with columns intensity and correct (0/1), optional subject "
                    "and condition. The threshold is the stimulus where F = 0.5; its interval is the profile "
                    "likelihood's. Writes fit.json (the fit of all trials pooled, and every group, with their "
                    "flags), fits.csv (per subject and condition, and pooled) and the figures into --out. Sessions "
                    "are pooled only when they are the same measurement (task, stimulus, scale, unit, reference).")
    p.add_argument("data", metavar="DATA", help="study data folder, one subject's folder, or a CSV file")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created; new or empty)")
    p.add_argument("--force", action="store_true", help="write into --out even if it holds earlier results")
    p.add_argument("--alternatives", type=int, default=None, metavar="N",
                   help="n of the n-AFC task: guess rate 1/N; 1 for yes/no or 'which was harder?' (guess rate 0). "
                        "Default: the sessions' experiment.alternatives (required for a CSV)")
    p.add_argument("--function", choices=FUNCTIONS, default="logistic",
                   help="F: logistic, cumulative normal or Weibull (intensities > 0) (default logistic)")
    p.add_argument("--lapse", type=_lapse, default=None, metavar="free|RATE",
                   help="lapse rate: 'free' (fitted in [0, 0.1], the default) or a fixed rate such as 0")
    p.add_argument("--lower-asymptote", choices=("auto", "free", "lapse", "zero"), default="auto",
                   help="yes/no and 'which was harder?' tasks (--alternatives 1): 'free' fits the false-alarm rate "
                        "(psignifit's and Palamedes' yes/no), 'lapse' sets the lower asymptote to the fitted lapse "
                        "rate (gamma = lambda: a lapse flips an answer either way; psignifit's equal asymptote), "
                        "'zero' fixes it at 0. Default 'auto': 'lapse' for a 'which was harder?' session, 'free' "
                        "otherwise. Ignored for n-AFC tasks, whose guess rate is 1/N")
    p.add_argument("--bayesian", action="store_true",
                   help="a Bayesian fit (psignifit 4's priors and beta-binomial overdispersion eta): maximum a "
                        "posteriori estimates and credible intervals instead of maximum likelihood")
    p.add_argument("--threshold-at", type=_proportions, default=(), metavar="P[,P...]",
                   help="also report the stimulus where the proportion correct (or 'yes') is P, with its interval "
                        "(psignifit's threshold(pc)), e.g. 0.75,0.9")
    p.add_argument("--compare", action="store_true",
                   help="with two or more conditions: fit them together with a shared slope and lapse rate and test "
                        "whether their thresholds differ and whether the slopes may be shared (likelihood ratio, "
                        "Palamedes' model comparison)")
    p.add_argument("--separately", action="store_true",
                   help="fit sessions that are different measurements (scale, stimulus, reference, ...) each on "
                        "its own instead of refusing to pool them")
    p.add_argument("--bootstrap", type=int, default=1000, metavar="R",
                   help="parametric bootstrap resamples for the intervals and the deviance test (default 1000; 0: none)")
    p.add_argument("--ci", type=float, default=0.95, help="confidence level of the intervals (default 0.95)")
    p.add_argument("--reference", type=float, default=None, metavar="X",
                   help="reference stimulus of a discrimination task, for the Weber fraction (default: the "
                        "sessions' experiment.reference)")
    p.add_argument("--intensity-label", default=None, metavar="TEXT",
                   help="x axis label with its unit, e.g. 'comparison stiffness (N/m)'")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap (default 0)")
    p.add_argument("--no-figures", action="store_true", help="tables without figures")
    with_examples(p, "hfam-analysis psychometric DATA --out FITS",
                  "hfam-analysis psychometric trials.csv --alternatives 2 --function weibull --out FITS",
                  "hfam-analysis psychometric jnd.csv --alternatives 1 --reference 500 --lapse 0 --out FITS",
                  "hfam-analysis psychometric DATA --compare --threshold-at 0.75 --out FITS",
                  "hfam-analysis psychometric DATA --separately --bayesian --out FITS")
    p.set_defaults(func=Body("analysis.cli_psychometric", "run"))
