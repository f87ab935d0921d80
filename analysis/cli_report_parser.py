"""``python -m analysis report DATA --out REPORT``: analyse a study folder (the report itself is :mod:`analysis.report`).

The parser (light: imported for ``--help``); the body is :mod:`analysis.cli_report`.
"""

from __future__ import annotations

from analysis.config import DEFAULT_MARGIN, DEFAULT_REFERENCE
from plumbing.cliargs import add_renamed
from plumbing.dispatch import Body


def register(subparsers) -> None:
    """Add the ``report`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m analysis`` sub-command parsers.
    """
    p = subparsers.add_parser("report", help="analyse a study folder: tables, figures, report.md/.html",
                              description="Analyse DATA (folder of subject folders with session.json and "
                                          "trials.csv) and write tables, figures, report.md and report.html "
                                          "into REPORT.")
    p.add_argument("data", metavar="DATA", help="study data folder (one subfolder per subject)")
    p.add_argument("--out", required=True, metavar="REPORT", help="output folder (created; new or empty)")
    p.add_argument("--force", action="store_true", help="write into --out even if it holds an earlier report")
    p.add_argument("--reference", default=DEFAULT_REFERENCE,
                   help=f"reference sample of the equivalence tests (default {DEFAULT_REFERENCE})")
    p.add_argument("--margin", type=float, default=DEFAULT_MARGIN,
                   help=f"equivalence margin in rating points, set before looking (default {DEFAULT_MARGIN})")
    p.add_argument("--group", default="both", choices=("both", "all", "experienced"),
                   help="subject groups to test: all subjects, experienced (experience != none) or both (default)")
    p.add_argument("--alpha", type=float, default=0.05, help="significance level (default 0.05)")
    add_renamed(p, "--velocity-m-s", "--velocity", type=float, default=None, metavar="V", dest="velocity",
                help="common incoming velocity for Figure 4.20 in m/s (default: median of all "
                                         "taps)")
    p.add_argument("--no-figures", action="store_true", help="tables and report without figures")
    p.add_argument("--no-models", action="store_true",
                   help="skip the mixed and ordinal models of every attempt (section Models says so)")
    p.epilog = "example: hfam-analysis report DATA --out REPORT --reference wood_on_foam --margin 0.5"
    p.set_defaults(func=Body('analysis.cli_report', 'run'))

