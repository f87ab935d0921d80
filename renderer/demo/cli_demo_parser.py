"""``python -m renderer demo``: the command (sim mode: :mod:`renderer.demo.sim_demo`; a hardware device:
:mod:`renderer.demo.hw_demo`). See ``docs/demo.md``.

The parser (light: imported for ``--help``); the body is :mod:`renderer.demo.cli_demo`.
"""

from __future__ import annotations

from pathlib import Path

from plumbing.cliargs import add_renamed, with_examples
from plumbing.dispatch import Body
from plumbing.fileio import user_cache_dir
from stimuli.hfam.settings import PipelineSettings

#: the demo's default device (devices.sim.presets.CHAPTER_4_DEVICE; the parser stays light: no devices.sim import)
CHAPTER_4_DEVICE = PipelineSettings.device

from .config import DemoConfig
from .renderings import RENDERINGS


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
    p.add_argument("--device", default=CHAPTER_4_DEVICE,
                   help=f"{CHAPTER_4_DEVICE} (default: the section 4.4.3 one-dof testbed, linear linkage), sim or "
                        "sim:joystick (the Table 3.1 joystick), sim:lti, sim:<params file>, serial:<port>, hid:<vid>:<pid>")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder (default ./out/demo)")
    p.add_argument("--force", action="store_true",
                   help="replace an earlier demo's results in --out (summary.csv, traces.npz, figures)")
    p.add_argument("--cache-dir", type=Path, default=None,
                   help=f"cache folder (default $XDG_CACHE_HOME/hfam-haptics = {user_cache_dir()})")
    p.add_argument("--rebuild", action="store_true", help="rebuild the cached identification/recordings/library")
    add_renamed(p, "--velocities-m-s", "--velocities", dest="velocities", default=None, help="comma-separated tap speeds in m/s (sim; default "
                                                       + ",".join(f"{v:g}" for v in DemoConfig.velocities_m_s) + ")")
    add_renamed(p, "--grips-N", "--grips", dest="grips", default=None, help="comma-separated grips in N (sim; default "
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
                   help="hardware mode: comma-separated subset of "
                        + ",".join(r.name for r in RENDERINGS if not r.is_real)
                        + " (the real wood-on-foam sample is always first)")
    p.add_argument("--timeout", type=float, default=120.0, help="hardware mode: seconds allowed per rendering")
    p.add_argument("--scope", choices=("auto", "window", "text", "none"), default="auto",
                   help="hardware mode live scope: a matplotlib window if a display is available, else text")
    with_examples(p, "hfam-renderer demo", "hfam-renderer demo --device sim:lti --out out/demo_lti --force",
                  "hfam-renderer demo --device serial:/dev/ttyACM0 --library LIB.npz --out out/hw")
    p.set_defaults(func=Body('renderer.demo.cli_demo', 'run'))

