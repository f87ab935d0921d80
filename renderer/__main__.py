"""``python -m renderer <command>``: each command lives in its own module with ``register(subparsers)``."""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from devices.base import DeviceError

# command modules; each defines register(subparsers) -> adds its parser with set_defaults(func=...)
COMMAND_MODULES: tuple[str, ...] = ("renderer.cli_run", "renderer.demo.cli_demo")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog=_prog(), description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, DeviceError) as exc:  # DeviceError: a port that is absent or mute
        print(f"error: {exc}", file=sys.stderr)
        return 2


def run() -> None:
    """Entry point of ``python -m renderer`` and of the ``hfam-renderer`` console script: exit with main()'s code."""
    try:
        code = main()
        sys.stdout.flush()  # a reader that went away (``| head``) shows up here or in a print
    except BrokenPipeError:
        # recipe of the Python docs (signal module, "Note on SIGPIPE"): point stdout at devnull so the
        # interpreter's final flush cannot raise again, and exit 1 without a traceback
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        sys.exit(1)
    sys.exit(code)


def _prog() -> str:
    """``hfam-renderer`` when run as the console script, else ``python -m renderer`` (for usage and error lines)."""
    name = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    return name if name.startswith("hfam-") else "python -m renderer"


if __name__ == "__main__":
    run()
