"""``python -m renderer demo``: the virtual-wall demo that reproduces the HFAM pipeline end to end.

Sim mode (default, ``--device sim``), thesis sections 4.4.3 and 4.5.5:

1. identify the sim device at several grips, record real taps on the
   simulated wood-on-foam sample and build the HFAM library (cached, see
   :mod:`renderer.demo.cache`);
2. let the simulated user tap every rendering (:data:`renderer.demo.runs.RENDERINGS`)
   at several velocities and grips;
3. print a table per rendering and write ``DIR/summary.csv`` (one row per
   rendering x velocity x grip), ``DIR/fidelity.csv`` (one row per thesis claim,
   :mod:`renderer.demo.fidelity`) plus ``DIR/traces.npz``;
4. write the figures (``DIR/fig_*.png``) and print where they are.

With a hardware device string (``serial:...``, ``hid:...``) a person taps
instead, one rendering at a time (:mod:`renderer.demo.hw_demo`).
See ``docs/demo.md``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import multiprocessing as mp
import os
import threading
import time
from pathlib import Path

import matplotlib.pyplot  # noqa: F401 (before the HFAM grid's drawing process is forked)
import numpy as np

from devices.registry import make_device
from devices.sim import ReactiveHand
from plumbing.fileio import user_cache_dir
from plumbing.pools import worker_dies_with_parent
from stimuli.hfam.pipeline import Progress

from ..teleop import claims as teleop_claims
from . import fidelity
from . import figures as figs
from . import runs
from . import study_rows, thesis_rows
from .cache import Pipeline, build_or_load, code_digest, entry_hfam_claims, keep_figures, restore_figures
from .config import DemoConfig, DemoResult
from .report import write_summary, write_traces


def in_library_range(library, v_m_s: float) -> bool:
    """True if ``v_m_s`` lies within the library's recorded velocities (no extrapolation)."""
    return float(library.velocities_m_s[0]) <= v_m_s <= float(library.velocities_m_s[-1])


_JOB: tuple | None = None  # (cfg, pipe, refs) shared with forked tap workers


def _can_fork() -> bool:
    """Fork workers only from a single-threaded process (a fork copies locks other threads may hold)."""
    return "fork" in mp.get_all_start_methods() and threading.active_count() == 1


def _draw_aside(target, args: tuple):
    """Start ``target(*args)`` (figures) in a forked process beside this one; None where no fork is safe
    or the machine has one core (the caller then draws them itself). :func:`_drawn_aside` joins it."""
    if not (_can_fork() and (os.cpu_count() or 1) > 1):
        return None
    proc = mp.get_context("fork").Process(target=target, args=args, daemon=True)
    proc.start()
    return proc


def _drawn_aside(proc) -> bool:
    """Join a process of :func:`_draw_aside`: True if it drew its figures, False if the caller must (no
    process, or it failed: drawn again here, its traceback shows)."""
    if proc is None:
        return False
    proc.join()
    return proc.exitcode == 0


def _hand(cfg: DemoConfig) -> dict:
    """The simulated hand of the recordings, used for every rendering too (same tap, apples to apples)."""
    return {"stop_time_s": cfg.pipeline.tap_stop_time_s}


def _tap_rendering(index: int) -> tuple[str, dict, float]:
    """Tap one rendering at every velocity x grip on a device of its own (seeded by the rendering's index)."""
    cfg, pipe, refs = _JOB
    r = cfg.renderings[index]
    t0 = time.perf_counter()
    dev = make_device(cfg.pipeline.device, seed=cfg.pipeline.seed + 2 + index)
    out = {}
    with dev:
        transient = runs.make_transient(r, pipe.library, cfg.medium_grip_N)
        for v in cfg.velocities_m_s:
            for g in cfg.grips_N:
                out[(r.name, v, g)] = [runs.add_metrics(runs.tap_sim(dev, r, transient, v, g, pipe.fs_hz,
                                                                     **_hand(cfg)), refs[v],
                                                        pipe.fs_hz) for _ in range(cfg.taps)]
    return r.name, out, time.perf_counter() - t0


