"""``python -m stimuli build-library``: build an HFAM current library from recorded taps and device models."""

from __future__ import annotations

import sys
from pathlib import Path

from devices import registry  # registry.make_device: replaceable in tests
from devices.identify.modelset import read_model_set_index
from devices.model import load_model
from plumbing.fileio import check_output_file
from plumbing.outdir import output_file

from .hfam.build import build_library, format_verification, source_entry
from .hfam.refine import RefineSettings, recording_targets, refine_library
from .hfam.settings import BuildSettings
from .recordings import read_tap_csv


def _device_limits(args) -> tuple[float, float | None, float | None, tuple | None]:
    """(force_per_amp_N_A, peak_current_A, servo_rate_hz, grip_range_N) from --device and the overrides."""
    fpa, peak, rate, grips = args.force_per_amp, args.peak_current_A, None, None
    if args.device.lower() != "none":
        # a hardware device learns its info in the hello handshake, so open it (zero current) to read it
        with registry.make_device(args.device) as dev:
            info = dev.info
        fpa = info.force_per_amp_N_A if fpa is None else fpa
        peak = info.current_peak_A if peak is None else peak
        rate = info.servo_rate_hz
        grips = tuple(float(g) for g in info.grip_range_N)
    if fpa is None:
        raise ValueError("--force-per-amp is required with --device none")
    return fpa, peak, rate, grips


def expand_model_paths(paths) -> list[Path]:
    """Model files from ``--model`` arguments: JSON models as given, model sets expanded to their accel models.

    A model set is a directory holding ``model_set.json`` or that index file itself
    (``{"kind": "model_set", "models": {"accel_m_s2": [file or null, ...]}}``).
    """
    out = []
    for path in paths:
        path = Path(path)
        index = path / "model_set.json" if path.is_dir() else path
        if not index.is_file():
            raise FileNotFoundError(f"model file not found: {path}")
        if index.name == "model_set.json" or path.is_dir():
            index, _, by_output = read_model_set_index(index)
            files = [f for f in by_output.get("accel_m_s2", []) if f is not None]
            if not files:
                raise ValueError(f"{index}: the model set has no acceleration models")
            out.extend(files)
        else:
            out.append(path)
    return out


def run(args) -> int:
    """The ``build-library`` command: taps + models -> HFAM library, verified through the forward models; returns the exit code."""
    check_output_file(args.out, force=True)   # a folder or a path below a file: refused before building
    if args.out.suffix != ".npz":
        raise ValueError(f"--out {args.out}: the library file must end in .npz")
    # a folder, a path below a file or (without --force) an existing library: refused before building; the
    # library is written beside and renamed into place, one writer at a time (plumbing.outdir)
    with output_file(args.out, args.force) as out:
        return _build(args, out.path)


def _build(args, library_path) -> int:
    """The build of ``run``, the library written to ``library_path`` (renamed to ``--out`` by the caller)."""
    taps_sel = None
    if args.taps:
        try:
            taps_sel = tuple(int(x) for x in args.taps.split(","))
        except ValueError:
            raise ValueError(f"--taps {args.taps!r}: expected comma-separated integers") from None
    fpa, peak, rate, grip_range = _device_limits(args)
    settings = BuildSettings(
        n_velocities=args.n_velocities, taps=taps_sel, duration_s=args.duration_s, smooth_hz=args.smooth_hz,
        highpass_hz=args.highpass_hz, added_zero_hz=args.added_zero_hz, added_zero_zeta=args.added_zero_zeta,
        taper_s=args.taper_s, onset_delay_s=args.onset_delay_s, gain=args.gain,
        max_pre_impact_ratio=args.max_pre_impact_ratio, min_neighbour_corr=args.min_neighbour_corr,
        peak_current_A=peak, scale_to_limit=args.scale_to_limit, max_extrapolation=args.max_extrapolation,
    )
    print(f"reading {args.recordings}", flush=True)
    fs, taps = read_tap_csv(args.recordings)
    print(f"  {len(taps)} taps at {fs:g} Hz, velocities {min(t.v_in_m_s for t in taps):.4g}.."
          f"{max(t.v_in_m_s for t in taps):.4g} m/s", flush=True)
    if rate is not None and abs(rate - fs) > 1e-6 * rate:
        raise ValueError(f"{args.recordings}: sampled at {fs:g} Hz but device {args.device!r} runs at {rate:g} Hz")
    models = []
    args.models = expand_model_paths(args.models)
    for path in args.models:
        print(f"reading model {path}", flush=True)
        models.append((str(path), load_model(path)))
    provenance = {
        "source_files": {"recordings": source_entry(args.recordings), "models": [source_entry(p) for p in args.models]},
        "device": args.device,
        "command": " ".join(["python -m stimuli"] + sys.argv[1:]) if sys.argv and sys.argv[0] else "",
    }
    library, report = build_library(taps, fs, models, settings, force_per_amp_N_A=fpa,
                                    log=lambda m: print(m, flush=True), provenance=provenance)
    print(format_verification(report, settings.verify_band_hz))
    if args.refine < 0:
        raise ValueError(f"--refine must be >= 0, got {args.refine}")
    if args.refine:
        if not str(args.device).startswith("sim"):
            raise ValueError(f"--refine plays the transients on a simulated device; --device {args.device!r} is not "
                             f"one (on hardware refinement needs repeated taps by a person, see docs/hfam_library.md)")


        library, _ = refine_library(library, models, lambda: registry.make_device(args.device, seed=0),
                                    RefineSettings(iterations=args.refine, wall_N_m=args.refine_wall,
                                                   gain=args.refine_gain, max_lag_s=args.refine_max_lag,
                                                   recording_iterations=args.refine_recordings), settings,
                                    log=lambda m: print(m, flush=True),
                                    recordings_m_s2=recording_targets(library, taps, settings))
    for msg in report.scaled:
        print(f"warning: {msg}")
    g = library.grips_N
    if grip_range is not None and len(g) > 1 and (g[0] > grip_range[0] + 1e-9 or g[-1] < grip_range[1] - 1e-9):
        # the renderer and the study refuse such a library on this device (HfamLibrary.check_device)
        print(f"warning: model grip levels {g[0]:g}..{g[-1]:g} N do not cover device {args.device!r} grip range "
              f"{grip_range[0]:g}..{grip_range[1]:g} N: renderer and study will refuse this library on it; "
              f"identify at grips spanning the range (e.g. --grip 0,1,2,3,5,10)")
    library.save(library_path)
    print(f"wrote {args.out}: {len(library.velocities_m_s)} velocities x {len(library.grips_N)} grip level(s) x "
          f"{library.n_samples} samples at {library.fs_hz:g} Hz")
    return 0
