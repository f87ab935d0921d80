"""``python -m analysis plan --dz D | --pilot DATA --out PLAN``: how many subjects the next study needs."""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from plumbing.cliargs import with_examples

from analysis.config import DEFAULT_MARGIN, DEFAULT_REFERENCE, check_data_folder

# the report's design: 12 samples of the default catalog, every pair tested, each against the reference
DEFAULT_PAIRS = 66
DEFAULT_EQUIVALENCE = 11


def _given(value, default):
    """``value`` unless the flag was not given (None): 0 stays 0, so that the settings refuse it."""
    return default if value is None else value


def run(args: argparse.Namespace) -> int:
    """The ``plan`` command: write ``plan.csv`` and the power-curve figure into ``--out``, print one line per comparison."""
    from plumbing.fileio import check_output_dir  # deferred: keeps `--help` fast (a command loads what it runs)

    if (args.dz is None) == (args.pilot is None):
        raise ValueError("give either --dz (an assumed effect) or --pilot DATA (a pilot study folder), not both "
                         "and not neither")
    out = check_output_dir(args.out, args.force)
    if args.pilot is not None:
        check_data_folder(args.pilot)
    if args.dz is not None and args.dz == 0:
        raise ValueError("--dz must not be 0: there is no effect to detect")
    from analysis.power import PlanSettings, assumed_plan, pilot_plan, plan_line  # deferred: scipy/statsmodels

    if args.pilot is not None:
        from analysis.load import AnalysisWarning, load_study  # deferred: pandas/pyarrow, pilot mode only
        from analysis.stats import rating_matrix  # deferred: as above

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", AnalysisWarning)
            study = load_study(Path(args.pilot))
        for w in caught:
            if issubclass(w.category, AnalysisWarning):
                print(f"warning: {w.message}")
        if args.reference not in study.catalog:
            raise ValueError(f"--reference {args.reference!r} is not a sample of the pilot's catalog "
                             f"({', '.join(study.catalog)})")
        k = len(study.catalog)
        settings = PlanSettings(power=args.power, alpha=args.alpha, margin=args.margin,
                                comparisons=_given(args.comparisons, k * (k - 1) // 2),
                                equivalence_comparisons=_given(args.equivalence_comparisons, k - 1))
        matrix = rating_matrix(study)
        if len(matrix.subjects) < 2:
            raise ValueError(f"--pilot {args.pilot}: {len(matrix.subjects)} subject(s); a pilot needs 2 or more to "
                             "estimate d_z")
        plan = pilot_plan(matrix, args.reference, settings)
    else:
        if not args.sd_diff > 0:
            raise ValueError(f"--sd-diff must be > 0 rating points, got {args.sd_diff}")
        settings = PlanSettings(power=args.power, alpha=args.alpha, margin=args.margin,
                                comparisons=_given(args.comparisons, DEFAULT_PAIRS),
                                equivalence_comparisons=_given(args.equivalence_comparisons, DEFAULT_EQUIVALENCE))
        plan = assumed_plan(args.dz, args.sd_diff, settings)
    from analysis.plan_report import write_plan  # deferred: matplotlib

    written = write_plan(plan, out)
    for r in plan.itertuples():
        print(plan_line(r))
    print(f"wrote {', '.join(p.name for p in written)} into {out}")
    return 0


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
                    "(--dz) or at every pair's d_z observed in a pilot study folder (--pilot, with its 95 %% CI), "
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
    p.set_defaults(func=run)
