"""The test suite itself: ``make test`` on a fresh clone, its wall time, its CPU time and its slowest tests.

``python -m benchmarks suite`` clones this repository's committed ``HEAD`` into a temporary folder and runs
``make test`` there as a new user would on a fresh machine: the venv is created, the system parts are
provisioned into ``.deps``, nothing is cached (a new ``XDG_CACHE_HOME``; numba's cache starts empty with the
clone). It prints the wall time, the CPU time of everything ``make`` ran (user + system, child processes
included: what the suite costs a shared machine whatever its load), the load average before and after, and
from the suite's per-test CPU log (``HFAM_TEST_CPU_LOG``, tests/support/cpuprofile.py) the timeline (when the
first test began and each worker's last one ended, from ``make``'s start), the ten slowest tests by wall and by
CPU and the CPU by test folder. Not run by ``make bench`` (a whole suite, ~5 min); options:

* ``--runs N``: N runs in a row (the target is three green runs), each on its own fresh clone; medians.
* ``--pytest-only``: skip the clone and ``make``: run ``make test``'s pytest command in this tree.
* ``--workers N``: ``TEST_WORKERS`` (default: the Makefile's).
* ``--log FILE``: keep the per-test CPU log (JSON lines) of the last run.
* ``--write-costs``: write each work unit's wall time, the median over the runs, into
  ``tests/support/unit_costs.json``: the order in which ``make test`` hands out its units, longest first
  (tests/support/parallel.py).

A failed run prints pytest's failure report (each failed test's traceback and message) under its line.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from tests.support.parallel import UNIT_COSTS, unit_of

ROOT = Path(__file__).resolve().parents[1]

#: skipped by ``python -m benchmarks`` without names (``make bench``): ask for it by name
RUN_BY_DEFAULT = False


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _loadavg() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def phases(log: Path) -> list[dict]:
    """The test phases of a CPU log (:mod:`tests.support.cpuprofile`: one JSON line per phase, with its ``nodeid``,
    ``worker``, ``phase``, ``wall_s``, ``self_s``, ``children_s`` and ``end_unix_s``); a failure's own lines left
    out; none when there is no log."""
    if not log.exists():
        return []
    return [row for row in map(json.loads, log.read_text().splitlines()) if "wall_s" in row]


def per_test(log: Path) -> dict[str, dict[str, float]]:
    """``{nodeid: {"wall_s", "cpu_s"}}`` summed over a test's phases from a CPU log."""
    tests: dict[str, dict[str, float]] = defaultdict(lambda: {"wall_s": 0.0, "cpu_s": 0.0})
    for row in phases(log):
        t = tests[row["nodeid"]]
        t["wall_s"] += row["wall_s"]
        t["cpu_s"] += row["self_s"] + row["children_s"]
    return dict(tests)


def unit_walls(log: Path) -> dict[str, tuple[float, int]]:
    """``{work unit: (wall s, tests)}`` of one run's CPU log: every phase's wall time, and the tests whose call
    phase ran, summed over the unit's tests (:func:`tests.support.parallel.unit_of`)."""
    units: dict[str, list] = defaultdict(lambda: [0.0, 0])
    for row in phases(log):
        u = units[unit_of(row["nodeid"])]
        u[0] += row["wall_s"]
        u[1] += row["phase"] == "call"
    return {k: (w, n) for k, (w, n) in units.items()}


def cost_table(runs: list[dict[str, tuple[float, int]]]) -> dict:
    """The table of ``tests/support/unit_costs.json`` from several runs' :func:`unit_walls`: each unit's median
    wall time (s, over the runs that ran it) and the seconds per test over every unit."""
    names = sorted({name for run in runs for name in run})
    walls = {name: round(statistics.median(run[name][0] for run in runs if name in run), 1) for name in names}
    tests = {name: statistics.median(run[name][1] for run in runs if name in run) for name in names}
    per_test = sum(walls.values()) / max(1.0, sum(tests.values()))
    return {"units": walls, "seconds_per_test": round(per_test, 3)}


def timeline(log: Path, start_unix: float) -> str:
    """When, in s after ``make`` began, the first test began and each worker's last test phase ended."""
    first, last = float("inf"), {}
    for row in phases(log):
        first = min(first, row["end_unix_s"] - row["wall_s"] - start_unix)
        last[row["worker"]] = max(last.get(row["worker"], 0.0), row["end_unix_s"] - start_unix)
    if not last:
        return ""
    ends = ", ".join(f"{w} {t:.0f}" for w, t in sorted(last.items()))
    return f"timeline (s after make began): first test began at {first:.0f}; each worker's last test ended: {ends}"


def folder_of(nodeid: str) -> str:
    parts = nodeid.split("::")[0].split("/")
    return "/".join(parts[:-1]) if len(parts) > 2 else parts[0]


