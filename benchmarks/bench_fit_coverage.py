"""Coverage of the printed 95 % threshold interval on hidden observers: on- and off-slope designs, every task.

Each row simulates hidden observers (seeded), fits them by maximum likelihood (``fit_counts``, free lapse in
[0, 0.1], ``bootstrap = 0``) and counts how often the printed profile-likelihood interval holds the true
threshold. Printed per row: design, function, task, observers, coverage with its exact (Clopper-Pearson)
binomial 95 % interval, and the median threshold error (estimate / truth - 1).

Designs (levels fixed, the observers drawn so that the levels sit on a chosen part of their sigmoid F, before
the guess and lapse rates scale it):

* ``on-slope``: threshold uniform in the middle third of the levels, 10-90 % width 0.4-0.8 of their span
  (the generator of ``tests/psychophysics/test_intervals.py``);
* ``low side``: the lowest level at F = 0.05-0.15, the highest at F = 0.40-0.60 (for 2AFC, about 55-75 %
  correct): the threshold at or above the top of the levels;
* ``high side``: the lowest level at F = 0.60-0.80, the highest at F = 0.97-0.995 (for 2AFC, about 80-99 %
  correct): the threshold at or below the bottom of the levels.

Tasks: 2AFC and 3AFC, 7 levels x 50 trials (1-4, the Weibull on the same levels); yes/no, 8 levels x 100
trials, fitted with the free lower asymptote (the yes/no default), by observers without false alarms
(gamma = 0) and with 5-15 % false alarms. Lapse rates 0-0.04.

Runs as ``python -m benchmarks fit_coverage [--observers N] [--big-observers M] [--workers W]``; it takes
minutes (not run by ``make bench`` unless named).
"""

from __future__ import annotations

import argparse
import math
import multiprocessing
import time

import numpy as np
from scipy import stats

from psychophysics import fitting as pm
from psychophysics.psychometric import base_quantile, from_axis, psi, stimulus_axis

RUN_BY_DEFAULT = False

TASKS = {  # name: (alternatives, levels, trials per level, lower asymptote fitted, false alarms)
    "2AFC": (2, np.linspace(1.0, 4.0, 7), 50, "fixed", False),
    "3AFC": (3, np.linspace(1.0, 4.0, 7), 50, "fixed", False),
    "yes/no": (1, np.linspace(1.0, 4.0, 8), 100, "free", False),
    "yes/no, 5-15 % FA": (1, np.linspace(1.0, 4.0, 8), 100, "free", True),
}
DESIGNS = ("on-slope", "low side", "high side")
FUNCTIONS = ("weibull", "normal")
#: F at the lowest and the highest level, each drawn uniformly from its range (off-slope designs)
F_RANGES = {"low side": ((0.05, 0.15), (0.40, 0.60)), "high side": ((0.60, 0.80), (0.97, 0.995))}


