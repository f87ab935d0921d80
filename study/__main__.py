"""``python -m study <command>``: run a blind realism session (sim rehearsal or real subjects)."""

from __future__ import annotations

from plumbing.dispatch import Command, main as dispatch, run_as_script

#: the commands, registered without importing them (``--help`` stays fast); each module has ``register(subparsers)``
COMMANDS = (
    Command("run", "study.cli_run", "run a blind realism session (sim rehearsal or real subjects)"),
    Command("simulate-observer", "study.cli_simulate_observer", "run an adaptive method against a simulated observer",
            blas_threads=1),
)


def main(argv=None) -> int:
    """Run ``python -m study`` with ``argv`` (default: the command line); returns the exit code."""
    return dispatch("python -m study", __doc__.splitlines()[0], COMMANDS, argv)


def run() -> None:
    """Entry point of ``python -m study`` and of the ``hfam-study`` console script: exit with main()'s code."""
    run_as_script(main)


if __name__ == "__main__":
    run()
