"""``python -m renderer demo``: the command (sim mode: :mod:`renderer.demo.sim_demo`; a hardware device:
:mod:`renderer.demo.hw_demo`). See ``docs/demo.md``."""

from __future__ import annotations

import math
import time
from pathlib import Path

from plumbing.fileio import check_output_dir, user_cache_dir
from plumbing.outdir import output_folder
from stimuli.hfam.pipeline import PipelineSettings

from . import runs
from .report import DEMO_PRODUCTS
from .config import DemoConfig
from .report import format_reactive
from .sim_demo import format_table, run_sim_demo


# ---------------------------------------------------------------------------------------------- CLI
def register(subparsers) -> None:
    """Add the ``demo`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m renderer`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "demo", help="virtual-wall demo: proportional walls vs pulse, sinusoid, HFAM and a real sample",
        description="Reproduce the HFAM pipeline end to end (thesis 4.4.3, 4.5.5): identify the device at several "
                    "grips, record real taps on wood on foam, build the HFAM library (cached), tap soft/firm/very "
                    "firm walls, pulse, decaying sinusoid and HFAM renderings and the real sample, print a table, "
                    "write DIR/summary.csv and figures. With a hardware device a person taps. See docs/demo.md.")
    p.add_argument("--device", default="sim", help="sim (default), sim:lti, sim:<params file>, serial:<port>, "
                                                  "hid:<vid>:<pid>")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder (default ./out/demo)")
    p.add_argument("--force", action="store_true",
                   help="replace an earlier demo's results in --out (summary.csv, traces.npz, figures)")
    p.add_argument("--cache-dir", type=Path, default=None,
                   help=f"cache folder (default $XDG_CACHE_HOME/hfam-haptics = {user_cache_dir()})")
    p.add_argument("--rebuild", action="store_true", help="rebuild the cached identification/recordings/library")
    p.add_argument("--velocities", default=None, help="comma-separated tap speeds in m/s (sim; default "
                                                       + ",".join(f"{v:g}" for v in DemoConfig.velocities_m_s) + ")")
    p.add_argument("--grips", default=None, help="comma-separated grips in N (sim; default "
                                                  + ",".join(f"{g:g}" for g in DemoConfig.grips_N) + ")")
    p.add_argument("--tap-stop-time", type=float, default=None, metavar="S",
                   help="sim: seconds after contact at which the simulated hand's aim comes to rest (default "
                        f"{PipelineSettings.tap_stop_time_s:g}; longer = more of a press; docs/demo.md)")
    p.add_argument("--record-velocities", default=None, metavar="LIST",
                   help="sim: comma-separated speeds (m/s) of the recorded real taps that build the library "
                        "(default " + ",".join(f"{v:g}" for v in PipelineSettings.record_velocities_m_s) + ")")
    p.add_argument("--sweep-amplitude", type=float, default=None, metavar="A",
                   help="sim: swept-sine current amplitude of the identification (default "
                        f"{PipelineSettings.sweep_amplitude_A:g} A)")
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    p.add_argument("--library", type=Path, default=None,
                   help="hardware mode: HFAM library (.npz) built for this device (default: none, HFAM skipped)")
    p.add_argument("--taps", type=int, default=None, help="taps per rendering (hardware default 5, sim default 1)")
    p.add_argument("--renderings", type=lambda s: tuple(x for x in s.split(",") if x), default=None,
                   help="hardware mode: comma-separated subset of " + ",".join(r.name for r in runs.RENDERINGS)
                        + " (the real sample is always first)")
    p.add_argument("--timeout", type=float, default=120.0, help="hardware mode: seconds allowed per rendering")
    p.add_argument("--scope", choices=("auto", "window", "text", "none"), default="auto",
                   help="hardware mode live scope: a matplotlib window if a display is available, else text")
    p.set_defaults(func=run)


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
        from .hw_demo import run_hardware_demo  # deferred: keeps `--help` fast (a command loads only what it runs)

        return run_hardware_demo(args)
    t0 = time.perf_counter()
    vels = _floats(args.velocities, "--velocities")
    grips = _floats(args.grips, "--grips")
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
    print()
    print(f"detail (one row per rendering x velocity x grip): {args.out / 'summary.csv'}")
    for name, path in res.figures.items():
        print(f"figure {name:9s}: {path}")
    print(f"cache: {res.pipeline.directory} ({'reused' if res.pipeline.from_cache else 'built'}); "
          f"total {time.perf_counter() - t0:.1f} s")
    return 0