def simulate(cfg: DemoConfig, pipe: Pipeline, progress: Progress, workers: int | None = None,
             meanwhile=None) -> tuple[dict, dict]:
    """Tap every rendering at every velocity x grip; returns (traces, references).

    Renderings are spread over ``workers`` forked processes (default: up to 2,
    the CPUs of the reference machine); each rendering runs on a device seeded
    by its index, so the results do not depend on the number of workers.
    ``meanwhile()`` (optional) runs in this process while the workers tap (or
    after the taps, without workers).
    """
    global _JOB

    fs = pipe.fs_hz
    refs: dict = {}
    dev = make_device(cfg.pipeline.device, seed=cfg.pipeline.seed + 1)
    with dev:
        # the reference: the real sample tapped like the library's recordings (same grip), per velocity
        for v in cfg.velocities_m_s:
            refs[v] = runs.tap_sim(dev, runs.REAL, None, v, cfg.pipeline.record_grip_N, fs, **_hand(cfg)).accel
    workers = min(2, os.cpu_count() or 1) if workers is None else workers
    n_cond = len(cfg.velocities_m_s) * len(cfg.grips_N) * cfg.taps
    _JOB = (cfg, pipe, refs)
    try:
        if workers > 1 and _can_fork():
            # the workers take SIGTERM with its default action: the pool's exit terminates them with it, and
            # a fork inside the output folder's stop_on_signals block would otherwise keep its handler (one
            # worker then waited for tasks for ever and the pool's exit with it, in a CI run)
            with mp.get_context("fork").Pool(workers, initializer=worker_dies_with_parent,
                                             initargs=(os.getpid(),)) as pool:
                done = pool.imap(_tap_rendering, range(len(cfg.renderings)))
                if meanwhile is not None:
                    meanwhile()
                    meanwhile = None
                results = []
                for name, out, dt in done:
                    progress.say(f"{name:22s} {n_cond} taps in {dt:.2f} s")
                    results.append(out)
        else:
            results = []
            for i in range(len(cfg.renderings)):
                name, out, dt = _tap_rendering(i)
                progress.say(f"{name:22s} {n_cond} taps in {dt:.2f} s")
                results.append(out)
    finally:
        _JOB = None
    if meanwhile is not None:
        meanwhile()
    traces: dict = {}
    for out in results:
        traces.update(out)
    return traces, refs


def summarize(cfg: DemoConfig, traces: dict, library) -> list[dict]:
    """One row per rendering x velocity x grip: means over the condition's taps (``SUMMARY_COLUMNS``)."""
    rows = []
    for r in cfg.renderings:
        for v in cfg.velocities_m_s:
            for g in cfg.grips_N:
                ts = traces[(r.name, v, g)]

                def mean(key, ts=ts):
                    vals = [t.metrics[key] for t in ts if t.found]
                    return float(np.mean(vals)) if vals else math.nan

                rows.append({
                    "rendering": r.name, "velocity_m_s": v, "grip_N": g,
                    "peak_accel_m_s2": mean("peak_accel_m_s2"), "dominant_freq_hz": mean("dominant_freq_hz"),
                    "penetration_mean_m": float(np.mean([t.penetration_m for t in ts if t.found]))
                    if any(t.found for t in ts) else math.nan,
                    "nrmse": mean("nrmse"), "correlation": mean("correlation"),
                    "clipped": int(sum(t.clipped for t in ts)),
                    "in_library_range": in_library_range(library, v),
                    "taps": len(ts), "missed": int(sum(not t.found for t in ts)),
                })
    return rows


