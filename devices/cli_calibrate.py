"""``python -m devices calibrate``: calibrate a real board (encoder zero, accelerometer and grip offsets).

Hold the handle still at a known height (``--known-position-m``, m above the wall height 0; e.g. resting on
its lower stop) with the grip not held, then run this: the encoder zero (eq. 3.3) and the sensor offsets
are measured at zero current and stored per device id in the calibration file, which the serial driver
loads on every open (``?calibration=FILE`` or ``$HFAM_CALIBRATION``). docs/bringup.md, "Calibration".
"""

from __future__ import annotations

import argparse
import math

from plumbing.cliargs import with_examples
from plumbing.fileio import check_output_file


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--known-position-m must be a number, got {text!r}") from None
    if not (math.isfinite(value) and abs(value) <= 0.1):
        raise argparse.ArgumentTypeError(f"--known-position-m must be within +-0.1 m, got {text!r}")
    return value


def _samples(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--samples must be an integer, got {text!r}") from None
    if not 10 <= value <= 100_000:
        raise argparse.ArgumentTypeError(f"--samples must be 10..100000, got {text!r}")
    return value


def register(subparsers) -> None:
    """Add the ``calibrate`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m devices`` sub-command parsers.
    """
    p = subparsers.add_parser("calibrate", help="calibrate a real board: encoder zero, accelerometer and grip offsets",
                              description=" ".join(__doc__.split("\n\n")[1].split()))
    p.add_argument("--device", required=True, help="the board: serial:<port> (e.g. serial:/dev/ttyACM0)")
    p.add_argument("--out", required=True, help="calibration JSON file (other boards' entries are kept)")
    p.add_argument("--force", action="store_true", help="replace this board's entry if --out already holds one")
    p.add_argument("--known-position-m", type=_finite, default=0.0,
                   help="height the handle is held at, m above the wall height (default 0)")
    p.add_argument("--samples", type=_samples, default=200, help="reads averaged per step (default 200)")
    p.add_argument("--skip-accel", action="store_true", help="keep the accelerometer offset")
    p.add_argument("--skip-grip", action="store_true", help="keep the grip-sensor offset (e.g. the grip is held)")
    with_examples(p, "hfam-devices calibrate --device serial:/dev/ttyACM0 --known-position-m 0.0 --out calibration.json")
    p.set_defaults(func=run_command)


def run_command(args) -> int:
    """Open the board, calibrate it at zero current, store and print the result; 0 on success."""
    from devices.registry import make_device  # deferred: keeps `--help` fast (loads only the driver asked for)

    from .hardware.bringup import calibrate, existing_entry  # deferred: keeps `--help` fast (numpy)

    if args.device.split(":", 1)[0] != "serial":
        raise ValueError(f"--device {args.device!r}: calibrate talks to a serial board (serial:<port>)")
    check_output_file(args.out, True)  # a folder or a path below a file is refused; the file itself is merged
    with make_device(args.device) as dev:
        if existing_entry(args.out, dev.wire_info.device_id) and not args.force:
            raise ValueError(f"{args.out} already holds a calibration of {dev.wire_info.device_id}; not "
                             "overwriting it: pass --force to replace it, or choose another --out")
        rec = calibrate(dev, args.out, args.known_position_m, args.samples, not args.skip_accel, not args.skip_grip)
    b, a, c = rec["before"], rec["after"], rec["calibration"]
    print(f"calibrated {rec['device_id']} ({args.samples} reads per step, zero current)")
    print(f"  position  {1000 * b['position_m_mean']:+.3f} mm -> {1000 * a['position_m_mean']:+.3f} mm "
          f"(held at {1000 * args.known_position_m:+.3f} mm); encoder zero {c['encoder_zero_counts']} counts")
    print(f"  accel     {b['accel_m_s2_mean']:+.3f} -> {a['accel_m_s2_mean']:+.3f} m/s^2 (sd {a['accel_m_s2_sd']:.3f}); "
          f"offset {c['accel_offset_counts']:.2f} counts")
    print(f"  grip      {b['grip_N_mean']:+.3f} -> {a['grip_N_mean']:+.3f} N (sd {a['grip_N_sd']:.3f}); "
          f"offset {c['grip_offset_counts']:.2f} counts")
    print(f"saved {rec['file']} (load it with --device 'serial:PORT?calibration={rec['file']}' or "
          "HFAM_CALIBRATION)")
    return 0
