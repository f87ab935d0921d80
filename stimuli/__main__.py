"""``python -m stimuli <command>``: build, show and rebuild HFAM transient libraries."""

from __future__ import annotations

from plumbing.dispatch import Command, run_as_script
from plumbing.dispatch import main as dispatch

#: the commands, listed without importing them; each names its parser module (``register(subparsers)``, light),
#: whose parser names the body that runs (plumbing.dispatch.Body)
COMMANDS = (
    Command("build-library", "stimuli.cli_build_parser", "build an HFAM transient library (section 4.4.1)"),
    Command("show", "stimuli.cli_show_parser", "plot an HFAM library (accelerations and currents per velocity/grip) to a PNG"),
    Command("sim-library", "stimuli.cli_sim_library_parser",
            "record simulated taps and build the shipped default library through the sim's LTI models"),
    Command("score-hfam", "stimuli.cli_score_parser",
            "score the open-loop and refined HFAM libraries against the real tap on the sim"),
)


def main(argv=None) -> int:
    """Run ``python -m stimuli`` with ``argv`` (default: the command line); returns the exit code."""
    return dispatch("python -m stimuli", __doc__.splitlines()[0], COMMANDS, argv)


def run() -> None:
    """Entry point of ``python -m stimuli`` and of the ``hfam-stimuli`` console script: exit with main()'s code."""
    run_as_script(main)


if __name__ == "__main__":
    run()
