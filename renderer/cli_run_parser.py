"""``python -m renderer run``: render a virtual wall under a (simulated or real) user tapping.

Example::

    python -m renderer run --device sim --transient hfam --library lib.npz \
        --stiffness 680 --taps 10 --velocity 0.1 --grip 2 --out runs/hfam

On a sim device the simulated hand taps ``--taps`` times at ``--velocity``
(TapTrajectory) and the run ends when it is done. On hardware the run lasts
``--duration`` seconds (or until Ctrl-C) in its own process
(renderer.process). Writes ``events.csv``, ``run.json`` and ``log.npz`` into
``--out`` (formats in docs/renderer.md) and prints a short table.

The parser (light: imported for ``--help``); the body is :mod:`renderer.cli_run`.
"""

from __future__ import annotations

import argparse

from plumbing.cliargs import add_renamed, positive, positive_list, vector3, with_examples
from plumbing.dispatch import Body

TRANSIENTS = ("none", "pulse", "sinusoid", "hfam")


class _Lsl(argparse.Action):
    """``--lsl``: the run's body that also streams (:mod:`renderer.cli_run_lsl`), so a run without it never
    loads pylsl; it keeps the interpreter's normal exit (liblsl sends its last samples from its own threads)."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        namespace.lsl = True
        namespace.func = Body("renderer.cli_run_lsl", "run_command")
        namespace.fast_exit = False


def register(subparsers) -> None:
    """Add the ``run`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m renderer`` sub-command parsers.
    """
    p = subparsers.add_parser("run", help="render a virtual wall under a simulated or real user tapping",
                              description="Render a virtual wall under a (simulated or real) user tapping. On a sim device the "
                                          "simulated hand taps --taps times at --velocities-m-s and the run ends when "
                                          "it is done; on hardware it lasts --duration-s (or until Ctrl-C). Outputs: "
                                          "events.csv, run.json, log.npz. A 3-D scene (meshes, objects with their own stiffness, "
                                          "friction or transient) or a 3-DOF device (sim:3d) renders with the "
                                          "god-object proxy; the simulated person taps --tap-object from above or "
                                          "--tap-target-m along --tap-direction.")
    p.add_argument("--device", default="sim", help="device string: sim (default), sim:lti, sim:<file>, sim:3d[-delta|-serial], serial:<port>, hid:<vid>:<pid>")
    p.add_argument("--transient", default="none", choices=TRANSIENTS, help="contact transient (default none)")
    p.add_argument("--library", help="HFAM library file (needed for --transient hfam)")
    p.add_argument("--transient-gain", type=float, default=None,
                   help="gain of the transient (stimuli gain; default: Table 4.1 / the library's own)")
    add_renamed(p, "--stiffness-N-m", "--stiffness", dest="stiffness", type=float, default=None,
                   help="proportional stiffness k (N/m); default 680 or the config file's")
    add_renamed(p, "--damping-N-s-m", "--damping", dest="damping", type=float, default=None, help="virtual damping on entry (N s/m); default 0 or the config file's")
    p.add_argument("--config", help="renderer config/scene file (TOML or JSON, see docs/renderer.md); default: built-in settings")
    p.add_argument("--taps", type=int, default=10, help="sim: number of taps (default 10)")
    add_renamed(p, "--velocities-m-s", "--velocity", dest="velocity", type=positive_list("--velocities-m-s"), default=[0.1],
                   help="sim: tap speed in m/s (comma list: one per tap, cycled; default 0.1)")
    add_renamed(p, "--grip-N", "--grip", dest="grip", type=float, default=2.0, help="sim: grip force in N (default 2)")
    p.add_argument("--sample", default="placeholder", help="sim: real sample under the stylus (default placeholder)")
    p.add_argument("--seed", type=int, default=0, help="sim: noise seed (default 0)")
    add_renamed(p, "--duration-s", "--duration", dest="duration", type=positive("--duration-s"), default=None,
                   help="run length in s (hardware default: until Ctrl-C; sim default: until the taps are done)")
    p.add_argument("--tap-object", default=None,
                   help="sim:3d: the scene object the simulated person taps (its name); default: whatever lies "
                        "below the tap target")
    p.add_argument("--tap-target-m", type=vector3("--tap-target-m"), default=None,
                   help="sim:3d: the point tapped, x,y,z in m (default: the surface straight below the object's "
                        "centre, or below the origin)")
    p.add_argument("--tap-direction", type=vector3("--tap-direction"), default=(0.0, 0.0, -1.0),
                   help="sim:3d: the direction the tap moves in, dx,dy,dz (default 0,0,-1: straight down)")
    p.add_argument("--realtime", action="store_true", help="sim: pace to wall-clock time (hardware always is)")
    p.add_argument("--in-process", action="store_true",
                   help="hardware: run the servo loop in this process instead of its own")
    p.add_argument("--out", required=True, help="output directory (new or empty)")
    p.add_argument("--force", action="store_true", help="write into --out even if it holds an earlier run")
    p.add_argument("--no-figure", dest="figure", action="store_false",
                   help="do not draw run.png/.svg (position, forces, acceleration, events, the wall) beside the data")
    p.add_argument("--lsl", nargs=0, action=_Lsl, default=False,
                   help="publish the servo's state (decimated), its contacts and the run's start and end as Lab "
                        "Streaming Layer streams (sim, or hardware with --in-process; docs/renderer.md)")
    p.add_argument("--lsl-rate-hz", type=float, default=1000.0, help="--lsl: the state stream's rate, Hz (default 1000)")
    with_examples(p, 'hfam-renderer run --device sim --transient pulse --stiffness-N-m 680 --taps 10 --velocities-m-s 0.1 --out runs/pulse', 'hfam-renderer run --device serial:/dev/ttyACM0 --transient hfam --library LIB.npz --duration-s 60 --out runs/hw')
    # run_command closes the device and every file and joins its threads before it returns
    p.set_defaults(func=Body('renderer.cli_run', 'run_command'), fast_exit=True)

