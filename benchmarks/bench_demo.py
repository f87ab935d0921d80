"""Demo benchmark: wall time of ``python -m renderer demo --device sim`` cold and cached (budget: < 60 s, < 15 s).

``python -m benchmarks demo`` (or ``.venv/bin/python benchmarks/bench_demo.py [--quick]``).
Each run is the real command in a fresh interpreter (imports, JIT and figures
included), timed from outside:

* fresh: empty demo cache *and* empty numba and matplotlib caches (what a
  first ``make demo`` on a new machine pays, minus the packages' install);
* cold: empty demo cache (identification, recordings and library rebuilt),
  JIT and font caches warm;
* cached: the demo cache from the previous run reused;
* fresh clone (only with ``HFAM_BENCH_FRESH_CLONE=1``: it needs a package index, uv's or pip's): ``git clone``
  of this repository into a temporary folder and ``make demo`` there, the virtual environment
  included -- what a new user's first command costs.

The machine is shared and noisy: medians over repeats, plus the ratio to each budget
(60 s fresh and cold, 15 s cached) and target (4 s cached, 45 s for ``make demo`` on a fresh
clone).
"""

from __future__ import annotations

import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BUDGET_S = {"fresh": 60.0, "cold": 60.0, "cached": 15.0}
#: the tighter targets
TARGET_S = {"cached": 4.0, "fresh clone": 45.0}


def _fresh_clone(tmp: Path) -> float:
    """Wall time of ``make demo`` in a fresh clone of this repository (venv and pipeline included)."""
    clone = tmp / "clone"
    subprocess.run(["git", "clone", "--quiet", str(ROOT), str(clone)], check=True)
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH")}
    env["XDG_CACHE_HOME"] = str(tmp / "xdg")      # an empty demo cache, as on a new machine
    t0 = time.perf_counter()
    proc = subprocess.run(["make", "demo"], cwd=clone, env=env, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"make demo in a fresh clone failed ({proc.returncode}): {proc.stderr[-2000:]}")
    shutil.rmtree(clone, ignore_errors=True)
    return dt


def _run_demo(out: Path, cache: Path, env_extra: dict | None = None) -> float:
    env = dict(os.environ)
    env.update(env_extra or {})
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "renderer", "demo", "--device", "sim:onedof", "--out", str(out),
                           "--cache-dir", str(cache), "--force"], cwd=ROOT, env=env, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"demo failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return dt


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    quick = "--quick" in argv
    reps = {"fresh": 1, "cold": 1 if quick else 2, "cached": 1 if quick else 3}
    times: dict[str, list[float]] = {k: [] for k in reps}
    with tempfile.TemporaryDirectory(prefix="bench_demo_") as tmp:
        tmp = Path(tmp)
        for i in range(reps["fresh"]):
            env = {"NUMBA_CACHE_DIR": str(tmp / f"numba{i}"), "MPLCONFIGDIR": str(tmp / f"mpl{i}")}
            times["fresh"].append(_run_demo(tmp / "out", tmp / f"fresh{i}", env))
        for i in range(reps["cold"]):
            times["cold"].append(_run_demo(tmp / "out", tmp / f"cold{i}"))
        for _ in range(reps["cached"]):
            times["cached"].append(_run_demo(tmp / "out", tmp / "cold0"))
        if os.environ.get("HFAM_BENCH_FRESH_CLONE") == "1":
            times["fresh clone"] = [_fresh_clone(tmp)]
    print(f"   make demo wall time (python -m renderer demo --device sim), {os.cpu_count()} CPUs, "
          f"load {os.getloadavg()[0]:.1f}")
    for k, v in times.items():
        med = statistics.median(v)
        budgets = [f"budget {BUDGET_S[k]:.0f} s -> {med / BUDGET_S[k]:.2f}"] if k in BUDGET_S else []
        if k in TARGET_S:
            budgets.append(f"target {TARGET_S[k]:.0f} s -> {med / TARGET_S[k]:.2f} "
                           f"({'met' if med < TARGET_S[k] else 'NOT met'})")
        print(f"   {k:11s}: median {med:6.1f} s over {len(v)} run(s) ({', '.join(f'{x:.1f}' for x in v)}); "
              + "; ".join(budgets))
    if "fresh clone" not in times:
        print("   fresh clone: not measured (HFAM_BENCH_FRESH_CLONE=1 runs `make demo` in a fresh clone, "
              f"venv included; target {TARGET_S['fresh clone']:.0f} s)")


if __name__ == "__main__":
    main()
