"""Record, fit, validate and save a grip-dependent model set for a device (sections 3.4.1-3.4.6)."""

from __future__ import annotations

import json
import multiprocessing
import os
import time
from concurrent.futures import FIRST_COMPLETED, wait
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import scipy.linalg  # noqa: F401 (loaded once, before the fork, for the recorder and the fitting processes)
from scipy.signal import find_peaks

from plumbing.fileio import atomic_write_text
from plumbing.progress import Progress
from plumbing.pools import worker_dies_with_parent, worker_pool
from plumbing.stopsignals import signals_blocked, stop_if_signalled
from plumbing.validation import require_int

from ..base import Device
from ..registry import make_device
from .etfe import Etfe, etfe
from .figures import bode_plot, preload_figures
from .fit import FitError, FitOptions, fit_etfes, load_solvers
from .modelset import ModelSet
from .record import record_condition
from .recording import write_recording
from .sweep import SweepConfig
from .validate import record_transients, validate_model, write_transient_recording

OUTPUT_SHORT = {"accel_m_s2": "accel", "position_m": "position"}
# fit rule by the model's purpose (sec. 3.4.4): HFAM inverts the model, so it must not over-stimulate a
# resonance (fit the highest-magnitude curves); cancellation of induced master motion (CIMM) must not
# over-cancel (lowest); a general model fits the average
PURPOSE_WEIGHT = {"hfam": "high", "cimm": "low", "general": "mean"}


@dataclass(frozen=True)
class IdentifyConfig:
    """What :func:`identify_device` does.

    Attributes
    ----------
    grips_N : tuple of float
        Grip levels (strictly increasing).
    trials : int
        Good trials per grip (half with reversed polarity).
    sweep : SweepConfig
        ``fs_hz`` must equal the device's servo rate.
    accel_options, position_options : FitOptions
        Fit options for H_ha and G_i (band None: automatic, see ``fit.default_band``).
    validate : bool
        Play contact-like transients at each grip and report the accel model's NRMSE.
    validation_amplitude_A : float
    amplitudes_A : tuple of float
        Sweep amplitudes per grip (empty: ``sweep.amplitude_A`` only). With several, each is one ETFE
        curve and ``purpose`` decides how they are combined (sec. 3.4.3-3.4.4).
    purpose : {"hfam", "cimm", "general"}
        Fit the highest, lowest or average magnitude curves (``PURPOSE_WEIGHT``); stored in every model's
        ``fit.purpose``.
    workers : int
        Simulated devices only: grips are fitted in this many processes at once, as one more process
        records them (each on its own device made from ``device_spec``, noise seed
        ``seed + 1000 * grip index``); with more than one, the Bode plots are also drawn in parallel.
    detrend : {"ramp", "periodic"}
        ETFE detrending (see :func:`devices.identify.etfe.etfe`).
    reverse_half : bool
        Reverse the sweep's polarity for the second half of the trials (sec. 3.4.1).
    outputs : tuple of str
        Which outputs to fit: ``"accel_m_s2"`` (H_ha, what HFAM needs) and/or ``"position_m"`` (G_i).
    figures : bool
        Draw ``bode_<output>.png`` (the ETFEs are always written to ``etfe_<output>.npz``).
    """

    grips_N: tuple = (0.0, 1.0, 2.0, 3.0, 4.0)
    trials: int = 4
    sweep: SweepConfig = field(default_factory=SweepConfig)
    accel_options: FitOptions = field(default_factory=FitOptions)
    position_options: FitOptions = field(default_factory=FitOptions)
    validate: bool = True
    validation_amplitude_A: float = 1.0
    detrend: str = "ramp"
    reverse_half: bool = True
    amplitudes_A: tuple = ()
    purpose: str = "general"
    workers: int = 1
    outputs: tuple = ("accel_m_s2", "position_m")
    figures: bool = True

    def __post_init__(self) -> None:
        if self.purpose not in PURPOSE_WEIGHT:
            raise ValueError(f"purpose must be one of {sorted(PURPOSE_WEIGHT)}, got {self.purpose!r}")
        if any(not (np.isfinite(a) and a > 0) for a in self.amplitudes_A):
            raise ValueError(f"amplitudes must be finite and > 0 A, got {self.amplitudes_A!r}")
        g = list(self.grips_N)
        if not g or any(not np.isfinite(x) or x < 0 for x in g) or any(b <= a for a, b in zip(g, g[1:])):
            raise ValueError(f"grip levels must be finite, >= 0 and strictly increasing, got {self.grips_N!r}")
        require_int("trials", self.trials, minimum=1, maximum=50)
        if not self.outputs or any(o not in OUTPUT_SHORT for o in self.outputs):
            raise ValueError(f"outputs must be some of {list(OUTPUT_SHORT)}, got {self.outputs!r}")


