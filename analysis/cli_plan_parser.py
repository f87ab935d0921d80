"""``python -m analysis plan --dz D | --pilot DATA --out PLAN``: how many subjects the next study needs.

The parser (light: imported for ``--help``); the body is :mod:`analysis.cli_plan`.
"""

from __future__ import annotations

from plumbing.cliargs import with_examples
from plumbing.dispatch import Body

from analysis.config import DEFAULT_MARGIN, DEFAULT_REFERENCE

# the report's design: 12 samples of the default catalog, every pair tested, each against the reference
DEFAULT_PAIRS = 66
DEFAULT_EQUIVALENCE = 11



def register(subparsers) -> None:
    """Add the ``plan`` command (parser only: no numpy/scipy/statsmodels imported here).

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m analysis`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "plan", help="number of subjects for the next study (difference and equivalence tests)",
        description="Subjects needed for a target power: for two-sided paired t-tests at an assumed d_z "
                    "(--dz) or at every pair's d_z observed in a pilot study folder (--pilot, with its 95 % CI), "
                    "and for paired TOST equivalence at ±--margin rating points; α is Holm-corrected over the "
                    "planned comparisons (planned at α/m, Holm's first step). Numbers from statsmodels' "
                    "TTestPower. Prints one line per comparison and writes plan.csv and a power-curve figure "
                    "into --out.")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--dz", type=float, metavar="D", help="assumed effect size Cohen's d_z of a difference (1)")
    src.add_argument("--pilot", metavar="DATA", help="pilot study folder (the study's format): observed d_z per pair")
    p.add_argument("--out", required=True, metavar="PLAN", help="folder for plan.csv and fig_power_curves.*")
    p.add_argument("--force", action="store_true", help="replace the files of an earlier plan in --out")
    p.add_argument("--power", type=float, default=0.8, help="target power of every comparison (default 0.8)")
    p.add_argument("--alpha", type=float, default=0.05, help="family-wise α, Holm over the planned comparisons "
                                                             "(default 0.05)")
    p.add_argument("--comparisons", type=int, default=None, metavar="M",
                   help=f"planned difference tests (Holm family; default: every pair, {DEFAULT_PAIRS} for the "
                        "default 12-sample catalog)")
    p.add_argument("--equivalence-comparisons", type=int, default=None, metavar="M",
                   help=f"planned equivalence tests (default: every sample against the reference, "
                        f"{DEFAULT_EQUIVALENCE})")
    p.add_argument("--margin", type=float, default=DEFAULT_MARGIN,
                   help=f"equivalence margin, ± rating points (default {DEFAULT_MARGIN})")
    p.add_argument("--sd-diff", type=float, default=1.0, metavar="S",
                   help="with --dz: SD of the per-subject differences, rating points, for the equivalence plan "
                        "(default 1.0; a pilot gives its own)")
    p.add_argument("--reference", default=DEFAULT_REFERENCE,
                   help=f"with --pilot: the equivalence tests' reference sample (default {DEFAULT_REFERENCE})")
    with_examples(p, "python -m analysis plan --dz 0.5 --out PLAN",
                  "python -m analysis plan --pilot PILOT_DATA --margin 0.5 --power 0.9 --out PLAN --force")
    p.set_defaults(func=Body("analysis.cli_plan", "run"))