def penetration_cuts(cfg: DemoConfig, rows: list[dict]) -> dict:
    """Fraction by which each transient rendering cuts the mean penetration of its wall alone (section 4.5.5).

    Pairs every rendering with a transient with the plain wall of the same
    stiffness; means over all velocities x grips. Returns name -> 1 - pen/pen_wall.
    """
    def pen(name):
        vals = [x["penetration_mean_m"] for x in rows if x["rendering"] == name and math.isfinite(x["penetration_mean_m"])]
        return float(np.mean(vals)) if vals else math.nan

    walls = {r.stiffness_N_m: r.name for r in cfg.renderings if r.transient == "none" and not r.is_real}
    out = {}
    for r in cfg.renderings:
        if r.transient != "none" and r.stiffness_N_m in walls:
            p_tr, p_wall = pen(r.name), pen(walls[r.stiffness_N_m])
            if math.isfinite(p_tr) and p_wall > 0:
                out[r.name] = 1.0 - p_tr / p_wall
    return out


def format_table(cfg: DemoConfig, rows: list[dict], library) -> str:
    """The printed table: one line per rendering (means over velocities x grips; see the header)."""
    lib_lo, lib_hi = float(library.velocities_m_s[0]), float(library.velocities_m_s[-1])
    lines = [
        f"Renderings tapped by the simulated user at {', '.join(f'{v:g}' for v in cfg.velocities_m_s)} m/s x "
        f"grips {', '.join(f'{g:g}' for g in cfg.grips_N)} N ({cfg.taps} tap(s) each).",
        f"NRMSE and correlation: handle acceleration vs the real sample at the same velocity, 20-1000 Hz, "
        f"mean over velocities inside the library range ({lib_lo:.3f}-{lib_hi:.3f} m/s); other columns: "
        f"mean (dominant frequency: median) over all taps.",
        f"{'rendering':22s} {'peak a m/s2':>11} {'f_dom Hz':>8} {'pen mm':>7} {'NRMSE':>6} {'corr':>6} "
        f"{'clipped':>8}",
    ]
    for r in cfg.renderings:
        rr = [x for x in rows if x["rendering"] == r.name]
        inr = [x for x in rr if x["in_library_range"]]

        def m(key, sel=rr):
            vals = [x[key] for x in sel if math.isfinite(x[key])]
            return float(np.mean(vals)) if vals else math.nan

        f_dom = float(np.nanmedian([x["dominant_freq_hz"] for x in rr]))
        clipped = sum(x["clipped"] for x in rr)
        taps = sum(x["taps"] for x in rr)
        lines.append(f"{r.name:22s} {m('peak_accel_m_s2'):11.1f} {f_dom:8.0f} {m('penetration_mean_m') * 1e3:7.2f} "
                     f"{m('nrmse', inr):6.3f} {m('correlation', inr):6.3f} {clipped:>4d}/{taps:<3d}")
    cuts = penetration_cuts(cfg, rows)
    if cuts:
        lines.append("Mean penetration cut by the transient vs the same wall alone: "
                     + ", ".join(f"{name} {cut * 100:.0f} %" for name, cut in cuts.items())
                     + " (thesis 4.5.5: about a factor of two; docs/demo.md, 'The simulated tap')")
    lines += clipping_explanation(rows, cuts, library)
    out_of_range = [v for v in cfg.velocities_m_s if not lib_lo <= v <= lib_hi]
    hf = [x for x in rows if x["rendering"] == "hfam_firm"]
    if out_of_range and hf:
        parts = []
        for v in out_of_range:
            sel = [x for x in hf if x["velocity_m_s"] == v]
            parts.append(f"{v:g} m/s NRMSE {np.mean([x['nrmse'] for x in sel]):.2f}, corr "
                         f"{np.mean([x['correlation'] for x in sel]):.2f}, clipped {sum(x['clipped'] for x in sel)}"
                         f"/{sum(x['taps'] for x in sel)}")
        lines.append("HFAM over firm beyond the library range (extrapolated transient): " + "; ".join(parts))
    return "\n".join(lines)


