"""How ``make test`` runs on the machine's cores (pytest-xdist ``-n auto``; ``--dist loadgroup`` is in pyproject.toml).

Wired by ``tests/conftest.py``:

* **Up to two workers per core** (:func:`auto_workers`, one per core on a machine already busy, capped by memory): about
  a quarter of the suite's wall time is tests waiting on real time (sessions paced by the clock, emulators, a
  browser), which leaves a core idle under one worker per core. On this project's 2-core machines with one core
  kept busy, a fresh clone's ``make test`` took 506 s with 4 workers, 564 s with 3 and 542 s with 6 (681 s with 2).

* **Work units are modules**, not single tests (:class:`ModuleScheduling`, :func:`unit_of`): a module's tests run
  on one worker, so a module-scoped fixture (a successive isolation, a report, a firmware build) is made once, and
  tests that share files in a module never meet themselves on the other core. Every test under a folder of
  :data:`FOLDER_GROUPS` joins that folder's unit instead: for session-scoped fixtures shared by several modules
  (made once per unit). The scheduler reads the folder from the test's id: pytest-xdist's own ``xdist_group``
  mark is not used, as xdist 3.8 cannot add its group to a test's id under pytest 9 (which no longer reads the
  id it writes), so the mark would silently group nothing.
* **Longest units first** (:func:`cost_order`): the work queue is ordered by each unit's measured wall time,
  :data:`UNIT_COSTS` (a unit not in it: its number of tests times the measured seconds per test). A worker takes
  the next unit when it is free, so the run ends with short units on every worker, not one long unit on one
  (scheduled by their number of tests, a few long modules of few tests ran last: one worker ended 20-25 s after
  the others). ``python -m benchmarks suite --write-costs`` measures the table again.
* **The numba cache is filled once** (:mod:`tests.support.jitwarm`): by ``make test`` beside its other set-up, or
  where pytest runs on its own (:func:`start_jit_warmup`) while the workers import and collect; then each worker
  waits for it before its first test (:func:`wait_for_jit_warmup`).
"""

from __future__ import annotations

import fcntl
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: folder (relative to the repository, with a trailing slash) -> the work unit of every test below it: a
#: session-scoped fixture that folder's modules share (made once per unit)
FOLDER_GROUPS = {
    "tests/renderer/teleop/": "teleop-cimm-model",    # conftest.py: cimm_file, cimm_model
}

#: the work units' measured wall times (``python -m benchmarks suite --write-costs``): ``{"units": {unit: s},
#: "seconds_per_test": s}``
UNIT_COSTS = Path(__file__).with_name("unit_costs.json")

WARMUP_LOCK = "jitwarm.lock"

#: memory a worker may take at its largest (measured: 0.45-0.6 GB resident), with the processes it starts
WORKER_MEMORY_BYTES = 1 << 30


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the platform has one)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def auto_workers(cores: int | None = None, available_bytes: int | None = None, others: int | None = None) -> int:
    """xdist's ``-n auto``: two workers per core this process may run on, but one per core where as many other
    processes as cores are already running (with two suites at once on 2 cores, 4 workers each took 866 s and
    failed real-time tests, against 641 s with 2), and at most one per :data:`WORKER_MEMORY_BYTES` of available
    memory; at least 1. ``others``: processes running besides this one (:func:`running_others`).
    ``HFAM_TEST_WORKERS_PER_CORE`` changes the 2."""
    if cores is None:
        cores = usable_cores()
    if available_bytes is None:
        available_bytes = _available_memory()
    if others is None:
        others = running_others()
    per_core = float(os.environ.get("HFAM_TEST_WORKERS_PER_CORE", "2"))
    wanted = int(round(per_core * cores)) if others < cores else cores
    by_memory = available_bytes // WORKER_MEMORY_BYTES if available_bytes else 1 << 16
    return max(1, min(wanted, int(by_memory)))


