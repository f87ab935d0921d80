"""``python -m devices calibrate``: calibrate a real board (encoder zero, accelerometer and grip offsets).

Hold the handle still at a known height (``--known-position-m``, m above the wall height 0; e.g. resting on
its lower stop) with the grip not held, then run this: the encoder zero (eq. 3.3) and the sensor offsets
are measured at zero current and stored per device id in the calibration file, which the serial driver
loads on every open (``?calibration=FILE`` or ``$HFAM_CALIBRATION``). docs/bringup.md, "Calibration".

The parser (light: imported for ``--help``); the body is :mod:`devices.cli_calibrate`.
"""

from __future__ import annotations

from plumbing.cliargs import integer, with_examples, within
from plumbing.dispatch import Body


def register(subparsers) -> None:
    """Add the ``calibrate`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m devices`` sub-command parsers.
    """
    p = subparsers.add_parser("calibrate", help="calibrate a real board: encoder zero, accelerometer and grip offsets",
                              description=" ".join(__doc__.split("\n\n")[1].split()).replace("``", ""))
    p.add_argument("--device", required=True, help="the board: serial:<port> (e.g. serial:/dev/ttyACM0)")
    p.add_argument("--out", required=True, help="calibration JSON file (other boards' entries are kept)")
    p.add_argument("--force", action="store_true", help="replace this board's entry if --out already holds one")
    p.add_argument("--known-position-m", type=within("--known-position-m", 0.1, "m"), default=0.0,
                   help="height the handle is held at, m above the wall height (default 0)")
    p.add_argument("--samples", type=integer("--samples", 10, 100_000), default=200, help="reads averaged per step (default 200)")
    p.add_argument("--skip-accel", action="store_true", help="keep the accelerometer offset")
    p.add_argument("--skip-grip", action="store_true", help="keep the grip-sensor offset (e.g. the grip is held)")
    with_examples(p, "hfam-devices calibrate --device serial:/dev/ttyACM0 --known-position-m 0.0 --out calibration.json")
    p.set_defaults(func=Body('devices.cli_calibrate', 'run_command'))
