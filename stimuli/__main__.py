"""``python -m stimuli <command>``: each command lives in its own module with ``register(subparsers)``."""

from __future__ import annotations

import argparse
import importlib
import sys

from devices.base import DeviceError

# command modules; each defines register(subparsers) -> adds its parser with set_defaults(func=...)
COMMAND_MODULES: tuple[str, ...] = ("stimuli.cli_build", "stimuli.cli_show")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m stimuli", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, DeviceError) as exc:  # DeviceError: a port that is absent or mute
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
