"""``python -m devices record``: tap a (simulated) real sample and save reference handle accelerations."""

from __future__ import annotations

import math

import numpy as np

from plumbing.fileio import check_output_file

from .limits import check_grips, check_tap_speeds
from .recording import record_taps, write_tap_recording
from .registry import make_device


def _velocities(text: str) -> list[float]:
    try:
        vels = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"--velocities: expected comma-separated m/s values, got {text!r}") from None
    if not vels or any(not (math.isfinite(v) and v > 0) for v in vels):
        raise ValueError(f"--velocities: values must be positive finite m/s, got {text!r}")
    return vels


def run(args) -> int:
    """The ``record`` command: tap the sample once per velocity (motor off) and write the tap CSV; returns the exit code."""

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