def observers(design: str, function: str, levels, n_obs: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Hidden observers' thresholds (stimulus units) and slopes (the function's own beta) for a design."""
    u = stimulus_axis(levels, function)
    u_lo, u_hi = u[0], u[-1]
    span = u_hi - u_lo
    if design == "on-slope":
        a = rng.uniform(u_lo + 0.35 * span, u_lo + 0.65 * span, n_obs)
        width = rng.uniform(0.4, 0.8, n_obs) * span                 # 10-90 % width on the function's axis
        beta = (base_quantile(0.9, function) - base_quantile(0.1, function)) / width
    else:
        (f0, f1), (g0, g1) = F_RANGES[design]
        z_lo = base_quantile(rng.uniform(f0, f1, n_obs), function)
        z_hi = base_quantile(rng.uniform(g0, g1, n_obs), function)
        beta = (z_hi - z_lo) / span
        a = u_lo - z_lo / beta
    return from_axis(a, function), beta


def run_row(job) -> tuple:
    """One row (or one share of a row): (key, covered flags, relative threshold errors, open ends, seconds)."""
    key, design, function, task, n_obs, seed = job
    alternatives, levels, per_level, lower, false_alarms = TASKS[task]
    rng = np.random.default_rng(seed)
    thr, beta = observers(design, function, levels, n_obs, rng)
    lapse = rng.uniform(0.0, 0.04, n_obs)
    guess = rng.uniform(0.05, 0.15, n_obs) if false_alarms else np.full(n_obs, pm.guess_rate(alternatives))
    p = psi(levels[None, :], thr[:, None], beta[:, None], guess[:, None], lapse[:, None], function)
    k = rng.binomial(per_level, p).astype(float)
    t0 = time.perf_counter()
    fits = pm.fit_counts(levels, np.full(len(levels), float(per_level)), k, alternatives, function, bootstrap=0,
                         lower_asymptote=lower)
    seconds = time.perf_counter() - t0
    ci = np.array([f.threshold_ci for f in fits], dtype=float)
    est = np.array([f.threshold for f in fits], dtype=float)
    covered = (ci[:, 0] <= thr) & (thr <= ci[:, 1])
    open_ends = ~np.isfinite(ci).all(axis=1)
    return key, covered, est / thr - 1.0, open_ends, seconds


def jobs(n_obs: int, big: int, share: int = 250) -> list[tuple]:
    """Every row, split into shares of at most ``share`` observers (each with its own seed) to balance workers."""
    out = []
    seed = 1000
    for task in TASKS:
        for function in FUNCTIONS:
            for design in DESIGNS:
                total = big if (task, function, design) == ("2AFC", "normal", "on-slope") else n_obs
                for start in range(0, total, share):
                    seed += 1
                    out.append(((design, function, task), design, function, task, min(share, total - start), seed))
    return out


def table(results: dict) -> list[str]:
    """The printed (Markdown) table, rows in a fixed order."""
    lines = ["| design | function | task | observers | coverage [binomial 95 %] | median threshold error | "
             "open intervals |", "|---|---|---|---|---|---|---|"]
    for task in TASKS:
        for function in FUNCTIONS:
            for design in DESIGNS:
                parts = results.get((design, function, task))
                if not parts:
                    continue
                cov = np.concatenate([c for c, _, _ in parts])
                err = np.concatenate([e for _, e, _ in parts])
                opened = np.concatenate([o for _, _, o in parts])
                ci = stats.binomtest(int(cov.sum()), len(cov)).proportion_ci(0.95, method="exact")
                flag = "" if 0.93 <= cov.mean() <= 0.97 else " (outside 93-97 %)"
                bias = np.median(err[np.isfinite(err)]) * 100
                lines.append(f"| {design} | {function} | {task} | {len(cov)} | {cov.mean():.3f} "
                             f"[{ci.low:.3f}, {ci.high:.3f}]{flag} | {bias:+.1f} % | {opened.mean() * 100:.1f} % |")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks fit_coverage", description=__doc__.splitlines()[0])
    p.add_argument("--observers", type=int, default=250, help="hidden observers per row (default 250)")
    p.add_argument("--big-observers", type=int, default=1000,
                   help="observers of the normal 2AFC on-slope row (default 1000)")
    p.add_argument("--workers", type=int, default=2, help="worker processes (default 2: the machine is shared)")
    a = p.parse_args([] if argv is None else argv)
    todo = jobs(a.observers, a.big_observers)
    results: dict = {}
    t0 = time.perf_counter()
    fit_seconds = 0.0
    with multiprocessing.get_context("spawn").Pool(a.workers) as pool:
        for key, cov, err, opened, sec in pool.imap_unordered(run_row, todo):
            results.setdefault(key, []).append((cov, err, opened))
            fit_seconds += sec
            print(f"   done {key[2]:<18} {key[1]:<8} {key[0]:<9} {len(cov):4d} observers, coverage "
                  f"{cov.mean():.3f}, {sec:.1f} s", flush=True)
    wall = time.perf_counter() - t0
    print()
    for line in table(results):
        print(line)
    n_fits = sum(len(c) for parts in results.values() for c, _, _ in parts)
    print(f"\n   {n_fits} fits in {wall:.0f} s wall on {a.workers} workers ({fit_seconds:.0f} s of fitting; "
          f"{1000 * fit_seconds / max(n_fits, 1):.0f} ms per fit)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