def clipping_explanation(rows: list[dict], cuts: dict, library) -> list[str]:
    """Plain-language lines where the table looks wrong: HFAM clipped on most taps, or a negative "cut".

    Parameters
    ----------
    rows : list of dict
        :func:`summarize`'s rows (``rendering``, ``clipped``, ``taps``).
    cuts : dict
        :func:`penetration_cuts` (rendering -> fraction; negative: deeper than the wall alone).
    library : stimuli.library.HfamLibrary
        The library the HFAM renderings played (its peak current and force constant).

    Returns
    -------
    list of str
        Nothing when nothing looks wrong.
    """
    out = []
    peak_lib = float(np.max(np.abs(library.currents_A)))
    for name in sorted({x["rendering"] for x in rows if x["rendering"].startswith("hfam")}):
        sel = [x for x in rows if x["rendering"] == name]
        clipped, taps = sum(x["clipped"] for x in sel), sum(x["taps"] for x in sel)
        if taps and clipped * 2 > taps:
            out.append(f"Why {name} clipped {clipped}/{taps} taps: its transients ask up to {peak_lib:.2f} A (the "
                       f"library's peak, built for a force constant of {library.force_per_amp_N_A:.3g} N/A); on this "
                       "device the wall plus the transient exceeds the peak current limit, so the amplifier's limit "
                       "cuts them (and the acceleration match). Build a library for this device (--rebuild, or "
                       "`stimuli build-library --scale-to-limit`) to render it within its limits.")
    deeper = {n: c for n, c in cuts.items() if c < 0}
    if deeper:
        out.append("A negative cut (" + ", ".join(f"{n} {c * 100:.0f} %" for n, c in deeper.items())
                   + ") means those taps went deeper with the transient than on the wall alone: while a clipped "
                   "transient plays, the peak limit also takes current from the wall's own spring, which then "
                   "holds the handle less.")
    return out


#: tap speeds (m/s) of the reactive-hand penetration check: section 4.5.5's slow-to-moderate taps
REACTIVE_VELOCITY_RANGE_M_S = (0.05, 0.15)
_REACTIVE_RENDERINGS = ("firm", "pulse_firm", "hfam_firm")


def reactive_hand_cuts(cfg: DemoConfig, pipe: Pipeline) -> dict:
    """Penetration cut of pulse and HFAM over firm with the reactive simulated hand (section 4.5.5).

    The demo's hand (eq. 3.34, tied to its trajectory) is a velocity source,
    so a transient's impulse barely changes penetration. This taps firm,
    pulse over firm and HFAM over firm once more, at the demo's velocities
    inside ``REACTIVE_VELOCITY_RANGE_M_S`` x its grips, with
    :class:`devices.sim.ReactiveHand` (default, physiologically motivated
    parameters: a 0.2 kg hand driven by a 120 N/m, 2 N s/m muscle impedance,
    40 ms contact reflex), the same tap trajectory and the same transients.

    Returns
    -------
    dict
        Empty if not applicable (no velocity in range, a device other than
        the nonlinear sim, or a rendering missing); else ``velocities_m_s``,
        ``grips_N``, ``taps``, ``penetration_m`` (rendering -> mean maximum
        penetration, m) and ``cuts`` (``pulse_firm``/``hfam_firm`` -> 1 -
        pen/pen_firm).
    """

    lo, hi = REACTIVE_VELOCITY_RANGE_M_S
    vels = tuple(v for v in cfg.velocities_m_s if lo <= v <= hi)
    by_name = {r.name: r for r in cfg.renderings}
    if not vels or any(n not in by_name for n in _REACTIVE_RENDERINGS):
        return {}
    dev = make_device(cfg.pipeline.device, seed=cfg.pipeline.seed + 1000)
    if getattr(getattr(dev, "params", None), "model", None) != "nonlinear":
        return {}
    hand = ReactiveHand()
    pen = {}
    with dev:
        for name in _REACTIVE_RENDERINGS:
            r = by_name[name]
            transient = runs.make_transient(r, pipe.library, cfg.medium_grip_N)
            vals = [runs.tap_sim(dev, r, transient, v, g, pipe.fs_hz, hand=hand, **_hand(cfg)).penetration_m
                    for v in vels for g in cfg.grips_N for _ in range(cfg.taps)]
            vals = [x for x in vals if math.isfinite(x)]
            if not vals:
                return {}
            pen[name] = float(np.mean(vals))
    cuts = {name: 1.0 - pen[name] / pen["firm"] for name in _REACTIVE_RENDERINGS[1:]}
    return {"velocities_m_s": vels, "grips_N": tuple(cfg.grips_N),
            "taps": len(_REACTIVE_RENDERINGS) * len(vels) * len(cfg.grips_N) * cfg.taps,
            "penetration_m": pen, "cuts": cuts}