def running_others(samples: int = 9, interval_s: float = 0.05) -> int:
    """The median number of processes running besides this one, from /proc/loadavg's runnable count sampled
    ``samples`` times ``interval_s`` apart (not the load average, which still counts this run's own set-up);
    0 where there is no /proc/loadavg."""
    counts = []
    for k in range(samples):
        try:
            with open("/proc/loadavg") as fh:
                counts.append(int(fh.read().split()[3].split("/")[0]) - 1)
        except (OSError, IndexError, ValueError):
            return 0
        if k + 1 < samples:
            time.sleep(interval_s)
    return sorted(counts)[len(counts) // 2]


def _available_memory() -> int | None:
    """``MemAvailable`` of /proc/meminfo in bytes (None where there is no such file)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def controller_or_alone(config) -> bool:
    """True in the process that starts the xdist workers, and in a run without xdist; False in a worker."""
    return not hasattr(config, "workerinput")


def run_base(config) -> Path:
    """The run's base temporary folder (each xdist worker's basetemp is a folder inside it)."""
    base = config._tmp_path_factory.getbasetemp()
    return base.parent if not controller_or_alone(config) else base


def start_jit_warmup(config) -> list[subprocess.Popen]:
    """Start the two :mod:`tests.support.jitwarm` processes, holding the run's warm-up lock until both end.

    The lock is taken here, before any worker exists, on a file opened here and inherited by both processes
    (an ``flock`` belongs to the open file, not to a process): no worker can take its shared lock first.
    ``HFAM_TEST_JIT_WARMUP=0`` turns it off (each kernel is then compiled by its first caller).
    """
    if not warmup_enabled() or config.option.collectonly or _cache_filled():
        return []
    base = run_base(config)
    fd = os.open(base / WARMUP_LOCK, os.O_WRONLY | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        procs = []
        for part in (0, 1):
            log = open(base / f"jitwarm-{part}.log", "w")
            procs.append(subprocess.Popen([sys.executable, "-m", "tests.support.jitwarm", "--part", str(part)],
                                          cwd=ROOT, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                          pass_fds=(fd,)))
            log.close()
    finally:
        os.close(fd)                 # the children hold the lock now (released when the last one ends)
    return procs


def warmup_enabled() -> bool:
    """False where ``HFAM_TEST_JIT_WARMUP=0`` turns the warm-up off."""
    return os.environ.get("HFAM_TEST_JIT_WARMUP", "1") != "0"


def _cache_filled() -> bool:
    """Whether numba's cache holds an entry for every kernel of :mod:`tests.support.jitwarm` (an index file
    newer than the kernel's source; a kernel whose imports were edited since is recompiled by its first caller,
    as it would be anyway). Then there is nothing to warm: a developer's second run starts at once.

    The kernels' sources are found by their module names under the repository, not imported: finding a module
    through the import system would run its packages' ``__init__`` (numba, scipy: seconds of CPU in every run).
    """
    from tests.support.jitwarm import CACHE_NAMES, KERNELS

    for module, function, _ in (k for part in KERNELS for k in part):
        source = ROOT.joinpath(*module.split(".")).with_suffix(".py")
        if not source.is_file():
            return False
        name = CACHE_NAMES.get((module, function), function)
        index = list((source.parent / "__pycache__").glob(f"{source.stem}.{name}-*.nbi"))
        if not index or max(p.stat().st_mtime for p in index) < source.stat().st_mtime:
            return False
    return True


def wait_for_jit_warmup(config) -> None:
    """Block until the run's warm-up processes have ended (at once if there were none)."""
    lock = run_base(config) / WARMUP_LOCK
    if not lock.exists():
        return
    with open(lock) as fh:
        fcntl.flock(fh, fcntl.LOCK_SH)


def report_jit_warmup(procs, config) -> str | None:
    """A line naming the log of a warm-up process that failed (the tests compile for themselves then)."""
    for part, proc in enumerate(procs):
        if proc.wait() != 0:
            return (f"numba warm-up part {part} failed (exit {proc.returncode}); the tests compiled their kernels "
                    f"themselves: {run_base(config) / f'jitwarm-{part}.log'}")
    return None


def unit_of(nodeid: str) -> str:
    """The work unit of a test: its folder's unit (:data:`FOLDER_GROUPS`), else its module; a group xdist added
    to the id (``<id>@<group>``, ``xdist_group`` under pytest < 9) is kept."""
    if nodeid.rfind("@") > nodeid.rfind("]"):
        return nodeid.rsplit("@", 1)[-1]
    module = nodeid.split("::", 1)[0]
    for folder, group in FOLDER_GROUPS.items():
        if module.startswith(folder):
            return group
    return module


def unit_costs(path: Path = UNIT_COSTS) -> tuple[dict[str, float], float]:
    """The measured wall time of each work unit (s) and per test (s), from ``path``; ``({}, 1.0)`` without a
    readable table (the units are then ordered by their number of tests)."""
    try:
        table = json.loads(path.read_text(encoding="utf-8"))
        return ({str(k): float(v) for k, v in table["units"].items()}, float(table["seconds_per_test"]))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}, 1.0


def cost_order(units: dict, costs: tuple[dict[str, float], float] | None = None) -> list[str]:
    """The work units (name -> tests), longest first: by the measured wall time of :func:`unit_costs` (or
    ``costs``), a unit not measured by its number of tests times the seconds per test; ties by name."""
    walls, per_test = unit_costs() if costs is None else costs
    return sorted(units, key=lambda unit: (-walls.get(unit, per_test * len(units[unit])), unit))


def make_scheduler(config, log):
    """The :class:`ModuleScheduling` of ``--dist loadgroup`` (None for xdist's other modes)."""
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class ModuleScheduling(LoadScopeScheduling):
        """xdist's ``loadscope`` with the units of :func:`unit_of`, longest first (:func:`cost_order`)."""

        def _split_scope(self, nodeid: str) -> str:
            return unit_of(nodeid)

        def schedule(self) -> None:
            # xdist's LoadScopeScheduling.schedule with the units ordered by cost_order (xdist orders them by
            # their number of tests); the nodes' collections keep their own order (tests are sent by index)
            assert self.collection_is_completed
            if self.collection is not None:
                for node in self.nodes:
                    self._reschedule(node)
                return
            if not self._check_nodes_have_same_collection():
                self.log("**Different tests collected, aborting run**")
                return
            self.collection = list(next(iter(self.registered_collections.values())))
            if not self.collection:
                return
            units: dict[str, dict[str, bool]] = {}
            for nodeid in self.collection:
                units.setdefault(self._split_scope(nodeid), {})[nodeid] = False
            for scope in cost_order(units):
                self.workqueue[scope] = units[scope]
            for _ in range(len(self.nodes) - len(self.workqueue)):
                unused, _assigned = self.assigned_work.popitem()
                unused.shutdown()
            for node in self.nodes:
                self._assign_work_unit(node)
            for node in self.nodes:
                self._reschedule(node)
            if not self.workqueue:
                for node in self.nodes:
                    node.shutdown()

    return ModuleScheduling(config, log)
