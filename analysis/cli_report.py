"""``python -m analysis report DATA --out REPORT``: the command; the report itself is :mod:`analysis.report`."""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from analysis.config import DEFAULT_MARGIN, DEFAULT_REFERENCE, AnalysisConfig


def run(args: argparse.Namespace) -> int:
    """The ``report`` command: analyse the study folder and write tables, figures and report.md/.html; returns the exit code."""
    cfg = AnalysisConfig(reference=args.reference, margin=args.margin, group=args.group, alpha=args.alpha)
    out = Path(args.out)
    if out.resolve() == Path(args.data).resolve():
        raise ValueError(f"--out {out} must not be the data folder {args.data}")
    if out.is_file() or (out.is_dir() and any(out.iterdir()) and not args.force):
        raise ValueError(f"{out} exists and is not empty; not overwriting an earlier report: choose another --out "
                         "or pass --force to replace it")
    from analysis.load import AnalysisWarning  # deferred: keeps `--help` fast (a command loads only what it runs)
    from analysis.pipeline import analyse  # deferred: keeps `--help` fast (a command loads only what it runs)
    from analysis.report import write_report  # deferred: pandas, matplotlib and statsmodels behind it (~2 s)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", AnalysisWarning)
        res = analyse(args.data, cfg)
        written = write_report(res, out, figures=not args.no_figures, target_v_m_s=args.velocity)
    for w in caught:
        if issubclass(w.category, AnalysisWarning):
            print(f"warning: {w.message}", file=sys.stderr)
    for note in written["notes"]:
        print(f"note: {note}", file=sys.stderr)
    print(f"wrote {len(written['tables'])} tables, {len(written['figures'])} figures, "
          f"{written['md']} and {written['html']}")
    return 0


class _Renamed(argparse._StoreAction):
    """Accepts the old spelling (second option string) with a deprecation notice (grammar: devices/cliargs.py;
    analysis imports no other package, so this is its own copy)."""

    def __call__(self, parser, namespace, values, option_string=None):
        if option_string is not None and option_string != self.option_strings[0]:
            print(f"warning: {option_string} is deprecated; use {self.option_strings[0]} (the old spelling is "
                  "accepted until the next release)", file=sys.stderr)
        super().__call__(parser, namespace, values, option_string)


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
    p.add_argument("--velocity-m-s", "--velocity", type=float, default=None, metavar="V", dest="velocity",
                   action=_Renamed, help="common incoming velocity for Figure 4.20 in m/s (default: median of all "
                                         "taps)")
    p.add_argument("--no-figures", action="store_true", help="tables and report without figures")
    p.epilog = "example: hfam-analysis report DATA --out REPORT --reference wood_on_foam --margin 0.5"
    p.set_defaults(func=run)
