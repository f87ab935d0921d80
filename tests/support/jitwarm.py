"""Fill numba's on-disk cache of the project's kernels before the tests run: ``python -m tests.support.jitwarm``.

A fresh clone has no cache: the first process that calls a kernel compiles it (``renderer.law.run_sim`` alone
takes ~5 s of CPU) and writes it next to its source (``__pycache__``, plumbing/jitcache.py); every later
process loads it in milliseconds. With two xdist workers starting together, both would compile the same
kernels at the same moment, and so could the command a test starts. ``make test`` therefore runs this module
in two processes (``--part 0``/``1``: the kernels split into halves of about the same compile time) beside
its other set-up (the tests' byte-code, the system parts), with ``--if-needed``: nothing to do when the cache
is filled already. A run of pytest on its own does it in ``tests/conftest.py`` instead, while the workers
import and collect, and the workers wait for it before their first test: the parts inherit an exclusive
``fcntl`` lock (held by an open file they share, released when both have ended, however they end), on which
each worker takes a shared lock.

Each kernel is compiled for the argument types the project calls it with (``Dispatcher.compile``, which
saves to the cache like a first call does). A signature that drifts from the calls only costs the compile
this module saves -- the call compiles its own types -- never a wrong result: the cache is keyed by types.
"""

from __future__ import annotations

import argparse
import importlib
import sys

A = "float64[::1]"
U = "uint64[::1]"
A2 = "float64[:, ::1]"
IA = "int64[::1]"
F, I, B = "float64", "int64", "boolean"

#: (module, function, argument types) of every kernel the suite's processes compile, in two parts of about
#: equal cost (measured from an empty cache on 2 cores: part 0 ~14 s of CPU, the 1-DOF closed loop, the
#: identification and HFAM kernels (~7 s) and the teleoperation session (~6.5 s); part 1 ~12.5 s, the 3-DOF
#: proxy and loop, which also compile the lateral axes' step). None: the signature of renderer.sim_aot. A
#: kernel listed here is one its module's ``__pycache__`` names (parallel._cache_filled looks for
#: ``<module>.<function>-*.nbi``, or the name of :data:`CACHE_NAMES`). A caller compiled by numba that passes
#: a constant makes an entry of its own (numba types it ``Literal``): the suite's callers pass variables.
KERNELS = (
    (("renderer.law", "run_sim", None),
     ("devices.sim.kernel", "tick", None),           # compiled with run_sim: found in the cache here
     ("renderer.law", "run_homing", (A, A, A, A, U, A, A, I)),   # renderer.homing on the simulated device
     ("devices.identify._fastplay", "play_open", (A, A, U, A, A, I, F, A, F, F, F, F, A, A, A)),
     ("devices.identify.successive._fastrun", "run_pd", (A, A, U, A, A, A, A, B, F, F, F, F, F, F, A, A, A, A)),
     ("stimuli.hfam._fasttap", "tap_on_wall", (A, A, A, U, A, A, A, F, F, I, A, A, A, A)),
     ("devices.sim.teleop_kernel", "run_session", (A, A, U, A, A, A2, I, I, I))),
    (("renderer.proxy", "proxy_step", (A2, A2, A2, IA, A, F, F, F)),
     ("renderer.proxy", "first_hit", (A2, A2, A2, IA, F, F, F, F, F, F)),
     ("renderer.proxy", "proxy_force", (A, F, F, F, F)),
     ("renderer.law3", "law3_tick", (A, A, A2, A2, A2, IA, A2, F, F, F, F, F, F, I)),
     ("renderer.law3", "run_sim3", (A, A, A2, A2, A2, IA, A2, A, A, A, U, A, A, A, A, A, F, I))),
)

#: the name numba's cache files carry for a kernel made by ``njit(...)(f)`` from a function of another name
#: (the file is named after ``f``): (module, kernel) -> that name
CACHE_NAMES = {("renderer.law3", "law3_tick"): "_law3_tick"}


def _signature(function: str, args) -> tuple:
    # imported here: parallel._cache_filled reads KERNELS in every test run, which then needs no numba
    from numba.core import sigutils

    from renderer import sim_aot

    if args is None:
        text = sim_aot.SIGNATURE if function == "run_sim" else sim_aot.TICK_SIGNATURE
        return sigutils.normalize_signature(text)[0]
    return tuple(sigutils.normalize_signature(f"({a},)")[0][0] for a in args)


def warm(part: int) -> None:
    """Compile (or find in the cache) the kernels of ``part`` (0 or 1)."""
    for module, function, args in KERNELS[part]:
        kernel = getattr(importlib.import_module(module), function)
        kernel.compile(_signature(function, args))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tests.support.jitwarm", description=__doc__.splitlines()[0])
    p.add_argument("--part", type=int, choices=(0, 1), required=True)
    p.add_argument("--if-needed", action="store_true",
                   help="do nothing where the cache holds every kernel already, or HFAM_TEST_JIT_WARMUP=0")
    args = p.parse_args(argv)
    if args.if_needed:
        from tests.support.parallel import _cache_filled, warmup_enabled

        if not warmup_enabled() or _cache_filled():
            return 0
    warm(args.part)
    return 0


if __name__ == "__main__":
    sys.exit(main())