def _is_nonlinear_sim(device: str) -> bool:
    """True for a sim device string whose device has the person (the nonlinear model: joystick or one-dof)."""
    if not device.startswith("sim"):
        return False
    return getattr(getattr(make_device(device), "params", None), "model", None) == "nonlinear"


def population(cfg: DemoConfig, pipe: Pipeline) -> dict:
    """The > 2 mm rows' population of persons (:func:`renderer.demo.thesis_rows.population_penetration`) on the
    demo's device and library; empty on a device without the simulated person or without operating-point speeds."""
    if not _is_nonlinear_sim(cfg.pipeline.device) or not fidelity.operating_weights(cfg.velocities_m_s):
        return {}
    return thesis_rows.population_penetration(cfg.pipeline.device, pipe.library, cfg.velocities_m_s,
                                              cfg.pipeline.tap_stop_time_s)


def more_claims(cfg: DemoConfig) -> list:
    """:func:`device_and_teleop_claims` and the simulated study's rows (:func:`renderer.demo.study_rows.study_claims`,
    read afresh: they depend on the gallery's stamp).

    The device and teleoperation rows depend on nothing but the code that computes them and the device, so they
    are kept in the user cache (``claims-<key>.json``, ``key`` hashing that code and the device; not in
    ``cache_base``, so demos with other pipeline caches share them) and read back by later demos."""
    key = hashlib.sha256((code_digest(paths=_MORE_CLAIMS_CODE) + cfg.pipeline.device
                          + repr(cfg.pipeline.tap_stop_time_s)).encode()).hexdigest()[:16]
    path = user_cache_dir() / f"claims-{key}.json"
    rows = None
    try:
        rows = fidelity.claims_from_dicts(json.loads(path.read_text()))
    except (OSError, ValueError):
        pass
    if rows is None:
        rows = device_and_teleop_claims(cfg)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
            tmp.write_text(json.dumps([dataclasses.asdict(c) for c in rows], allow_nan=True) + "\n")
            os.replace(tmp, path)
        except OSError:
            pass
    return rows + study_rows.study_claims()


#: the code the device and teleoperation rows depend on (their cache key)
_MORE_CLAIMS_CODE = ("devices", "renderer", "stimuli")


def device_and_teleop_claims(cfg: DemoConfig) -> list:
    """The rows beyond the demo's taps: section 2.2.1's wall, 3.4.6's slopes (on the demo's device), 3.5.2's
    grip-independent resonance (the joystick, chapter 3's device), chapter 5's and section 4.3.2's teleoperation
    rows (the joystick testbed). On a device without the simulated person the device rows are "not measured"."""
    out = []
    if _is_nonlinear_sim(cfg.pipeline.device):
        out += [thesis_rows.wall_resonance_claim(cfg.pipeline.device), thesis_rows.held_slopes_claim(cfg.pipeline.device)]
    else:
        out += [fidelity.Claim(cid, sec, "", "", math.nan, f"not measured: {cfg.pipeline.device} has no simulated "
                               "person", False) for cid, sec in (("wall_resonance", "2.2.1"),
                                                                 ("held_device_slopes", "3.4.6, Figure 3.12"))]
    out.append(thesis_rows.grip_resonance_claim())
    out += fidelity.claims_from_dicts(teleop_claims.teleop_claims() + [teleop_claims.delay_claim()])
    return out


