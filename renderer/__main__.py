"""``python -m renderer <command>``: render a virtual wall, or run the virtual-wall demo."""

from __future__ import annotations

from devices.dispatch import Command, main as dispatch, run_as_script

#: the commands, registered without importing them (``--help`` stays fast); each module has ``register(subparsers)``
COMMANDS = (
    Command("run", "renderer.cli_run", "render a virtual wall under a simulated or real user tapping"),
    Command("demo", "renderer.demo.cli_demo",
            "virtual-wall demo: proportional walls vs pulse, sinusoid, HFAM and a real sample"),
)


def main(argv=None) -> int:
    """Run ``python -m renderer`` with ``argv`` (default: the command line); returns the exit code."""
    return dispatch("python -m renderer", __doc__.splitlines()[0], COMMANDS, argv)


if __name__ == "__main__":
    run_as_script(main)
