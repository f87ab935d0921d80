"""``python -m analysis synthetic OUT``: write a synthetic study folder (for rehearsing the report)."""

from __future__ import annotations

import argparse
from pathlib import Path

from analysis.synthetic import write_synthetic_study


def run(args: argparse.Namespace) -> int:
    """The ``synthetic`` command: write synthetic subject folders in the study's data format; returns the exit code."""

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


