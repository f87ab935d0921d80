"""Psychometric fit of 7 levels x 60 trials with 1,000 parametric bootstrap resamples (target < 2 s), and per observer.

Figures (medians of repeated runs, wall and CPU time): one `psychophysics.fit` with 1,000 resamples
(logistic, normal, Weibull; 2AFC, free lapse), the profile-likelihood interval alone, and 300 observers fitted at
once without the bootstrap (the recovery test's workload).
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from psychophysics import fitting as pm
from psychophysics.psychometric import psi

REPEATS = 5


def _times(fn, repeats=REPEATS):
    wall, cpu = [], []
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


def main() -> None:
    rng = np.random.default_rng(0)
    levels = np.linspace(500.0, 800.0, 7)
    x = np.repeat(levels, 60)
    for function, slope in (("logistic", 0.03), ("normal", 0.02), ("weibull", 12.0)):
        y = (rng.random(len(x)) < psi(x, 620.0, slope, 0.5, 0.02, function)).astype(int)
        wall, cpu = _times(lambda: pm.fit(x, y, alternatives=2, function=function, bootstrap=1000))
        print(f"   fit + 1000 bootstrap resamples, {function:8s}: {wall:.3f} s wall, {cpu:.3f} s CPU "
              f"(target < 2 s)", flush=True)
    y = (rng.random(len(x)) < psi(x, 620.0, 0.03, 0.5, 0.02)).astype(int)
    wall, cpu = _times(lambda: pm.fit(x, y, alternatives=2, bootstrap=0))
    print(f"   fit + profile-likelihood interval (no bootstrap): {wall * 1e3:.1f} ms wall, {cpu * 1e3:.1f} ms CPU")
    k = rng.binomial(60, psi(levels[None, :], rng.uniform(550, 700, (300, 1)), 0.03, 0.5, 0.02))
    wall, cpu = _times(lambda: pm.fit_counts(levels, np.full(7, 60.0), k, alternatives=2, bootstrap=0), 3)
    print(f"   300 observers at once (no bootstrap): {wall:.2f} s wall, {cpu:.2f} s CPU "
          f"({wall / 300 * 1e3:.1f} ms per observer)")


if __name__ == "__main__":
    main()
