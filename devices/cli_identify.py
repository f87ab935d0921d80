"""``python -m devices identify`` (record + fit a grip-dependent model set) and ``python -m devices fit``
(fit a model offline from recordings); formats in docs/models.md."""

from __future__ import annotations

import argparse
import os
import sys
from collections import OrderedDict
from pathlib import Path

from plumbing.cliargs import add_renamed, with_examples
from plumbing.fileio import check_output_dir, refuse_overwrite
from plumbing.outdir import output_folder
from plumbing.stopsignals import Terminated


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def _order(text: str):
    if text == "auto":
        return "auto"
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--order must be 'auto' or an integer, got {text!r}") from None
    return n


def _delay(text: str):
    if text == "auto":
        return "auto"
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--delay must be 'auto' or a number of seconds, got {text!r}") from None


def _fit_options_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--order", type=_order, default="auto", help="number of poles, or 'auto' (default): "
                   "chosen from the error-versus-order table")
    p.add_argument("--max-order", type=int, default=14, help="largest order tried by --order auto (default 14)")
    add_renamed(p, "--delay-s", "--delay", dest="delay", type=_delay, default="auto", help="pure delay in s, or 'auto' (default)")
    p.add_argument("--max-rms-db", type=float, default=3.0,
                   help="requested RMS magnitude error; a worse fit writes nothing (default 3 dB)")
    p.add_argument("--max-rms-phase-deg", type=float, default=20.0,
                   help="requested RMS phase error; a worse fit writes nothing (default 20 deg)")
    p.add_argument("--no-coherence-weight", action="store_true", help="do not weight bins by coherence")
    p.add_argument("--min-phase", action="store_true",
                   help="mirror right-half-plane zeros into the left half plane and re-fit the delay (models "
                        "meant for inversion, section 4.2.2); the reported errors include the change")
    p.add_argument("--detrend", choices=("ramp", "periodic"), default="ramp",
                   help="ETFE detrending: 'ramp' (thesis eq. 3.13-3.14, default) or 'periodic' (remove only the "
                        "drift between the two sweep copies; exact in the lowest bins)")


def _fit_options(args, band=None, weight="mean"):
    from .identify.fit import FitOptions  # deferred: keeps `--help` fast (a command loads only what it runs)

    return FitOptions(band_hz=band, order=args.order, max_order=max(args.max_order, 1), delay_s=args.delay,
                      weight=weight, use_coherence=not args.no_coherence_weight, max_rms_db=args.max_rms_db,
                      max_rms_phase_deg=args.max_rms_phase_deg, minimum_phase=args.min_phase)


