"""``python -m devices validate MODEL``: check an identified model against the device (thesis sec. 3.4.5):
ETFE agreement at several current magnitudes and the held-handle response to contact-like transients."""

from __future__ import annotations

import json
from pathlib import Path

import figstyle
from plumbing.fileio import check_output_file

from .identify.modelset import load_model_set
from .identify.validate_td import etfe_agreement, time_domain_figure, time_domain_validation
from .model import load_model
from .registry import check_device_spec, make_device
from .sim.device import SimDevice
from .sim.params import load_sim_params


def _load(path: Path, grip: float):
    """('nonlinear', SimParams) or ('zpk', ZpkModel) from a file or folder."""

    if path.is_dir():
        if (path / "model.json").is_file():
            path = path / "model.json"
        elif (path / "model_set.json").is_file():
            return "zpk", load_model_set(path).model_at(grip, "accel_m_s2"), str(path)
        else:
            raise FileNotFoundError(f"{path}: no model.json or model_set.json in this folder")
    if not path.is_file():
        raise FileNotFoundError(f"model file not found: {path}")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a JSON model file: {exc}") from None
    if isinstance(data, dict) and data.get("kind") == "zpk":
        return "zpk", load_model(path), str(path)
    return "nonlinear", load_sim_params(path), str(path)


def run_validate(args) -> int:
    """Run ``validate`` (see the parser's description); returns the exit code."""

    check_device_spec(args.device)
    if args.plot:
        check_output_file(args.plot, args.force, what="--plot")   # before measuring
        figstyle.check_outputs(args.plot, force=args.force)        # and the figure's SVG and .plot.csv
    kind, model, src = _load(Path(args.model), args.grip)
    dev = make_device(args.device, seed=args.seed) if args.device.startswith("sim") else make_device(args.device)
    with dev:
        if kind == "nonlinear":
            model_dev = SimDevice(model.replace(sensors={"accel_noise_m_s2": 0.0}), seed=args.seed + 1)
            for row in etfe_agreement(dev, model_dev, args.amplitudes, args.grip):
                print(f"ETFE {row['amplitude_A']:g} A, grip {args.grip:g} N, 20-500 Hz: RMS {row['rms_db']:.2f} dB "
                      f"(max {row['max_db']:.2f}), {row['rms_deg']:.1f} deg (max {row['max_deg']:.1f})")
            models = {"nonlinear model": SimDevice(model.replace(sensors={"accel_noise_m_s2": 0.0}))}
        else:
            models = {"zpk model": model}
        res = time_domain_validation(dev, models, args.grip, args.amplitude)
    for name, m in res["models"].items():
        print(f"time-domain validation ({name}, {args.amplitude:g} A transients, grip {args.grip:g} N): NRMSE "
              f"{m['nrmse']:.3f}; per transient " + ", ".join(f"{x:.3f}" for x in m["nrmse_per_transient"]))
    if args.plot:
        print(f"wrote {time_domain_figure(res, args.plot, title=f'{src} on {args.device}', force=True)}")
    return 0
