"""``python -m analysis adjustment DATA --out DIR`` and ``python -m analysis magnitude DATA --out DIR``: the
method of adjustment's PSE, spread and constant error; magnitude estimation's Stevens exponents.

The parsers (light: imported for ``--help``); the bodies are :mod:`analysis.cli_scaling`.
"""

from __future__ import annotations

from plumbing.cliargs import with_examples
from plumbing.dispatch import Body


def _common(p) -> None:
    p.add_argument("data", metavar="DATA", help="study data folder (or one subject's folder)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (new, or --force)")
    p.add_argument("--force", action="store_true", help="replace earlier results in --out")
    p.add_argument("--ci", type=float, default=0.95, help="confidence level of the intervals (default 0.95)")
    p.add_argument("--no-figures", action="store_true", help="tables without figures")


def register_adjustment(subparsers) -> None:
    """Add the ``adjustment`` command."""
    p = subparsers.add_parser(
        "adjustment", help="method of adjustment: PSE, spread (JND estimate) and constant error",
        description="Per subject and condition and pooled over subjects: the point of subjective equality (the "
                    "geometric mean of the matches, with its t interval), the spread (SD of the log settings; JND "
                    "estimate 0.6745 SD: the Weber fraction), the constant error (PSE - reference) and the error of "
                    "the starting side; with several conditions, the block position as a factor (ANOVA). Writes "
                    "subjects.csv, pooled.csv, trials.csv, order_effects.csv, summary.json and the figures.")
    _common(p)
    with_examples(p, "hfam-analysis adjustment DATA --out MATCHES")
    p.set_defaults(func=Body("analysis.cli_scaling", "run_adjustment"))


def register_magnitude(subparsers) -> None:
    """Add the ``magnitude`` command."""
    p = subparsers.add_parser(
        "magnitude", help="magnitude estimation: Stevens' power law per subject and pooled",
        description="Fits log number = log k + exponent log stimulus per subject and condition (OLS, t "
                    "intervals), normalises the numbers by each subject's geometric mean (modulus equalisation), "
                    "and pools: the mean exponent over subjects with its interval and the group curve through the "
                    "geometric means; with several conditions, the block position as a factor. Writes "
                    "subjects.csv, pooled.csv, trials.csv, order_effects.csv, summary.json and the log-log figures.")
    _common(p)
    with_examples(p, "hfam-analysis magnitude DATA --out SCALES")
    p.set_defaults(func=Body("analysis.cli_scaling", "run_magnitude"))
