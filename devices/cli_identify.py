"""``python -m devices identify`` (record + fit a grip-dependent model set) and ``python -m devices fit``
(fit a model offline from recordings); formats in docs/models.md."""

from __future__ import annotations

import os
import sys
from collections import OrderedDict
from pathlib import Path

import figstyle
from plumbing.fileio import check_output_dir, refuse_overwrite
from plumbing.outdir import output_folder
from plumbing.stopsignals import Terminated

from .identify import (
    pipeline as identify_pipeline,  # identify_pipeline.identify_device: replaceable in tests
)
from .identify.etfe import etfe
from .identify.figures import bode_plot
from .identify.fit import FitOptions, fit_etfes
from .identify.pipeline import IdentifyConfig, format_report
from .identify.recording import read_recording
from .identify.successive import (
    STAGE_NAMES,
    format_result,
    identify_successive,
    save_result,
)
from .identify.successive.procedure import STATE_FILE
from .identify.sweep import SweepConfig
from .identify.validate import read_transient_recording, validate_model
from .limits import check_grips
from .registry import check_device_spec, make_device


def _fit_options(args, band=None, weight="mean"):
    return FitOptions(band_hz=band, order=args.order, max_order=max(args.max_order, 1), delay_s=args.delay,
                      weight=weight, use_coherence=not args.no_coherence_weight, max_rms_db=args.max_rms_db,
                      max_rms_phase_deg=args.max_rms_phase_deg, minimum_phase=args.min_phase)


def default_grip_levels(grip_range_N: tuple[float, float]) -> tuple[float, ...]:
    """Grip levels that span a device's grip range: dense where people usually hold (the first 3 N), then
    the middle and the top of the range, so interpolation never has to extrapolate (section 3.4.6)."""
    lo, hi = float(grip_range_N[0]), float(grip_range_N[1])
    levels = {lo, hi, (lo + hi) / 2.0} | {lo + k for k in (1.0, 2.0, 3.0) if lo + k < hi}
    return tuple(sorted(levels))


def check_out_dir(out, overwrite: bool, marker_files=("model_set.json", "model.json")) -> None:
    """Refuse to write into a folder that already holds a model unless ``overwrite`` (never overwrite a
    user's results silently)."""
    out = check_output_dir(out)  # a file, or a path below one: refused whatever ``overwrite``
    found = [m for m in marker_files if (out / m).exists()]
    if found and not overwrite:
        raise ValueError(f"--out {out} already holds a model ({', '.join(found)}); choose another folder or pass "
                         "--force")


#: What identify writes into --out (replaced with --force, only once a new run has succeeded).
IDENTIFY_PRODUCTS = ("recordings", "accel_g*N.json", "position_g*N.json", "model_set.json", "bode_*.png",
                     "bode_*.svg", "bode_*.csv", "etfe_*.npz", "report.txt", "report.json")


#: What ``identify --method successive`` writes into --out (devices.identify.successive.save_result).
SUCCESSIVE_PRODUCTS = ("model.json", "report.txt", "report.json", "stage_*.png", "successive_state.json")


def _rewrite_paths(new: Path, out: Path) -> None:
    """Paths to the staging folder ``new`` in a finished run's reports are rewritten to ``out``, where the
    run is swapped in."""
    if new == out:
        return
    for name in ("report.json", "report.txt"):
        p = new / name
        if p.is_file():
            p.write_text(p.read_text(encoding="utf-8").replace(str(new), str(out)), encoding="utf-8")


def run_identify(args) -> int:
    """The ``identify`` command (comprehensive or successive, see ``--method``); returns the exit code.

    With ``--force`` over earlier results, the new run is measured into a temporary folder beside
    ``--out`` and swapped in only when it succeeded: a failure, Ctrl-C or a stop signal leaves the earlier
    results as they were (plumbing.outdir). Ctrl-C prints one line and exits 130; SIGTERM/SIGHUP the same
    with 143/129, and no worker process outlives the command (plumbing.stopsignals.worker_pool).
    """
    try:
        return _run_identify(args)
    except KeyboardInterrupt:
        print(f"\ninterrupted: identification stopped; nothing in {args.out} was replaced", file=sys.stderr)
        return 130
    except Terminated as exc:  # SIGTERM/SIGHUP: the workers were killed, the staging folder removed
        print(f"{exc}: identification stopped; nothing in {args.out} was replaced", file=sys.stderr)
        return exc.code


