"""``python -m analysis plan --dz D | --pilot DATA --out PLAN``: how many subjects the next study needs.

The body; the parser is :mod:`analysis.cli_plan_parser`.
"""

from __future__ import annotations

import argparse
import math
import warnings
from pathlib import Path

from plumbing.outdir import output_folder

from analysis.cli_plan_parser import DEFAULT_EQUIVALENCE, DEFAULT_PAIRS
from analysis.config import check_data_folder
from analysis.load import AnalysisWarning, load_study
from analysis.plan_report import write_plan
from analysis.power import PlanSettings, assumed_plan, pilot_plan, plan_line
from analysis.stats import rating_matrix

#: what the command writes into --out (a folder of these alone, without the output marker, was written by an
#: older version and is replaced by --force)
PLAN_FILES = ("plan.csv", "fig_power_curves.*")


def _given(value, default):
    """``value`` unless the flag was not given (None): 0 stays 0, so that the settings refuse it."""
    return default if value is None else value


def run(args: argparse.Namespace) -> int:
    """The ``plan`` command: write ``plan.csv`` and the power-curve figure into ``--out``, print one line per comparison."""

    if (args.dz is None) == (args.pilot is None):
        raise ValueError("give either --dz (an assumed effect) or --pilot DATA (a pilot study folder), not both "
                         "and not neither")
    if args.dz is not None and not math.isfinite(args.dz):
        raise ValueError(f"--dz must be a finite number (an effect size d_z), got {args.dz}")
    if args.dz is not None and args.dz == 0:
        raise ValueError("--dz must not be 0: there is no effect to detect")
    if not math.isfinite(args.sd_diff):
        raise ValueError(f"--sd-diff must be a finite number of rating points, got {args.sd_diff}")
    # written beside --out and swapped in whole, one writer at a time (plumbing.outdir): an interrupted plan
    # leaves the earlier one as it was; an --out that is, holds or lies in the pilot's data is refused
    folder = output_folder(args.out, args.force, inputs=[(args.pilot, "the pilot's data folder")],
                           command="analysis plan", own=PLAN_FILES).open()
    with folder:
        if args.pilot is not None:
            check_data_folder(args.pilot)
        plan, written, notes = _plan(args, folder.path)
    for r in plan.itertuples():
        print(plan_line(r))
    for n in notes:
        print(f"warning: {n}")
    print(f"wrote {', '.join(p.name for p in written)} into {folder.out}")
    return 0


def _plan(args: argparse.Namespace, out: Path):
    """The plan (from the pilot or the assumed effect) and the files written into ``out``."""
    if args.pilot is not None:

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
        if len(matrix.subjects) < 2:     # every row says why it has no sample size; the plan is still written
            print(f"warning: --pilot {args.pilot}: {len(matrix.subjects)} subject(s); a pilot needs 2 or more to "
                  "estimate d_z: no row gets a sample size (plan with --dz instead)")
        plan = pilot_plan(matrix, args.reference, settings)
    else:
        if not args.sd_diff > 0:
            raise ValueError(f"--sd-diff must be > 0 rating points, got {args.sd_diff}")
        settings = PlanSettings(power=args.power, alpha=args.alpha, margin=args.margin,
                                comparisons=_given(args.comparisons, DEFAULT_PAIRS),
                                equivalence_comparisons=_given(args.equivalence_comparisons, DEFAULT_EQUIVALENCE))
        plan = assumed_plan(args.dz, args.sd_diff, settings)

    notes: list[str] = []
    return plan, write_plan(plan, out, notes), notes
