"""``python -m devices calibrate``: calibrate a real board (encoder zero, accelerometer and grip offsets).

Hold the handle still at a known height (``--known-position-m``, m above the wall height 0; e.g. resting on
its lower stop) with the grip not held, then run this: the encoder zero (eq. 3.3) and the sensor offsets
are measured at zero current and stored per device id in the calibration file, which the serial driver
loads on every open (``?calibration=FILE`` or ``$HFAM_CALIBRATION``). docs/bringup.md, "Calibration".

The body; the parser is :mod:`devices.cli_calibrate_parser`.
"""

from __future__ import annotations


from plumbing.fileio import check_output_file

from .hardware.bringup import calibrate, existing_entry
from .registry import make_device


def run_command(args) -> int:
    """Open the board, calibrate it at zero current, store and print the result; 0 on success."""


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
