"""``python -m stimuli show``: plot an HFAM library like thesis Figure 4.8.

The parser (light: imported for ``--help``); the body is :mod:`stimuli.cli_show`.
"""

from __future__ import annotations

from pathlib import Path

from plumbing.cliargs import with_examples
from plumbing.dispatch import Body


def register(subparsers) -> None:
    """Add the ``show`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m stimuli`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "show",
        help="plot an HFAM library (accelerations and currents per velocity/grip) to a PNG",
        description="Print a summary of an HFAM library and plot its desired accelerations and current "
                    "transients per velocity and grip level (like thesis Figure 4.8).",
    )
    p.add_argument("library", type=Path, help="library file (.npz)")
    p.add_argument("--out", type=Path, default=None, help="PNG to write (default: next to the library, .png)")
    p.add_argument("--force", action="store_true", help="overwrite the PNG, SVG and .plot.csv if they exist")
    with_examples(p, 'hfam-stimuli show LIB.npz --out LIB.png')
    p.set_defaults(func=Body('stimuli.cli_show', 'run'))

