"""``python -m renderer compile-sim``: compile the simulated closed loop ahead of time (``renderer.law.run_sim``
as a C extension).

The parser (light: imported for ``--help``); the body is :mod:`renderer.sim_aot`.
"""

from __future__ import annotations

from plumbing.cliargs import with_examples
from plumbing.dispatch import Body


def register(subparsers) -> None:
    """Add the ``compile-sim`` command to ``python -m renderer``."""
    p = subparsers.add_parser("compile-sim", help="compile the simulated closed loop ahead of time (fast sim runs)",
                              description="Compile renderer.law.run_sim (servo law + simulated physics) and the "
                                          "device's physics step into an extension module, so simulated runs "
                                          "start without numba. Runs by itself in the background after the "
                                          "first simulated run that finds none (HFAM_SIM_AOT=auto).")
    p.add_argument("--force", action="store_true", help="rebuild even if a build for these sources exists")
    with_examples(p, "hfam-renderer compile-sim", "hfam-renderer compile-sim --force")
    p.set_defaults(func=Body('renderer.sim_aot', 'compile_command'))

