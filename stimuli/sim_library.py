"""Recording simulated real taps and building the shipped default library from the sim device.

``python -m stimuli.sim_library --out stimuli/libraries/wood_on_foam_sim.npz`` regenerates
the library the default catalog's HFAM samples use: taps on the sim's
``wood_on_foam`` sample with the motor off (section 4.4.1 "Recording
Accelerations"), inverted through the sim's analytic LTI models
(``SimDevice.linear_model``) at five grip levels covering its grip sensor range.
This is a development tool: it imports ``devices.sim`` lazily, the library
code itself needs only ``devices.model``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from .hfam import BuildSettings, build_library, format_verification
from .recordings import Tap

DEFAULT_VELOCITIES_M_S = (0.03, 0.05, 0.07, 0.09, 0.11, 0.14, 0.17, 0.2, 0.25, 0.3)
DEFAULT_GRIPS_N = (0.0, 2.5, 5.0, 7.5, 10.0)


def record_sim_taps(velocities_m_s=DEFAULT_VELOCITIES_M_S, sample: str = "wood_on_foam", grip_N: float = 2.0,
                    pre_s: float = 0.005, post_s: float = 0.1, device=None, seed: int = 0) -> tuple[float, list[Tap]]:
    """Tap the sim's real ``sample`` with the motor off, one tap per velocity.

    Returns
    -------
    fs_hz : float
    taps : list of Tap
        Measured handle acceleration from ``pre_s`` before to ``post_s`` after
        the first in-contact sample (t = 0 there), tagged with the true
        incoming handle speed.
    """
    from devices.sim import SimDevice, TapTrajectory

    dev = device if device is not None else SimDevice(seed=seed)
    dev.set_sample(sample)
    dev.motor_enabled = False
    fs = dev.info.servo_rate_hz
    n_pre, n_post = int(round(pre_s * fs)), int(round(post_s * fs))
    taps = []
    with dev:
        for i, v in enumerate(velocities_m_s):
            dev.set_user(TapTrajectory(float(v), n_taps=1), grip_N=grip_N)
            acc, speeds, contact_at = [], [], None
            while not dev.trajectory_done:
                dev.command(0.0)
                acc.append(dev.read().accel_m_s2)
                speeds.append(abs(dev.true_state()["handle_velocity_m_s"]) if contact_at is None else 0.0)
                if contact_at is None and dev.in_contact:
                    contact_at = len(acc) - 1
                if contact_at is not None and len(acc) > contact_at + n_post:
                    break
            if contact_at is None or contact_at < n_pre + 1:
                raise RuntimeError(f"sim tap at {v} m/s did not hit the {sample} sample")
            a = np.array(acc[contact_at - n_pre: contact_at + n_post + 1])
            t = (np.arange(a.size) - n_pre) / fs
            taps.append(Tap(i, float(speeds[contact_at - 1]), t, a))
    return fs, taps


def build_sim_library(out=None, velocities_m_s=DEFAULT_VELOCITIES_M_S, grips_N=DEFAULT_GRIPS_N,
                      settings: BuildSettings | None = None, log=print):
    """Record sim taps and build (and optionally save) a library through the sim's LTI models."""
    from devices.sim import SimDevice

    dev = SimDevice()
    fs, taps = record_sim_taps(velocities_m_s, device=dev)
    models = [(f"sim linear_model(grip_N={g})", dev.linear_model(g)) for g in grips_N]
    # strong grips at high velocities need more than the 4 A peak (as in thesis Figure 4.13): scale those down
    settings = settings or BuildSettings(peak_current_A=dev.info.current_peak_A, scale_to_limit=True)
    lib, report = build_library(taps, fs, models, settings, force_per_amp_N_A=dev.info.force_per_amp_N_A, log=log,
                                provenance={"source_files": {"recordings": "simulated wood_on_foam taps, SimDevice()",
                                                             "models": [n for n, _ in models]},
                                            "device": "sim"})
    if log:
        log(format_verification(report))
    if out is not None:
        lib.save(out)
    return lib, report


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m stimuli.sim_library", description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True, help="library file to write (.npz)")
    args = p.parse_args(argv)
    build_sim_library(args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
