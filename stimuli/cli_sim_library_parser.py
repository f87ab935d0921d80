"""``python -m stimuli sim-library``: rebuild the shipped default library from the sim device.

The parser (light: imported for ``--help``); the body is :mod:`stimuli.cli_sim_library`.
"""

from __future__ import annotations

from pathlib import Path

from plumbing.cliargs import with_examples
from plumbing.dispatch import Body


def register(subparsers) -> None:
    """Add the ``sim-library`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m stimuli`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "sim-library",
        help="record simulated taps and build the shipped default library through the sim's LTI models",
        description="Recording simulated real taps and building the shipped default library from the sim device "
                    "(stimuli/libraries/wood_on_foam_sim.npz; see stimuli.hfam.pipeline).",
    )
    p.add_argument("--out", type=Path, required=True, help="library file to write (.npz)")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    with_examples(p, 'hfam-stimuli sim-library --out wood_on_foam_sim.npz')
    p.set_defaults(func=Body('stimuli.cli_sim_library', 'run'))

