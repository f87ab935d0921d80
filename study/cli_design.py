"""``python -m study design``: condition orders for every participant (Latin square or Williams design).

The body; the parser is :mod:`study.cli_design_parser`. Written into a staged output folder (whole or not at
all, :mod:`plumbing.outdir`): ``design.csv``, ``design.md``, ``design.json``.
"""

from __future__ import annotations

import argparse
import json
import sys

from plumbing.fileio import atomic_write_text
from plumbing.outdir import output_folder

from .design.assign import DESIGN_CSV, assign, check_conditions, format_design, markdown, read_participants


def run(args: argparse.Namespace) -> int:
    """The ``design`` command; returns the exit code."""
    conditions = check_conditions(args.conditions.split(","))
    participants = read_participants(args.participants)
    result = assign(participants, conditions, args.design, args.seed)
    with output_folder(args.out, args.force) as folder:
        atomic_write_text(folder.path / DESIGN_CSV, format_design(result["rows"]))
        atomic_write_text(folder.path / "design.md", markdown(result))
        record = {k: v for k, v in result.items() if k != "rows"}
        record["participants"] = len(result["rows"])
        atomic_write_text(folder.path / "design.json", json.dumps(record, indent=2) + "\n")
    if result["incomplete"]:
        print(f"warning: {len(participants)} participants are not a multiple of the design's "
              f"{len(result['sequences'])} sequences: the last {result['incomplete']} form an incomplete block, "
              "so order is balanced only over the ones before", file=sys.stderr)
    print(f"{args.design} design: {len(result['sequences'])} orders of {len(conditions)} conditions for "
          f"{len(participants)} participants; wrote {args.out}/{DESIGN_CSV}, design.md, design.json")
    return 0