def _run_identify(args) -> int:
    check_device_spec(args.device)
    if any(not a > 0 for a in args.amplitude):
        raise ValueError(f"--amplitudes-A must be > 0 A, got {args.amplitude}")
    if args.method == "successive":
        return run_successive(args)
    # written beside --out and swapped in once it succeeded (plumbing.outdir), one writer at a time
    folder = output_folder(args.out, args.force, products=IDENTIFY_PRODUCTS).open()
    out, target = folder.out, folder.path
    with folder:
        try:
            report = _measure(args, target)
        except ValueError as exc:
            if (target / "report.txt").is_file():  # a failed fit: its files are worth a look
                if not folder.replacing:  # a new --out: it holds them, as the run left them
                    raise ValueError(str(exc).replace(str(target), str(folder.commit()))) from None
                kept = folder.set_aside("failed")
                raise ValueError(f"{str(exc).replace(str(target), str(kept))} ({out} keeps the earlier results; "
                                 f"this run's files are in {kept})") from None
            raise
        _rewrite_paths(target, out)

    print(format_report(report).replace(str(target), str(out)), end="")
    print(f"wrote {out / 'model_set.json'}, models, etfe_accel.npz, etfe_position.npz, bode_accel.png, "
          "bode_position.png, report.txt")
    return 0


def _measure(args, out: Path) -> dict:
    """Identify ``args.device`` into ``out``; returns the report."""

    dev = make_device(args.device, seed=args.seed) if args.device.startswith("sim") else make_device(args.device)
    with dev:
        sweep = SweepConfig(amplitude_A=args.amplitude[0], f_start_hz=args.f_start, f_end_hz=args.f_end,
                            duration_s=args.duration, fs_hz=dev.info.servo_rate_hz, repetitions=args.repetitions)
        band = tuple(args.band) if args.band else None
        grips = args.grip if args.grip is not None else default_grip_levels(dev.info.grip_range_N)
        check_grips(dev.info, grips, "--grips-N")   # 200 N on a 0-10 N sensor: refused before measuring
        workers = args.workers if args.workers is not None else (os.cpu_count() or 1)
        cfg = IdentifyConfig(grips_N=grips, trials=args.trials, sweep=sweep,
                             accel_options=_fit_options(args, band, "mean"),
                             position_options=_fit_options(args, band, "mean"), validate=not args.no_validate,
                             detrend=args.detrend, reverse_half=not args.no_reverse,
                             amplitudes_A=tuple(args.amplitude) if len(args.amplitude) > 1 else (),
                             purpose=args.purpose, workers=max(1, workers))
        return identify_pipeline.identify_device(dev, cfg, out, device_spec=args.device, seed=args.seed)


def run_successive(args) -> int:
    """``identify --method successive``: stage by stage, progress per stage, model.json + report + figures.

    As the comprehensive method: a folder that holds a model is refused without ``--force`` (the message
    names the file); with it, the new run is identified into a temporary folder beside ``--out`` and
    swapped in only once its model, report and figures are written, so a failure or Ctrl-C midway leaves
    the earlier model as it was. A failed stage's state is kept in ``<out>.failed`` (``--resume`` there
    continues it). ``--resume`` continues the run whose state is in ``--out`` itself, in place.
    """

    out = check_output_dir(args.out)  # a file, or a path below one: refused whatever --force
    if not args.resume:
        check_out_dir(out, args.force)  # a model there: refused without --force, named
        found = sorted({p.name for pattern in SUCCESSIVE_PRODUCTS for p in out.glob(pattern)}) if out.is_dir() else []
        if found and not args.force:  # the rest of an earlier run (its report, figures, state) is the user's too
            raise ValueError(f"--out {out} already holds an identification's files ({', '.join(found)}); choose "
                             "another folder, pass --resume to continue it or --force to replace it")
    stages = tuple(s.strip() for s in args.stages.split(",")) if args.stages else STAGE_NAMES
    # earlier results stay until the new run has succeeded: it is identified beside --out and swapped in
    # (plumbing.outdir); --resume continues the run in --out itself, under the same lock
    folder = output_folder(out, True, products=SUCCESSIVE_PRODUCTS, in_place=args.resume).open()
    target = folder.path
    with folder:
        try:
            result = identify_successive(args.device, stages=stages, state_dir=target, resume=args.resume,
                                         seed=args.seed, log=lambda m: print(m, flush=True))
            path = save_result(result, target, overwrite=args.resume, figures=not args.no_figures)
        except ValueError as exc:
            if args.resume or not (target / STATE_FILE).is_file():
                raise
            if not folder.replacing:  # a new --out keeps the finished stages (--resume there continues)
                raise ValueError(str(exc).replace(str(target), str(folder.commit()))) from None
            kept = folder.set_aside("failed")
            raise ValueError(f"{str(exc).replace(str(target), str(kept))} ({out} keeps the earlier model; "
                             f"this run's finished stages are in {kept}: --out {kept} --resume continues "
                             "it)") from None
        _rewrite_paths(target, out)
    path = out / path.name
    print(format_result(result), end="")
    print(f"wrote {path} (use it as --device sim:{path}), report.txt, report.json"
          + ("" if args.no_figures else ", stage_*.png"))
    return 0


