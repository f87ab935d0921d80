"""``python -m analysis synthetic OUT``: write a synthetic study folder (for rehearsing the report).

The parser (light: imported for ``--help``); the body is :mod:`analysis.cli_synthetic`.
"""

from __future__ import annotations

from plumbing.dispatch import Body


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
    p.set_defaults(func=Body('analysis.cli_synthetic', 'run'))

