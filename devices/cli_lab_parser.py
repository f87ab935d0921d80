"""``python -m devices list`` (every device this machine can see) and ``python -m devices probe DEVICE`` (a
short, safe check of one).

The parser (light: imported for ``--help``); the body is :mod:`devices.cli_lab`.
"""

from __future__ import annotations

import argparse

from plumbing.cliargs import with_examples
from plumbing.dispatch import Body


def _pulse(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--pulse-N must be a number, got {text!r}") from None
    if not 0 < value <= 1.0:
        raise argparse.ArgumentTypeError(f"--pulse-N must be in (0, 1] N (a small check, not a test of limits), "
                                         f"got {text!r}")
    return value


def register(subparsers) -> None:
    """Add the ``list`` and ``probe`` commands.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m devices`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "list", help="list the haptic devices this machine can see (serial, HID, FTDI, vendor libraries)",
        description="Serial ports, USB HID devices, Novint Falcons on USB, and whether the Force Dimension and "
                    "OpenHaptics libraries are installed (with the reason when not), each with the device string "
                    "that opens it. Opens nothing.")
    with_examples(p, "hfam-devices list")
    p.set_defaults(func=Body("devices.cli_lab", "run_list"))

    q = subparsers.add_parser(
        "probe", help="a short, safe check of one device: workspace, sensors, and a small force pulse after a prompt",
        description="Open the device with zero force, report its specifications, read 0.5 s of samples (positions "
                    "finite, inside the workspace, round trip), then, only after you answer 'y' (or with --yes), "
                    "push 0.1 s up with --pulse-N and report the motion. Hold the handle lightly.")
    q.add_argument("device", help="device string, e.g. falcon:0, inverse3:/dev/ttyACM0, 'touch:Default Device'")
    q.add_argument("--pulse-N", type=_pulse, default=0.5, help="the pulse's force, N (default 0.5, at most 1)")
    q.add_argument("--yes", action="store_true", help="give the pulse without asking")
    q.add_argument("--no-pulse", action="store_true", help="no force at all (read only)")
    with_examples(q, "hfam-devices probe falcon:0?firmware=nvent_firmware.bin", "hfam-devices probe falcon:emulator --yes")
    q.set_defaults(func=Body("devices.cli_lab", "run_probe"))
