"""``python -m analysis synthetic OUT``: write a synthetic study folder (for rehearsing the report)."""

from __future__ import annotations

import argparse
from pathlib import Path

from plumbing.outdir import output_folder

from analysis.synthetic import write_synthetic_study


#: the most synthetic subjects (a typo such as 10^8 would fill the disk); far beyond any study's size
MAX_SUBJECTS = 1000


def run(args: argparse.Namespace) -> int:
    """The ``synthetic`` command: write synthetic subject folders in the study's data format; returns the exit code."""

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out} is a file, not a folder; synthetic data is written into a new or empty folder")
    if out.exists() and any(out.iterdir()):
        raise ValueError(f"{out} is not empty; synthetic data is only written into a new or empty folder")
    if not 1 <= args.subjects <= MAX_SUBJECTS:
        raise ValueError(f"--subjects must be 1..{MAX_SUBJECTS}, got {args.subjects}")
    # written beside OUT and swapped in whole, one writer at a time (plumbing.outdir): an interrupted run leaves
    # no half-written study behind, and a study's data is refused as OUT
    # (no marker file: the folder is a study's data, which no command's --force replaces)
    with output_folder(out, False, products=("*",), command="analysis synthetic") as folder:
        folders = write_synthetic_study(folder.path, args.subjects, seed=args.seed, traces=args.traces)
    print(f"wrote {len(folders)} synthetic subject folders into {out} (pipeline test data, not a model of "
          "human perception)")
    return 0


