"""``python -m devices record``: tap a (simulated) real sample and save reference handle accelerations."""

from __future__ import annotations

import math

import numpy as np

from plumbing.cliargs import add_renamed, with_examples
from plumbing.fileio import check_output_file


def _velocities(text: str) -> list[float]:
    try:
        vels = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"--velocities: expected comma-separated m/s values, got {text!r}") from None
    if not vels or any(not (math.isfinite(v) and v > 0) for v in vels):
        raise ValueError(f"--velocities: values must be positive finite m/s, got {text!r}")
    return vels


def register(subparsers) -> None:
    """Add the ``record`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m devices`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "record", help="tap a sample and record 100 ms of handle acceleration per tap (CSV)",
        description="Tap a sample once per velocity with the motor unpowered and save the handle acceleration "
                    "around each impact, at the servo rate, as a long-format CSV "
                    "(tap, incoming_velocity_m_s, t_s, accel_m_s2; t_s relative to impact). "
                    "With a simulated device the simulated hand taps the simulated sample; the impact is the "
                    "first servo tick in contact (true state) and the incoming velocity is measured from the "
                    "encoder over the 5 ms before impact.")
    p.add_argument("--device", default="sim", help="device string: sim, sim:lti, sim:<params file>, serial:<port>, "
                                                  "hid:<vid>:<pid> (default sim)")
    p.add_argument("--sample", default="wood_on_foam",
                   help="simulated sample under the stylus: wood, wood_on_foam, foam, placeholder (sim only)")
    add_renamed(p, "--velocities-m-s", "--velocities", dest="velocities", required=True, help="comma-separated tap speeds in m/s, e.g. 0.05,0.1,0.2")
    add_renamed(p, "--grip-N", "--grip", dest="grip", type=float, default=2.0, help="simulated grip force in N (default 2)")
    p.add_argument("--window-s", type=float, default=0.1, help="capture length per tap in s (default 0.1)")
    p.add_argument("--pre-s", type=float, default=0.005, help="capture before impact in s (default 0.005)")
    p.add_argument("--seed", type=int, default=0, help="sensor-noise seed of the simulated device")
    p.add_argument("--out", required=True, help="output CSV file")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    with_examples(p, 'hfam-devices record --device sim --sample wood_on_foam --velocities-m-s 0.05,0.1,0.2 --grip-N 2 --out taps.csv')
    p.set_defaults(func=run)


def run(args) -> int:
    """The ``record`` command: tap the sample once per velocity (motor off) and write the tap CSV; returns the exit code."""
    from .recording import (  # deferred: keeps `--help` fast (a command loads only what it runs)
        record_taps,
        write_tap_recording,
    )
    from .limits import check_grips, check_tap_speeds  # deferred: keeps `--help` fast (a command loads only what it runs)
    from .registry import make_device  # deferred: keeps `--help` fast (a command loads only what it runs)

    check_output_file(args.out, args.force)   # a folder, a path below a file, an existing file: before tapping
    vels = _velocities(args.velocities)
    if not (math.isfinite(args.grip) and args.grip >= 0):
        raise ValueError(f"--grip: must be >= 0 N, got {args.grip}")
    options = {"seed": args.seed} if args.device.split(":")[0] == "sim" else {}
    dev = make_device(args.device, **options)
    with dev:
        check_grips(dev.info, [args.grip], "--grip-N")
        check_tap_speeds(vels, "--velocities-m-s")   # 3 m/s saved a saturated tap
        if hasattr(dev, "set_sample"):
            dev.set_sample(args.sample)
        taps = record_taps(dev, vels, grip_N=args.grip, window_s=args.window_s, pre_s=args.pre_s)
        fs = dev.info.servo_rate_hz
    path = write_tap_recording(args.out, taps, fs)
    for i, (v, t, a) in enumerate(taps):
        print(f"tap {i}: incoming {v:.4f} m/s, peak |accel| {np.max(np.abs(a)):.2f} m/s^2")
    print(f"wrote {len(taps)} taps x {taps[0][1].size} samples at {fs:g} Hz to {path}")
    return 0
