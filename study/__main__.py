"""``python -m study <command>``: run a blind realism session (sim rehearsal or real subjects)."""

from __future__ import annotations

from plumbing.dispatch import Command, run_as_script
from plumbing.dispatch import main as dispatch

#: the commands, listed without importing them; each names its parser module (``register(subparsers)``, light),
#: whose parser names the body that runs (plumbing.dispatch.Body)
COMMANDS = (
    # one BLAS thread, as every command (plumbing.dispatch): the session runs a servo loop, and a QUEST+ update's matrix-vector product split over
    # threads waits for them on a loaded machine (benchmarks/bench_adaptive.py)
    Command("run", "study.cli_run_parser", "run a blind realism or psychophysics session (sim rehearsal or real subjects)"),
    Command("simulate-observer", "study.cli_simulate_observer_parser",
            "run an adaptive method against a simulated observer"),
    Command("design", "study.cli_design_parser",
            "counterbalanced condition orders for the participant list (Williams or Latin square)"),
)


def main(argv=None) -> int:
    """Run ``python -m study`` with ``argv`` (default: the command line); returns the exit code."""
    return dispatch("python -m study", __doc__.splitlines()[0], COMMANDS, argv)


def run() -> None:
    """Entry point of ``python -m study`` and of the ``hfam-study`` console script: exit with main()'s code."""
    run_as_script(main)


if __name__ == "__main__":
    run()
