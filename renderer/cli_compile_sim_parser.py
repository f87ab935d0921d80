"""``python -m renderer compile-sim``: compile the simulated closed loops ahead of time (``renderer.law.run_sim``
and ``renderer.law3.run_sim3`` as C extensions).

The parser (light: imported for ``--help``); the body is :mod:`renderer.sim_aot`.
"""

from __future__ import annotations

from plumbing.cliargs import with_examples
from plumbing.dispatch import Body


def register(subparsers) -> None:
    """Add the ``compile-sim`` command to ``python -m renderer``."""
    p = subparsers.add_parser("compile-sim", help="compile the simulated closed loop ahead of time (fast sim runs)",
                              description="Compile the simulated closed loops into extension modules, so "
                                          "simulated runs start without numba: renderer.law.run_sim (servo law + "
                                          "simulated physics) with the device's physics step, and the 3-D loop "
                                          "renderer.law3.run_sim3 (god-object proxy, 3-D law, 3-DOF device) with "
                                          "its per-tick law and proxy. Each runs by itself in the background "
                                          "after the first simulated run that finds none (HFAM_SIM_AOT=auto).")
    p.add_argument("--force", action="store_true", help="rebuild even if a build for these sources exists")
    with_examples(p, "hfam-renderer compile-sim", "hfam-renderer compile-sim --force")
    p.set_defaults(func=Body('renderer.sim_aot', 'compile_command'))

