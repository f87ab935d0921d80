"""``python -m renderer demo``: the command (sim mode: :mod:`renderer.demo.sim_demo`; a hardware device:
:mod:`renderer.demo.hw_demo`). See ``docs/demo.md``."""

from __future__ import annotations

import math
import time
from pathlib import Path

from devices.limits import check_tap_speeds
from plumbing.fileio import check_output_dir
from plumbing.outdir import output_folder
from stimuli.hfam.settings import PipelineSettings

from .fidelity import format_fidelity
from .report import DEMO_PRODUCTS
from .config import DemoConfig
from .hw_demo import run_hardware_demo
from .report import format_reactive
from .sim_demo import format_table, run_sim_demo


def _floats(text: str | None, what: str) -> tuple | None:
    if text is None:
        return None
    try:
        vals = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise ValueError(f"{what}: expected comma-separated numbers, got {text!r}") from None
    if not vals or any(not (math.isfinite(x) and x > 0) for x in vals):
        raise ValueError(f"{what}: values must be positive numbers, got {text!r}")
    return vals


def run(args) -> int:
    """The ``demo`` command: the sim demo (or, with a hardware device, the person-tapping demo); returns the exit code."""
    if not args.device.startswith("sim"):
        return run_hardware_demo(args)
    t0 = time.perf_counter()
    vels = _floats(args.velocities, "--velocities-m-s")
    if vels:
        check_tap_speeds(vels, "--velocities-m-s")   # 5 m/s (a 6.2 m/s tap, 57.5 mm in): refused
    grips = _floats(args.grips, "--grips-N")
    pipe_changes = {"device": args.device}
    if args.tap_stop_time is not None:
        pipe_changes["tap_stop_time_s"] = args.tap_stop_time
    rec = _floats(args.record_velocities, "--record-velocities")
    if rec:
        pipe_changes["record_velocities_m_s"] = rec
        pipe_changes["library_velocities"] = min(PipelineSettings.library_velocities, len(rec))
    if args.sweep_amplitude is not None:
        pipe_changes["sweep_amplitude_A"] = args.sweep_amplitude
    changes = {"pipeline": PipelineSettings(**pipe_changes)}
    if vels:
        changes["velocities_m_s"] = vels
        fig_v = min(vels, key=lambda v: abs(v - 0.11))
        changes["figure_velocity_m_s"] = fig_v
        changes["grid_velocities_m_s"] = tuple(sorted(vels, key=lambda v: abs(v - 0.08))[:3])
    if grips:
        changes["grips_N"] = grips
        changes["medium_grip_N"] = grips[len(grips) // 2]
    if args.taps is not None:
        changes["taps"] = args.taps
    cfg = DemoConfig(**changes)
    if args.cache_dir is not None:
        check_output_dir(args.cache_dir, what="--cache-dir")  # a file there: refused before anything is built
    # written beside --out and swapped in whole, one writer at a time (plumbing.outdir); the user's other
    # files in --out stay
    folder = output_folder(args.out, args.force, products=DEMO_PRODUCTS,
                           results="a demo's results").open()
    if folder.replacing:
        print(f"--force: replacing an earlier demo's results in {args.out} ({', '.join(folder.earlier_results())})")
    with folder:
        res = run_sim_demo(cfg, folder.path, args.cache_dir, args.rebuild, figures=not args.no_figures)
    res.figures = {k: folder.out / Path(p).name for k, p in res.figures.items()}
    print()
    print(format_table(cfg, res.rows, res.pipeline.library))
    if res.reactive:
        print(format_reactive(res.reactive))
    print(format_fidelity(res.claims))
    print()
    print(f"detail (one row per rendering x velocity x grip): {args.out / 'summary.csv'}")
    print(f"thesis claims (one row per claim, measured, holds or not): {args.out / 'fidelity.csv'}")
    for name, path in res.figures.items():
        print(f"figure {name:9s}: {path}")
    print(f"cache: {res.pipeline.directory} ({'reused' if res.pipeline.from_cache else 'built'}); "
          f"total {time.perf_counter() - t0:.1f} s")
    return 0