def _fit_one(curves: list, options: FitOptions, source: str):
    """(FitResult, None), or (None, reason) when the curves cannot be fitted to the requested error or have
    no usable band / data (e.g. an output that never moved)."""
    output = curves[0].output
    try:
        return fit_etfes(curves, options, source=source, grip_N=float(np.mean([c.grip_N for c in curves]))), None
    except FitError as exc:
        return None, str(exc)
    except ValueError as exc:
        return None, f"cannot fit {output}: {exc}"


def identify_device(dev: Device, cfg: IdentifyConfig, out_dir, log=print, device_spec: str = "",
                    seed: int = 0, progress: bool = True) -> dict:
    """Identify H_ha and G_i at every grip level of ``cfg`` and write the results to ``out_dir``.

    Writes ``recordings/g<g>N_t<k>.csv`` (+ ``.json``), the validation transients
    ``recordings/transients_g<g>N.csv``, the model set
    (``accel_g<g>N.json``, ``position_g<g>N.json``, ``model_set.json``),
    ``bode_accel.png``, ``bode_position.png`` and ``report.json`` /
    ``report.txt``. A grip level whose fit misses the requested error is
    reported and left out of the set; if no grip level fits, nothing but the
    recordings and the report is written and ValueError is raised.

    Parameters
    ----------
    dev : devices.base.Device
        The open device (simulated or hardware).
    cfg : IdentifyConfig
        Sweep, grip levels (N), trials, fit settings and ``workers``.
    out_dir : path
        Output folder (created).
    log : callable
        Receives one text line per message (default ``print``).
    device_spec : str
        The device string; simulated devices with ``cfg.workers > 1`` are identified grip by grip
        in parallel processes, each grip on a fresh device made from it (recorded by one process,
        fitted in ``cfg.workers`` others as its recordings arrive).
    seed : int
        Seed of the simulated devices' noise.
    progress : bool
        Show progress (grip n of N, elapsed, time left) on stderr: a bar on a terminal, plain lines otherwise.

    Returns
    -------
    dict
        The report (also in ``report.json``).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sweep = cfg.sweep
    t_start = time.perf_counter()
    outputs = [o for o in OUTPUT_SHORT if o in cfg.outputs]
    curves = {o: [] for o in outputs}
    models_plot = {o: [] for o in outputs}
    fits = {o: [] for o in outputs}
    rows = []
    label = device_spec or dev.info.name
    jobs = list(enumerate(cfg.grips_N))
    bar = Progress(len(jobs), f"identifying {label}", unit="grip", min_interval_s=0.0) if progress else None
    if cfg.workers > 1 and dev.simulated and device_spec.startswith("sim") and len(jobs) > 1:
        results = _grips_in_processes(jobs, cfg, device_spec, seed, label, out, bar)
    else:
        results = [None] * len(jobs)
        for i, (k, g) in enumerate(jobs):
            results[i] = _identify_grip(dev, k, g, cfg, label, out)
            if bar is not None:
                bar.update(status=f"grip {g:g} N")
    if bar is not None:
        bar.close()
    for (k, g), (row, gcurves, gfits, msgs) in zip(jobs, results):
        for m in msgs:
            log(m)
        for output in outputs:
            curves[output].extend(gcurves[output])
            fits[output].append(gfits[output])
            models_plot[output].extend([gfits[output].model if gfits[output] is not None else None]
                                       * len(gcurves[output]))
        rows.append(row)

    report = {"device": label, "purpose": cfg.purpose, "sweep": {
        "fs_hz": sweep.fs_hz, "f_start_hz": sweep.f_start_hz, "f_end_hz": sweep.f_end_hz,
        "duration_s": sweep.duration_s, "amplitude_A": sweep.amplitude_A, "repetitions": sweep.repetitions},
        "trials": cfg.trials, "amplitudes_A": list(cfg.amplitudes_A or (sweep.amplitude_A,)), "grips": rows}
    ok = [i for i, g in enumerate(cfg.grips_N) if any(fits[o][i] is not None for o in outputs)]
    written = []
    if ok:
        # deferred: devices.model loads scipy.signal (~1 s), which importing this module must not (the
        # recording process is forked before it is loaded, see above)

        models = {o: [fits[o][i].model if fits[o][i] is not None else None for i in ok] for o in outputs}
        models = {o: ms for o, ms in models.items() if any(m is not None for m in ms)}
        mset = ModelSet(np.array([cfg.grips_N[i] for i in ok], dtype=float), models)
        written.append(str(mset.save(out)))
    figures = {}
    if cfg.figures:
        figures = dict(zip(outputs, draw_bode_plots(
            [(curves[o], models_plot[o], out / f"bode_{OUTPUT_SHORT[o]}.png",
              f"{report['device']}: {OUTPUT_SHORT[o]} ETFE per grip (solid), fitted models (dashed)")
             for o in outputs], parallel=cfg.workers > 1)))
    for output in outputs:
        written.append(str(write_etfe_npz(curves[output], out / f"etfe_{OUTPUT_SHORT[output]}.npz")))
        if output in figures:
            written.append(str(figures[output]))
    report["written"] = written
    report["model_set_grips_N"] = [float(cfg.grips_N[i]) for i in ok]
    report["elapsed_s"] = time.perf_counter() - t_start
    _write_json(out / "report.json", report)
    (out / "report.txt").write_text(format_report(report))
    if not ok:
        raise ValueError(f"no grip level could be fitted to the requested error; see {out / 'report.txt'}; "
                         "no model set written")
    return report


def write_etfe_npz(curves: list, path) -> Path:
    """Write ETFE curves (one per grip level or condition) on one frequency grid.

    Parameters
    ----------
    curves : list of Etfe
        Curves of one output; interpolated onto the first curve's frequencies.
    path : path
        The ``.npz`` file (written atomically).

    Returns
    -------
    Path
        ``path``, holding ``f_hz`` (shape (n_f,), Hz), ``H`` (complex, shape (n_curves, n_f), output per A),
        ``coherence`` (shape (n_curves, n_f)) and ``grip_N`` (shape (n_curves,), N).
    """
    path = Path(path)
    f = curves[0].f_hz if curves else np.zeros(0)
    H = np.array([np.interp(f, c.f_hz, c.H.real) + 1j * np.interp(f, c.f_hz, c.H.imag) for c in curves])
    coh = np.array([np.interp(f, c.f_hz, c.coherence) for c in curves])
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, f_hz=f, grip_N=np.array([c.grip_N for c in curves]), H=H, coherence=coh)
    tmp.replace(path)
    return path


def draw_bode_plots(jobs: list, parallel: bool = False) -> list[Path]:
    """:func:`devices.identify.figures.bode_plot` for each ``(curves, models, path, title)`` of ``jobs``;
    with ``parallel``, the first here and the others at the same time in one forked process (matplotlib
    draws in one thread; what a process imported before, its fork need not import again).

    Returns
    -------
    list of Path
        The PNGs, in the order of ``jobs``.
    """
    if not parallel or len(jobs) < 2:
        return [bode_plot(*job, force=True) for job in jobs]   # into identify's own --out
    preload_figures()
    with worker_pool(1, multiprocessing.get_context("fork")) as pool:
        futures = [pool.submit(bode_plot, *job, force=True) for job in jobs[1:]]
        first = bode_plot(*jobs[0], force=True)
        return [first] + [f.result() for f in futures]


def _grips_in_processes(jobs: list, cfg: IdentifyConfig, spec: str, seed: int, label: str, out: Path, bar) -> list:
    """:func:`_identify_grip` of each ``(k, grip)`` of ``jobs`` on a fresh simulated device made from ``spec``
    (noise seed ``seed + 1000 k``), in processes: one records every grip in turn and is forked first, before
    the fitting code (scipy.signal, ~1 s) is loaded here; ``cfg.workers`` others, forked once it is, fit and
    validate the grips as their recordings arrive (fork: the processes inherit the imported and
    numba-compiled modules, so they start at once). Returns the results in the order of ``jobs``."""
    # before the fork: the recorder's first numba call loads scipy.linalg, and so does fitting here

    ctx = multiprocessing.get_context("fork")
    results = [None] * len(jobs)
    inbox, outbox = ctx.Pipe(duplex=False)
    recorder = ctx.Process(target=_recorder, args=(outbox, jobs, spec, seed, cfg, out, os.getpid()), daemon=True)
    with signals_blocked():  # a stop signal during the fork would be dropped in its after-fork hooks
        recorder.start()
    outbox.close()
    n_recorded = 0
    try:
        load_solvers()
        with worker_pool(min(cfg.workers, len(jobs)), ctx) as pool:  # workers die with this process
            fitting = {}
            while n_recorded < len(jobs) or fitting:
                # a stop signal that landed inside numba's compiler (load_solvers, a first fit) was swallowed
                # there (plumbing.stopsignals): raised here, within one pass, not after the whole run
                stop_if_signalled()
                if n_recorded < len(jobs):  # recordings arrive in grip order
                    if inbox.poll(0.05):
                        recorded = _received(inbox, recorder)
                        g = jobs[n_recorded][1]
                        fitting[pool.submit(_analyse_worker, (g, cfg, label, out, recorded))] = n_recorded
                        n_recorded += 1
                        if n_recorded == len(jobs) and cfg.figures:
                            # while the workers fit: the figure process forked later inherits matplotlib
                            preload_figures()
                    done = [f for f in fitting if f.done()]
                else:
                    done = wait(fitting, timeout=0.2, return_when=FIRST_COMPLETED)[0]
                for fut in sorted(done, key=fitting.get):
                    i = fitting.pop(fut)
                    results[i] = fut.result()
                    if bar is not None:
                        bar.update(status=f"grip {jobs[i][1]:g} N")
    finally:
        if recorder.is_alive() and n_recorded < len(jobs):  # stopped by an error
            recorder.terminate()
        recorder.join()
        inbox.close()
    return results


def _recorder(outbox, jobs, spec, seed, cfg, out, parent_pid) -> None:
    """Recording process of :func:`identify_device`: :func:`_record_worker` for each ``(k, grip)`` of ``jobs``
    in turn, each result sent as ``("ok", result)``; an error is sent as ``("error", exception)`` and ends
    it. It dies with the parent (``parent_pid``), whatever kills that."""
    worker_dies_with_parent(parent_pid)
    try:
        for k, g in jobs:
            outbox.send(("ok", _record_worker((spec, seed, k, g, cfg, out))))
    except BaseException as exc:  # noqa: BLE001  (reported to the parent, which raises it)
        try:
            outbox.send(("error", exc))
        except Exception:  # noqa: BLE001  (an exception that cannot be pickled)
            outbox.send(("error", RuntimeError(f"recording failed: {exc!r}")))
    finally:
        outbox.close()


def _received(inbox, recorder):
    """The next result of :func:`_recorder` (its error raised here)."""
    try:
        status, value = inbox.recv()
    except EOFError:
        recorder.join()
        raise RuntimeError(f"the recording process ended unexpectedly (exit code {recorder.exitcode})") from None
    if status == "error":
        raise value
    return value


def _record_worker(job):
    """One grip of :func:`_recorder`, on a fresh simulated device (see ``IdentifyConfig.workers``): its
    sweeps (written to ``out/recordings``), then, if validating, its transients, as :func:`_identify_grip`
    would record them on that device. Needs nothing beyond the simulator: it runs while the parent process
    loads the fitting code. Returns (recordings per condition, log messages, transients or None)."""
    spec, seed, k, g, cfg, out = job
    msgs = []
    dev = make_device(spec, seed=seed + 1000 * k)
    with dev:
        by_amp = _record_grip(dev, g, cfg, out, msgs)
        transients = None
        if cfg.validate and "accel_m_s2" in cfg.outputs:  # discarded if the accel fit fails
            transients = record_transients(dev, cfg.validation_amplitude_A, float(g))
    return by_amp, msgs, transients


def _analyse_worker(job):
    """Process-pool entry: fit and validate one grip recorded by :func:`_record_worker`."""
    g, cfg, label, out, (by_amp, msgs, transients) = job
    return _analyse_grip(g, cfg, label, out, by_amp, msgs, lambda: transients)


def _identify_grip(dev: Device, k: int, g: float, cfg: IdentifyConfig, label: str, out: Path):
    """Record, fit and validate one grip level; write its recordings (``out/recordings``). Returns (report
    row, curves per output, fit per output (FitResult or None), log messages)."""
    msgs = []
    by_amp = _record_grip(dev, g, cfg, out, msgs)
    return _analyse_grip(g, cfg, label, out, by_amp, msgs,
                         lambda: record_transients(dev, cfg.validation_amplitude_A, float(g)))


def _record_grip(dev: Device, g: float, cfg: IdentifyConfig, out: Path, msgs: list) -> list:
    """The sweeps of one grip level (every amplitude, ``cfg.trials`` each), written to ``out/recordings``.
    Returns [(condition label, recordings)] per amplitude."""
    amps = tuple(cfg.amplitudes_A) or (cfg.sweep.amplitude_A,)
    by_amp = []
    n_written = 0
    for amp in amps:
        sweep = replace(cfg.sweep, amplitude_A=float(amp))
        recs = record_condition(dev, sweep, float(g), cfg.trials, reverse_half=cfg.reverse_half,
                                log=msgs.append)
        cond = f"grip {g:g} N" if len(amps) == 1 else f"grip {g:g} N, {amp:g} A"
        for rec in recs:
            rec.meta["condition"] = cond
        for rec in recs:
            write_recording(out / "recordings" / f"g{g:g}N_t{n_written}.csv", rec)
            n_written += 1
        by_amp.append((cond, recs))
    return by_amp


def _analyse_grip(g: float, cfg: IdentifyConfig, label: str, out: Path, by_amp: list, msgs: list,
                  transients):
    """ETFEs, fits and (if ``cfg.validate`` and the accel fit succeeded) the time-domain validation of one
    grip level recorded by :func:`_record_grip`; ``transients()`` gives the recorded validation transients
    ``(current, accel, position, windows)``, written to ``out/recordings``. Returns (report row, curves per
    output, fit per output (FitResult or None), log messages)."""
    recs_all = [rec for _, recs in by_amp for rec in recs]
    gcurves, gfits = {o: [] for o in cfg.outputs}, {}
    row = {"grip_N": float(g), "grip_measured_N": float(np.mean([r.meta["grip_mean_N"] for r in recs_all])),
           "trials": len(recs_all), "purpose": cfg.purpose}
    for output, opts in (("accel_m_s2", cfg.accel_options), ("position_m", cfg.position_options)):
        if output not in cfg.outputs:
            continue
        opts = replace(opts, weight=PURPOSE_WEIGHT[cfg.purpose])
        cs = [etfe(recs, output, label=cond, detrend=cfg.detrend) for cond, recs in by_amp]
        gcurves[output] = cs
        src = f"python -m devices identify --device {label}, grip {g:g} N, {len(recs_all)} trials, " \
              f"purpose {cfg.purpose}"
        res, err = _fit_one(cs, opts, src)
        if res is not None:
            res.model.fit["purpose"] = cfg.purpose
        gfits[output] = res
        short = OUTPUT_SHORT[output]
        if res is None:
            row[short] = {"error": err}
            msgs.append(f"grip {g:g} N {short}: FIT FAILED: {err}")
            continue
        m = res.metrics
        row[short] = {kk: m[kk] for kk in ("rms_db", "rms_phase_deg", "worst_band_db", "order", "delay_s")}
        row[short]["band_hz"] = list(res.model.band_hz)
        row[short]["coherence_mean"] = m["coherence_mean"]
        row[short]["peak_hz"], row[short]["peak_db"] = main_resonance(cs[len(cs) // 2], res.model.band_hz)
        msgs.append(f"grip {g:g} N {short}: order {m['order']}, delay {m['delay_s'] * 1e3:.3f} ms, "
                    f"RMS {m['rms_db']:.2f} dB, {m['rms_phase_deg']:.1f} deg, worst band {m['worst_band_db']:.2f} dB "
                    f"over {res.model.band_hz[0]:.0f}-{res.model.band_hz[1]:.0f} Hz")
    if cfg.validate and gfits.get("accel_m_s2") is not None:
        u, a, x, windows = transients()
        write_transient_recording(out / "recordings" / f"transients_g{g:g}N.csv", cfg.sweep.fs_hz, u, a, x, g)
        v = validate_model(gfits["accel_m_s2"].model, u, a, cfg.sweep.fs_hz, windows)
        row["validation"] = {"nrmse": v["nrmse"], "nrmse_per_transient": v["nrmse_per_transient"]}
        msgs.append(f"grip {g:g} N accel time-domain validation: NRMSE {v['nrmse']:.3f} "
                    f"(per transient {', '.join(f'{x:.3f}' for x in v['nrmse_per_transient'])})")
    return row, gcurves, gfits, msgs


def main_resonance(curve: Etfe, band_hz) -> tuple[float, float]:
    """(frequency Hz, magnitude dB) of the ETFE's highest resonance peak in the band.

    A peak is a local maximum standing at least 1 dB above its surroundings;
    without one, the band's maximum.
    """

    sel = (curve.f_hz >= band_hz[0]) & (curve.f_hz <= band_hz[1])
    f, db = curve.f_hz[sel], 20 * np.log10(np.abs(curve.H[sel]))
    peaks, _ = find_peaks(db, prominence=1.0)
    i = int(peaks[np.argmax(db[peaks])]) if peaks.size else int(np.argmax(db))
    return float(f[i]), float(db[i])


def format_report(report: dict) -> str:
    """Human-readable fit report (one line per grip and output)."""
    lines = [f"identification of {report['device']}: sweep {report['sweep']['f_start_hz']:g}-"
             f"{report['sweep']['f_end_hz']:g} Hz, {report['sweep']['duration_s']:g} s x "
             f"{report['sweep']['repetitions']}, {report['sweep']['amplitude_A']:g} A, {report['trials']} trials",
             f"{'grip N':>7} {'output':>9} {'order':>5} {'delay ms':>8} {'RMS dB':>7} {'RMS deg':>7} "
             f"{'worst dB':>8} {'band Hz':>11} {'peak Hz':>7} {'peak dB':>7} {'NRMSE':>6}"]
    for row in report["grips"]:
        for short in ("accel", "position"):
            if short not in row:  # an output not asked for (IdentifyConfig.outputs)
                continue
            r = row[short]
            if "error" in r:
                lines.append(f"{row['grip_N']:7.2f} {short:>9}  FIT FAILED: {r['error']}")
                continue
            nr = row.get("validation", {}).get("nrmse") if short == "accel" else None
            lines.append(f"{row['grip_N']:7.2f} {short:>9} {r['order']:5d} {r['delay_s'] * 1e3:8.3f} "
                         f"{r['rms_db']:7.2f} {r['rms_phase_deg']:7.1f} {r['worst_band_db']:8.2f} "
                         f"{r['band_hz'][0]:5.0f}-{r['band_hz'][1]:<5.0f} {r['peak_hz']:7.1f} {r['peak_db']:7.1f} "
                         f"{'' if nr is None else f'{nr:6.3f}'}")
    lines.append(f"model set grips: {report['model_set_grips_N']}; elapsed {report['elapsed_s']:.1f} s")
    return "\n".join(lines) + "\n"


def _write_json(path: Path, data: dict) -> None:
    atomic_write_text(path, json.dumps(data, indent=2, default=float) + "\n")