def group_recordings(recs) -> "OrderedDict[str, list]":
    """Curves from recordings: by sidecar 'condition', else by grip (0.5 N) and amplitude."""
    groups: OrderedDict[str, list] = OrderedDict()
    for rec in recs:
        key = rec.meta.get("condition")
        if not key:
            g = rec.meta.get("grip_mean_N")
            if g is None:
                a, b = rec.sweep.n_samples, 2 * rec.sweep.n_samples
                g = float(rec.grip_N[a:b].mean()) if rec.grip_N.size >= b else float(rec.grip_N.mean())
            key = f"grip {round(g * 2) / 2:g} N, {rec.sweep.amplitude_A:g} A"
        groups.setdefault(str(key), []).append(rec)
    return groups


def run_fit(args) -> int:
    """The ``fit`` command: refit models from earlier recordings (ETFE + automatic order); returns the exit code."""

    refuse_overwrite(args.out, args.force)
    if args.plot:
        figstyle.check_outputs(args.plot, force=args.force)   # the PNG, SVG and .plot.csv it will write
    recs = [read_recording(p) for p in args.recordings]
    groups = group_recordings(recs)
    curves = [etfe(rs, args.output, label=f"{key} ({len(rs)} trials)", detrend=args.detrend)
              for key, rs in groups.items()]
    band = tuple(args.band) if args.band else None
    opts = _fit_options(args, band, args.weight)
    grips = {c.grip_N for c in curves}
    grip = curves[0].grip_N if len(grips) == 1 else None
    src = "python -m devices fit " + " ".join(str(p) for p in args.recordings)
    result = fit_etfes(curves, opts, source=src, grip_N=grip)  # FitError (a ValueError): nothing written
    out = result.model.save(args.out)
    m = result.metrics
    print("order  RMS dB  RMS deg")
    for row in result.table:
        mark = " <- chosen" if row["order"] == m["order"] else ""
        print(f"{row['order']:5d} {row['rms_db']:7.2f} {row['rms_phase_deg']:8.1f}{mark}")
    print(f"{len(curves)} curve(s), {len(recs)} recording(s), weight {args.weight}, band "
          f"{result.model.band_hz[0]:.1f}-{result.model.band_hz[1]:.1f} Hz: order {m['order']}, "
          f"delay {m['delay_s'] * 1e3:.3f} ms, RMS {m['rms_db']:.2f} dB, {m['rms_phase_deg']:.1f} deg, "
          f"worst band {m['worst_band_db']:.2f} dB")
    if args.plot:
        bode_plot(curves, [result.model], args.plot, title=f"{args.output}: ETFE (solid) and fitted model (dashed)",
                  force=args.force)
        print(f"wrote {args.plot}")
    for path in args.validate:
        fs, u, y = read_transient_recording(path, args.output)
        v = validate_model(result.model, u, y, fs)
        print(f"validation on {path}: NRMSE {v['nrmse']:.3f} ({u.size} samples at {fs:g} Hz)")
    print(f"wrote {out}")
    return 0
