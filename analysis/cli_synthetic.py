"""``python -m analysis synthetic OUT``: write a synthetic study folder (for rehearsing the report)."""

from __future__ import annotations

import argparse
from pathlib import Path


def run(args: argparse.Namespace) -> int:
    """The ``synthetic`` command: write synthetic subject folders in the study's data format; returns the exit code."""
    from analysis.synthetic import (  # deferred: keeps `--help` fast (a command loads only what it runs)
        write_synthetic_study,
    )

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out} is a file, not a folder; synthetic data is written into a new or empty folder")
    if out.exists() and any(out.iterdir()):
        raise ValueError(f"{out} is not empty; synthetic data is only written into a new or empty folder")
    if args.subjects < 1:
        raise ValueError(f"--subjects must be >= 1, got {args.subjects}")
    folders = write_synthetic_study(out, args.subjects, seed=args.seed, traces=args.traces)
    print(f"wrote {len(folders)} synthetic subject folders into {out} (pipeline test data, not a model of "
          "human perception)")
    return 0


def register(subparsers) -> None:
    """Add the ``synthetic`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m analysis`` sub-command parsers.
    """
    p = subparsers.add_parser("synthetic", help="write a synthetic study folder in the study's data format",
                              description="Write synthetic subject folders (session.json, trials.csv and, for "
                                          "the first --traces subjects, per-attempt traces) into OUT.")
    p.add_argument("out", metavar="OUT", help="new or empty folder")
    p.add_argument("--subjects", type=int, default=16, help="number of subjects (default 16)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--traces", type=int, default=0, metavar="N",
                   help="write per-attempt traces for the first N subjects (default 0)")
    p.epilog = "example: hfam-analysis synthetic SYNTH --subjects 16 --traces 2"
    p.set_defaults(func=run)
