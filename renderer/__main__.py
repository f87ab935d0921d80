"""``python -m renderer <command>``: render a virtual wall, run the virtual-wall demo or a teleoperation session."""

from __future__ import annotations

from plumbing.dispatch import Command, run_as_script
from plumbing.dispatch import main as dispatch

#: the commands, listed without importing them; each names its parser module (``register(subparsers)``, light),
#: whose parser names the body that runs (plumbing.dispatch.Body)
COMMANDS = (
    # one BLAS thread, as every command (plumbing.dispatch): the servo loop makes no BLAS call, and BLAS worker
    # threads would spin on the other core
    Command("run", "renderer.cli_run_parser", "render a virtual wall under a simulated or real user tapping",
            preload=("renderer.loop", "devices.registry")),
    Command("demo", "renderer.demo.cli_demo_parser",
            "virtual-wall demo: proportional walls vs pulse, sinusoid, HFAM and a real sample"),
    Command("teleop", "renderer.teleop.cli_teleop", "run a simulated teleoperation session (thesis ch. 5)"),
    Command("teleop-sweep", "renderer.teleop.cli_teleop",
            "lambda sweep with/without cancellation and stabilisers (Fig. 5.11)"),
    Command("teleop-servo-study", "renderer.teleop.cli_teleop",
            "section 5.7's targets at each servo bandwidth, slave handle re-identified at each"),
    Command("timing-check", "renderer.cli_timing_check_parser",
            "check this machine's servo timing (cyclictest-like)"),
    Command("compile-sim", "renderer.cli_compile_sim_parser", "compile the simulated closed loop ahead of time (fast sim runs)"),
)


def main(argv=None) -> int:
    """Run ``python -m renderer`` with ``argv`` (default: the command line); returns the exit code."""
    return dispatch("python -m renderer", __doc__.splitlines()[0], COMMANDS, argv)


def run() -> None:
    """Entry point of ``python -m renderer`` and of the ``hfam-renderer`` console script: exit with main()'s code."""
    run_as_script(main)


if __name__ == "__main__":
    run()
