"""``python -m analysis export-bids DATA --out DIR``: the body (parser: :mod:`analysis.cli_export_bids_parser`).
The dataset is written into a staged folder swapped in whole (:mod:`plumbing.outdir`)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from plumbing.outdir import output_folder

from analysis.bids import export


def run(args: argparse.Namespace) -> int:
    """The ``export-bids`` command; returns the exit code."""
    if not args.no_motion and not (math.isfinite(args.motion_rate_hz) and 0 < args.motion_rate_hz <= 100_000):
        raise ValueError(f"--motion-rate-hz must be in (0, 100000] Hz, got {args.motion_rate_hz}")
    if not Path(args.data).is_dir():
        raise ValueError(f"{args.data}: not a folder (give the study's data folder)")
    if Path(args.out).resolve() == Path(args.data).resolve() or Path(args.data).resolve() in Path(args.out).resolve().parents:
        raise ValueError(f"--out {args.out} must not be inside the data folder {args.data}")
    with output_folder(args.out, args.force) as folder:
        done = export(args.data, folder.path, None if args.no_motion else args.motion_rate_hz, args.name)
    print(f"BIDS dataset: {done['subjects']} subject(s), task(s) {', '.join(done['tasks'])}, {done['files']} data "
          f"files; wrote {args.out}")
    return 0