def summary(tests: dict[str, dict[str, float]], top: int = 10) -> list[str]:
    """Lines: the ``top`` slowest tests by wall and by CPU, and the CPU of each test folder."""
    lines = [f"{len(tests)} tests; CPU in the tests {sum(t['cpu_s'] for t in tests.values()):.0f} s "
             "(the rest: venv, provisioning, pytest's start-up and collection, xdist)"]
    for key, name in (("wall_s", "wall"), ("cpu_s", "CPU")):
        lines.append(f"the {top} slowest tests by {name} (s wall, s CPU):")
        for nodeid, t in sorted(tests.items(), key=lambda kv: -kv[1][key])[:top]:
            lines.append(f"  {t['wall_s']:6.1f} {t['cpu_s']:6.1f}  {nodeid}")
    folders: dict[str, float] = defaultdict(float)
    for nodeid, t in tests.items():
        folders[folder_of(nodeid)] += t["cpu_s"]
    lines.append("CPU by folder (s):")
    lines += [f"  {cpu:6.1f}  {folder}" for folder, cpu in sorted(folders.items(), key=lambda kv: -kv[1])]
    return lines


def run_once(pytest_only: bool, workers: str | None, log: Path) -> dict:
    """One ``make test`` (or its pytest command): wall, CPU, load, exit code and the last lines printed."""
    log.unlink(missing_ok=True)
    env = dict(os.environ, HFAM_TEST_CPU_LOG=str(log))
    env.pop("PYTEST_XDIST_WORKER", None)
    scratch = Path(tempfile.mkdtemp(prefix="hfam-suite-"))
    try:
        if pytest_only:
            tree = ROOT
            make = ["make", "test"]
        else:
            tree = scratch / "clone"
            subprocess.run(["git", "clone", "-q", str(ROOT), str(tree)], check=True)
            env["XDG_CACHE_HOME"] = str(scratch / "cache")           # a fresh machine's empty user cache
            make = ["make", "test"]
        if workers is not None:
            make.append(f"TEST_WORKERS={workers}")
        if pytest_only:   # make test without its prerequisites: this tree's venv is made already
            make = ["make", "-o", ".venv/.installed", "-o", ".venv/.compiled", "-o", "deps", *make[1:]]
        load_before = _loadavg()
        cpu0, t0, start_unix = _cpu_children(), time.perf_counter(), time.time()
        proc = subprocess.run(make, cwd=tree, env=env, capture_output=True, text=True)
        wall, cpu = time.perf_counter() - t0, _cpu_children() - cpu0
        lines = (proc.stdout + proc.stderr).strip().splitlines()
        # a failed run keeps pytest's report of what failed and why (from its FAILURES section), not only its totals
        start = next((i for i, ln in enumerate(lines) if "= FAILURES =" in ln), len(lines) - 3)
        tail = lines[start:] if proc.returncode else lines[-3:]
        return {"wall_s": wall, "cpu_s": cpu, "load_before": load_before, "load_after": _loadavg(),
                "returncode": proc.returncode, "tail": tail, "timeline": timeline(log, start_unix),
                "units": unit_walls(log)}
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks suite", description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=1)
    p.add_argument("--pytest-only", action="store_true")
    p.add_argument("--workers", default=None)
    p.add_argument("--log", type=Path, default=None)
    p.add_argument("--write-costs", action="store_true")
    args = p.parse_args([] if argv is None else argv)
    log = args.log or Path(tempfile.gettempdir()) / f"hfam-suite-cpu-{os.getpid()}.jsonl"
    results = []
    for i in range(args.runs):
        r = run_once(args.pytest_only, args.workers, log)
        results.append(r)
        state = "green" if r["returncode"] == 0 else f"FAILED (exit {r['returncode']})"
        print(f"run {i + 1}: {state}; wall {r['wall_s']:.0f} s, CPU {r['cpu_s']:.0f} s (user + system, children "
              f"included); load average {r['load_before']} before, {r['load_after']} after", flush=True)
        if r["timeline"]:
            print(f"   {r['timeline']}")
        for line in r["tail"]:
            print(f"   | {line}")
    if len(results) > 1:
        print(f"median of {len(results)}: wall {statistics.median(r['wall_s'] for r in results):.0f} s, "
              f"CPU {statistics.median(r['cpu_s'] for r in results):.0f} s; "
              f"{sum(r['returncode'] == 0 for r in results)} of {len(results)} green")
    for line in summary(per_test(log)):
        print(line)
    runs = [r["units"] for r in results if r["units"]]
    if args.write_costs and runs:
        table = cost_table(runs)
        UNIT_COSTS.write_text(json.dumps(table, indent=1, sort_keys=True) + "\n", encoding="utf-8")
        print(f"wrote {UNIT_COSTS.relative_to(ROOT)}: {len(table['units'])} work units from {len(runs)} run(s)")
    if args.log is None:
        log.unlink(missing_ok=True)
    return 0 if all(r["returncode"] == 0 for r in results) else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
