"""``python -m stimuli sim-library``: rebuild the shipped default library from the sim device."""

from __future__ import annotations

from plumbing.fileio import check_output_file

from .hfam.pipeline import build_sim_library


def run(args) -> int:
    """The ``sim-library`` command: build the shipped default library from the sim device; returns the exit code."""

    check_output_file(args.out, args.force)   # before building: never replace a user's file silently
    build_sim_library(args.out)
    print(f"wrote {args.out}")
    return 0