def make_figures(cfg: DemoConfig, result: DemoResult, out: Path, pipeline_figures: bool = True,
                 parallel: bool = True) -> dict:
    """Write the four figures into ``out`` (the library and Bode ones only if ``pipeline_figures``); with
    ``parallel`` the HFAM grid is drawn in a forked process beside the others (two cores or more)."""

    fs, pre = result.fs_hz, runs.PRE_S
    g_mid = cfg.medium_grip_N if cfg.medium_grip_N in cfg.grips_N else cfg.grips_N[len(cfg.grips_N) // 2]
    v_fig = cfg.figure_velocity_m_s
    tr = result.traces
    names = {"firm": "firm wall 680 N/m", "pulse_firm": "pulse over firm", "sinusoid_firm": "decaying sinusoid over firm",
             "hfam_firm": "HFAM over firm", runs.REAL.name: "real wood on foam"}
    panels = [(label, tr[(name, v_fig, g_mid)][0].accel) for name, label in names.items()
              if (name, v_fig, g_mid) in tr]
    ref = tr[(runs.REAL.name, v_fig, g_mid)][0].accel if (runs.REAL.name, v_fig, g_mid) in tr else result.references[v_fig]
    panels = [(lab, ref if lab == "real wood on foam" else w) for lab, w in panels]
    vs = cfg.grid_velocities_m_s
    grips = cfg.grips_N[:3] if len(cfg.grips_N) >= 3 else cfg.grips_N
    cells = {(v, g): tr[("hfam_firm", v, g)][0].accel for v in vs for g in grips if ("hfam_firm", v, g) in tr}
    grid = None
    if len(cells) == len(vs) * len(grips):
        cur = {(v, g): tr[("hfam_firm", v, g)][0].transient_current for v in vs for g in grips}
        fixed = {(v, g): tr[("hfam_fixed_grip_firm", v, g)][0].accel for v in vs for g in grips
                 if ("hfam_fixed_grip_firm", v, g) in tr and g != cfg.medium_grip_N}
        grid = (cells, result.references, cur, fixed, vs, grips, fs, pre, out / "fig_hfam_grid.png")
    side = None
    if grid is not None and parallel:
        # the grid and the contact figure take about as long each: draw the grid in a second process,
        # forked after pyplot is imported so the child does not import it again
        side = _draw_aside(figs.hfam_grid_figure, grid)
    out_figs = {"contact": figs.contact_figure(panels, ref, fs, pre, v_fig, g_mid, out / "fig_contact.png")}
    # Figure 4.19 is at the study's taps (section 4.5.4: 0.10 +/- 0.042 m/s): the demo's speeds in 0.05-0.15 m/s
    lo, hi = fidelity.OPERATING_RANGE_M_S
    op = [v for v in cfg.velocities_m_s if lo <= v <= hi] or list(cfg.velocities_m_s)
    pen = {}
    for (name, v, _g), taps in tr.items():
        if v in op:
            pen.setdefault(name, []).extend(t.penetration_m for t in taps if t.found)
    # Figure 4.19's twelve samples (the no-grip-compensation HFAM is not one of them)
    labels = {"real_wood": "real wood", runs.REAL.name: "real wood on foam", "real_foam": "real foam",
              "soft": "soft wall 340 N/m", "firm": "firm wall 680 N/m", "very_firm": "very firm wall 1020 N/m",
              "pulse_firm": "pulse over firm", "pulse_soft": "pulse over soft", "sinusoid_firm": "sinusoid over firm",
              "sinusoid_soft": "sinusoid over soft", "hfam_firm": "HFAM over firm", "hfam_soft": "HFAM over soft"}
    out_figs["penetration"] = figs.penetration_figure(
        pen, labels, out / "fig_penetration.png", f"{', '.join(f'{v:g}' for v in op)} m/s x grips",
        {"thesis 4.5.5: wood, wood on foam < 0.25 mm": 0.25, "thesis 4.5.5: foam, soft wall > 2 mm": 2.0})
    if grid is not None:
        out_figs["hfam_grid"] = grid[-1] if _drawn_aside(side) else figs.hfam_grid_figure(*grid)
    if pipeline_figures:
        out_figs.update(_pipeline_figures(result.pipeline, cfg, out))
    return out_figs


def _pipeline_figures(pipe: Pipeline, cfg: DemoConfig, out: Path) -> dict:
    """The figures that depend only on the cached pipeline: the library (Fig. 4.8) and the Bode plot; drawn
    once per cache entry and drawing code, then copied from the cache (``cache.keep_figures``)."""

    drawn = {"library": figs.library_figure(pipe.library, cfg.medium_grip_N, Path(out) / "fig_library.png"),
             "bode": figs.bode_figure(pipe.etfe_npz, pipe.model_set, Path(out) / "fig_bode.png")}
    keep_figures(pipe, out)
    return drawn


def run_sim_demo(cfg: DemoConfig, out: Path, cache_base: Path | None = None, rebuild: bool = False,
                 figures: bool = True, progress: Progress | None = None) -> DemoResult:
    """The whole sim demo (see module doc); writes into ``out`` and returns the results."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    progress = progress or Progress(5)
    t0 = time.perf_counter()
    pipe = build_or_load(cfg.pipeline, cache_base, rebuild, progress)
    if pipe.from_cache:
        progress.i = 3
        progress.say(f"[1-3/5] identification, recordings and HFAM library from the cache: {pipe.directory}",
                     indent=False)
    t_pipe = time.perf_counter() - t0
    # the library and Bode figures need only the pipeline: copied from the cache, or drawn while the user taps
    kept = restore_figures(pipe, out) if figures else None
    side = _draw_aside(_pipeline_figures, (pipe, cfg, out)) if figures and kept is None else None
    progress.start(f"simulated user tapping {len(cfg.renderings)} renderings")
    aside: dict = {}

    def meanwhile():
        # this process waits for the tap workers: tap the reactive hand here (pyplot, which the HFAM grid's
        # drawing process needs, is imported with this module, before that process is forked)
        aside["reactive"] = reactive_hand_cuts(cfg, pipe)
        # the HFAM libraries' accuracy (open loop, unseen conditions, saturation): fidelity.csv's item-5 rows
        aside["hfam_claims"] = fidelity.claims_from_dicts(entry_hfam_claims(pipe, cfg.pipeline))
        # the thesis's other claims: the population of persons for the > 2 mm rows, the held device, the
        # teleoperation testbed and the simulated study
        aside["population"] = population(cfg, pipe)
        aside["more_claims"] = more_claims(cfg)

    traces, refs = simulate(cfg, pipe, progress, meanwhile=meanwhile)
    reactive = aside["reactive"]
    if reactive:
        progress.say(f"{'reactive hand':22s} {reactive['taps']} taps on firm, pulse and HFAM over firm")
    t_sim = progress.done()
    rows = summarize(cfg, traces, pipe.library)
    claims = (thesis_rows.with_population(fidelity.measure_claims(traces, cfg.renderings, pipe.fs_hz,
                                                                  cfg.medium_grip_N), aside["population"])
              + aside["hfam_claims"] + aside["more_claims"])
    result = DemoResult(rows, traces, refs, pipe, {}, {}, pipe.fs_hz, reactive, claims)
    write_summary(rows, out / "summary.csv")
    fidelity.write_fidelity(claims, out / "fidelity.csv")
    write_traces(result, out / "traces.npz")
    t_fig = 0.0
    if figures:
        progress.start("drawing figures")
        result.figures = make_figures(cfg, result, out, pipeline_figures=side is None and kept is None)
        if kept is not None:
            result.figures.update(kept)
        elif side is not None:
            if _drawn_aside(side):
                result.figures.update({"library": out / "fig_library.png", "bode": out / "fig_bode.png"})
            else:
                result.figures.update(_pipeline_figures(pipe, cfg, out))
        t_fig = progress.done()
    result.timings_s = {"pipeline": t_pipe, "taps": t_sim, "figures": t_fig, "total": time.perf_counter() - t0,
                        "pipeline_cached": pipe.from_cache}
    return result


