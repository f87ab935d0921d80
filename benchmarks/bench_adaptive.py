"""Adaptive methods: one QUEST+/Psi update (Bayes + next intensity) on 3-parameter grids (target: < 10 ms).

An update is what happens between a response and the next trial: the posterior times the response's
likelihood, normalised, and the choice of the next intensity by minimum expected entropy
(``method.update(x, correct)`` followed by ``method.next_intensity()``). Timed per trial over 80-trial runs
against a simulated observer, on the simulate-observer default grid (41 intensities x 41 thresholds x 10
slopes x 6 lapses) and a fine one (81 x 81 x 20 x 11); medians and 95th percentiles of wall time (the
machine is shared: CPU time beside it), plus the up-down staircase for scale and the final estimate().

The study's commands run with one BLAS thread (``Command.blas_threads=1``, plumbing/dispatch.py): a QUEST+
choice is a matrix-vector product, which OpenBLAS splits over threads on large grids, and on a loaded
2-core machine the threads wait for each other (the fine grid: ~35 ms wall for 8 ms CPU instead of ~2 ms).
The figures are measured in a child process with one BLAS thread, as the commands run; then once more in
this process with the library's default threads, for comparison.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time

import numpy as np

from psychophysics.observer import ObserverParams, SimulatedObserver
from psychophysics.quest import Psi, QuestPlus
from psychophysics.staircase import UpDown

TARGET_MS = 10.0
TRIALS = 80
GRIDS = {
    "default 41x41x10x6": dict(n_x=41, n_t=41, n_s=10, n_l=6),
    "fine 81x81x20x11": dict(n_x=81, n_t=81, n_s=20, n_l=11),
}


def make(cls, n_x, n_t, n_s, n_l):
    """A method on log-spaced grids 0.1..10 (stimulus, threshold), slopes 1.5..8, lapses 0..0.05."""
    return cls(intensities={"min": 0.1, "max": 10.0, "n": n_x}, thresholds={"min": 0.1, "max": 10.0, "n": n_t},
               slopes={"min": 1.5, "max": 8.0, "n": n_s}, lapses=np.linspace(0.0, 0.05, n_l).tolist(),
               guess=0.5, function="weibull", max_trials=TRIALS)


def time_updates(factory, runs: int = 3) -> tuple[list[float], list[float], float]:
    """Wall and CPU ms per update over ``runs`` 80-trial runs, and the median estimate() wall ms."""
    wall, cpu, est = [], [], []
    for r in range(runs):
        method = factory()
        obs = SimulatedObserver(ObserverParams(1.3, 3.5, 0.02, 0.5), seed=r)
        while not method.finished:
            x = method.next_intensity()
            correct = obs.respond(x)
            w0, c0 = time.perf_counter(), time.process_time()
            method.update(x, correct)
            method.next_intensity()
            wall.append(1e3 * (time.perf_counter() - w0))
            cpu.append(1e3 * (time.process_time() - c0))
        w0 = time.perf_counter()
        method.estimate()
        est.append(1e3 * (time.perf_counter() - w0))
    return wall, cpu, statistics.median(est)


def measure(label: str) -> None:
    """Print the update times of every method and grid (``label``: the BLAS threading in use)."""
    print(f"   [{label}]", flush=True)
    for grid_name, grid in GRIDS.items():
        for cls in (QuestPlus, Psi):
            n_params = grid["n_t"] * grid["n_s"] * grid["n_l"]
            build0 = time.perf_counter()
            make(cls, **grid)
            build_ms = 1e3 * (time.perf_counter() - build0)
            wall, cpu, est_ms = time_updates(lambda cls=cls, grid=grid: make(cls, **grid))
            med = statistics.median(wall)
            p95 = float(np.percentile(wall, 95))
            print(f"   {cls.name:6s} {grid_name} ({n_params} parameter sets): update median {med:.2f} ms, "
                  f"p95 {p95:.2f} ms (cpu median {statistics.median(cpu):.2f} ms; target < {TARGET_MS:.0f} ms: "
                  f"{'ok' if med < TARGET_MS else 'MISSED'}); set-up {build_ms:.1f} ms, estimate {est_ms:.2f} ms",
                  flush=True)
    wall, _, _ = time_updates(lambda: UpDown(start=10.0, step_down=[0.4, 0.2, 0.1], max_trials=TRIALS))
    print(f"   updown: update median {1e3 * statistics.median(wall):.1f} us", flush=True)


def main() -> None:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1", OMP_NUM_THREADS="1")
    subprocess.run([sys.executable, "-m", "benchmarks.bench_adaptive", "--child"], env=env, check=True)
    measure("this process, the BLAS library's default threads")


if __name__ == "__main__":
    if "--child" in sys.argv:
        measure("one BLAS thread, as `python -m study ...` runs")
    else:
        main()
