"""``python -m devices validate MODEL``: check an identified model against the device (thesis sec. 3.4.5):
ETFE agreement at several current magnitudes and the held-handle response to contact-like transients."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import figstyle
from plumbing.cliargs import add_renamed, with_examples
from plumbing.fileio import check_output_file


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def register(subparsers) -> None:
    """Add the ``validate`` command to ``python -m devices``."""
    p = subparsers.add_parser(
        "validate", help="validate an identified model against the device (ETFEs, held transients)",
        description="MODEL is a nonlinear model file from 'identify --method successive' (model.json, a sim "
                    "parameter file), a zpk model JSON from comprehensive evaluation, or a folder holding either "
                    "(model.json or the accel model nearest --grip-N of model_set.json). Plays contact-like "
                    "transients while the (simulated) user holds at --grip-N and reports the normalized RMS error "
                    "of the model's predicted handle acceleration per transient; for a nonlinear model also "
                    "compares the ETFEs of device and model at each --amplitudes-A (20-500 Hz).")
    p.add_argument("model", help="model.json (nonlinear), a zpk JSON, or a model folder")
    p.add_argument("--device", default="sim", help="device string of the device to validate against")
    add_renamed(p, "--grip-N", "--grip", dest="grip", type=float, default=2.0,
                help="grip of the holding user in N (default 2)")
    add_renamed(p, "--amplitude-A", "--amplitude", dest="amplitude", type=float, default=1.0,
                help="transient amplitude in A (default 1)")
    add_renamed(p, "--amplitudes-A", "--amplitudes", dest="amplitudes", type=_floats, default=(0.2, 0.75, 1.25),
                   help="sweep amplitudes for the ETFE comparison (nonlinear models; default 0.2,0.75,1.25)")
    p.add_argument("--seed", type=int, default=0, help="sim noise seed")
    p.add_argument("--plot", default=None, help="write the time-domain figure (Figure 3.10 style) here")
    p.add_argument("--force", action="store_true", help="overwrite --plot if it exists")
    with_examples(p, "hfam-devices validate ident/ --device sim --grip-N 2 --plot td.png",
                  "hfam-devices validate model.json --amplitudes-A 0.2,0.75 --grip-N 3")
    p.set_defaults(func=run_validate)


def _load(path: Path, grip: float):
    """('nonlinear', SimParams) or ('zpk', ZpkModel) from a file or folder."""
    from .model import load_model  # deferred: keeps `--help` fast (a command loads only what it runs)
    from .sim.params import load_sim_params  # deferred: keeps `--help` fast (a command loads only what it runs)

    if path.is_dir():
        if (path / "model.json").is_file():
            path = path / "model.json"
        elif (path / "model_set.json").is_file():
            from .identify.modelset import (  # deferred: keeps `--help` fast (a command loads only what it runs)
                load_model_set,
            )

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
    from .identify.validate_td import (  # deferred: keeps `--help` fast (a command loads only what it runs)
        etfe_agreement,
        time_domain_figure,
        time_domain_validation,
    )
    from .registry import (  # deferred: keeps `--help` fast (a command loads only what it runs)
        check_device_spec,
        make_device,
    )

    check_device_spec(args.device)
    if args.plot:
        check_output_file(args.plot, args.force, what="--plot")   # before measuring
        figstyle.check_outputs(args.plot, force=args.force)        # and the figure's SVG and .plot.csv
    kind, model, src = _load(Path(args.model), args.grip)
    dev = make_device(args.device, seed=args.seed) if args.device.startswith("sim") else make_device(args.device)
    with dev:
        if kind == "nonlinear":
            from .sim.device import SimDevice  # deferred: keeps `--help` fast (a command loads only what it runs)

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