def register(subparsers) -> None:
    """Add the ``identify``, ``fit`` and ``validate``-family commands.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m devices`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "identify", help="identify a device: comprehensive evaluation (LTI model set) or successive isolation "
                         "(nonlinear physical model)",
        description="--method comprehensive (default, thesis sec. 3.4): play swept-sine current commands (eq. "
                    "3.11-3.12, twice back to back) while the user holds the handle at each grip level, estimate "
                    "ETFEs, fit stable zpk models with delay for handle acceleration and position, validate on "
                    "transients, and write recordings, one model JSON per grip and output, model_set.json, Bode "
                    "PNGs and a fit report into --out. --method successive (sec. 3.5): identify the nonlinear "
                    "model of eq. 3.32-3.35 stage by stage (amplifier, timing, motor, cables, drum, linkage "
                    "hysteresis, handle, user) in the mechanical configuration each stage needs (set directly on "
                    "the sim; the operator is prompted on hardware) and write model.json (a sim parameter file: "
                    "--device sim:DIR/model.json), report.txt/json and one figure per stage into --out.")
    p.add_argument("--method", choices=("comprehensive", "successive"), default="comprehensive",
                   help="comprehensive evaluation (LTI, default) or successive isolation (nonlinear)")
    p.add_argument("--device", default="sim", help="device string (sim, sim:lti, serial:PORT, hid:VID:PID)")
    add_renamed(p, "--grips-N", "--grip", dest="grip", type=_floats, default=None,
                   help="comma-separated grip levels in N (default: spans the device's grip range, "
                        "0,1,2,3,5,10 on the sim, so an HFAM library built from the set covers every grip)")
    p.add_argument("--trials", type=int, default=4, help="good trials per grip, half reversed (default 4)")
    add_renamed(p, "--amplitudes-A", "--amplitude", dest="amplitude", type=_floats, default=(0.75,),
                help="sweep amplitude(s) in A, comma-separated (default 0.75); several give one ETFE curve each, "
                     "combined by --purpose")
    p.add_argument("--purpose", choices=("hfam", "cimm", "general"), default="general",
                   help="fit rule (sec. 3.4.4): hfam fits the highest-magnitude curves (inverted model never "
                        "over-stimulates a resonance), cimm the lowest (never over-cancels), general the average; "
                        "stored in every model's fit.purpose")
    p.add_argument("--workers", type=int, default=None,
                   help="simulated devices: grips fitted in this many processes at once, beside one recording process "
                        "(default: the number of cores)")
    p.add_argument("--stages", default=None,
                   help="successive: comma-separated stages to run (default all: timing,amplifier,motor,cables,"
                        "drum,linkage,handle,user)")
    p.add_argument("--resume", action="store_true",
                   help="successive: skip the stages already done in --out (after an interruption)")
    p.add_argument("--no-figures", action="store_true", help="successive: do not draw the per-stage figures")
    add_renamed(p, "--f-start-hz", "--f-start", dest="f_start", type=float, default=5.0, help="sweep start frequency f_i in Hz (default 5)")
    add_renamed(p, "--f-end-hz", "--f-end", dest="f_end", type=float, default=1000.0, help="sweep end frequency f_f in Hz (default 1000)")
    add_renamed(p, "--duration-s", "--duration", dest="duration", type=float, default=2.0, help="one sweep's duration in s (default 2)")
    p.add_argument("--repetitions", type=int, default=2, help="sweep copies back to back (default 2)")
    add_renamed(p, "--band-hz", "--band", dest="band", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="fit band in Hz (default: 10 Hz to f_end, position limited by encoder resolution)")
    p.add_argument("--no-reverse", action="store_true",
                   help="do not reverse the sweep polarity for the second half of the trials")
    p.add_argument("--no-validate", action="store_true", help="skip the time-domain validation on transients")
    p.add_argument("--seed", type=int, default=0, help="sim noise seed")
    _fit_options_args(p)
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--force", action="store_true",
                   help="replace an earlier identification in --out (its models, recordings, plots and report are "
                        "replaced once the new run has succeeded, so old and new models never mix; a failed or "
                        "interrupted run leaves them as they were)")
    with_examples(p, 'hfam-devices identify --device sim --out ident/                  # grips 0,1,2,3,5,10 N', 'hfam-devices identify --device serial:/dev/ttyACM0 --grips-N 1,2,4 --trials 4 --out ident_hw/')
    p.set_defaults(func=run_identify)

    q = subparsers.add_parser(
        "fit", help="fit a model to swept-sine recordings made anywhere",
        description="Fit a stable zpk model with pure delay to the ETFE of one or more recordings (CSV "
                    "t_s,current_A,accel_m_s2,position_m,grip_N plus a JSON sidecar of the same name). "
                    "Recordings with the same sidecar 'condition' (else the same grip to 0.5 N and amplitude) "
                    "are complex-averaged into one curve; several curves are combined by --weight.")
    q.add_argument("recordings", nargs="+", help="recording CSV files")
    q.add_argument("--output", choices=("accel_m_s2", "position_m"), default="accel_m_s2",
                   help="which output to model (default accel_m_s2, H_ha)")
    add_renamed(q, "--band-hz", "--band", dest="band", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="fit band in Hz (default: 10 Hz to the sweep's end, limited by quantization)")
    q.add_argument("--weight", choices=("high", "low", "mean"), default="mean",
                   help="combine several curves by their upper envelope (HFAM), lower envelope "
                        "(cancellation) or mean (default)")
    q.add_argument("--plot", default=None, help="also write a Bode PNG here")
    q.add_argument("--validate", nargs="+", default=(), metavar="TRANSIENTS.csv",
                   help="time-domain validation (section 3.4.5): simulate the model on the commanded current of "
                        "these recordings (columns t_s,current_A,<output>) and print the NRMSE against the measured "
                        "output (e.g. recordings/transients_g2N.csv written by identify)")
    _fit_options_args(q)
    q.add_argument("--out", required=True, help="model JSON to write")
    q.add_argument("--force", action="store_true", help="overwrite --out (and --plot) if they exist")
    with_examples(q, 'hfam-devices fit ident/recordings/g1N_t*.csv ident/recordings/g3N_t*.csv --weight high --out hfam_model.json')
    q.set_defaults(func=run_fit)


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
    from .registry import check_device_spec  # deferred: keeps `--help` fast (a command loads only what it runs)

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
    from .identify.pipeline import format_report  # deferred: keeps `--help` fast (a command loads only what it runs)

    print(format_report(report).replace(str(target), str(out)), end="")
    print(f"wrote {out / 'model_set.json'}, models, etfe_accel.npz, etfe_position.npz, bode_accel.png, "
          "bode_position.png, report.txt")
    return 0


def _measure(args, out: Path) -> dict:
    """Identify ``args.device`` into ``out``; returns the report."""
    from .identify.pipeline import (  # deferred: keeps `--help` fast (a command loads only what it runs)
        IdentifyConfig,
        identify_device,
    )
    from .identify.sweep import SweepConfig  # deferred: keeps `--help` fast (a command loads only what it runs)
    from .registry import make_device  # deferred: keeps `--help` fast (a command loads only what it runs)

    dev = make_device(args.device, seed=args.seed) if args.device.startswith("sim") else make_device(args.device)
    with dev:
        sweep = SweepConfig(amplitude_A=args.amplitude[0], f_start_hz=args.f_start, f_end_hz=args.f_end,
                            duration_s=args.duration, fs_hz=dev.info.servo_rate_hz, repetitions=args.repetitions)
        band = tuple(args.band) if args.band else None
        grips = args.grip if args.grip is not None else default_grip_levels(dev.info.grip_range_N)
        workers = args.workers if args.workers is not None else (os.cpu_count() or 1)
        cfg = IdentifyConfig(grips_N=grips, trials=args.trials, sweep=sweep,
                             accel_options=_fit_options(args, band, "mean"),
                             position_options=_fit_options(args, band, "mean"), validate=not args.no_validate,
                             detrend=args.detrend, reverse_half=not args.no_reverse,
                             amplitudes_A=tuple(args.amplitude) if len(args.amplitude) > 1 else (),
                             purpose=args.purpose, workers=max(1, workers))
        return identify_device(dev, cfg, out, device_spec=args.device, seed=args.seed)


def run_successive(args) -> int:
    """``identify --method successive``: stage by stage, progress per stage, model.json + report + figures.

    As the comprehensive method: a folder that holds a model is refused without ``--force`` (the message
    names the file); with it, the new run is identified into a temporary folder beside ``--out`` and
    swapped in only once its model, report and figures are written, so a failure or Ctrl-C midway leaves
    the earlier model as it was. A failed stage's state is kept in ``<out>.failed`` (``--resume`` there
    continues it). ``--resume`` continues the run whose state is in ``--out`` itself, in place.
    """
    from .identify.successive import (  # deferred: keeps `--help` fast (a command loads only what it runs)
        STAGE_NAMES,
        format_result,
        identify_successive,
        save_result,
    )
    from .identify.successive.procedure import STATE_FILE  # deferred: keeps `--help` fast

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
    from .identify.etfe import etfe  # deferred: keeps `--help` fast (a command loads only what it runs)
    from .identify.figures import bode_plot  # deferred: keeps `--help` fast (a command loads only what it runs)
    from .identify.fit import fit_etfes  # deferred: keeps `--help` fast (a command loads only what it runs)
    from .identify.recording import read_recording  # deferred: keeps `--help` fast (a command loads only what it runs)

    refuse_overwrite(args.out, args.force)
    if args.plot:
        import figstyle  # deferred: keeps `--help` fast (a command loads only what it runs)

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
        from .identify.validate import (  # deferred: keeps `--help` fast (a command loads only what it runs)
            read_transient_recording,
            validate_model,
        )

        fs, u, y = read_transient_recording(path, args.output)
        v = validate_model(result.model, u, y, fs)
        print(f"validation on {path}: NRMSE {v['nrmse']:.3f} ({u.size} samples at {fs:g} Hz)")
    print(f"wrote {out}")
    return 0
