"""``python -m stimuli <command>``: build, show and rebuild HFAM transient libraries."""

from __future__ import annotations

from plumbing.dispatch import Command, main as dispatch, run_as_script

#: the commands, registered without importing them (``--help`` stays fast); each module has ``register(subparsers)``
COMMANDS = (
    Command("build-library", "stimuli.cli_build", "build an HFAM transient library (section 4.4.1)"),
    Command("show", "stimuli.cli_show", "plot an HFAM library (accelerations and currents per velocity/grip) to a PNG"),
    Command("sim-library", "stimuli.cli_sim_library",
            "record simulated taps and build the shipped default library through the sim's LTI models"),
)


def main(argv=None) -> int:
    """Run ``python -m stimuli`` with ``argv`` (default: the command line); returns the exit code."""
    return dispatch("python -m stimuli", __doc__.splitlines()[0], COMMANDS, argv)


def run() -> None:
    """Entry point of ``python -m stimuli`` and of the ``hfam-stimuli`` console script: exit with main()'s code."""
    run_as_script(main)


if __name__ == "__main__":
    run()
