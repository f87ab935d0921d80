"""Stimuli benchmarks: HFAM library build time and run-time lookup cost.

Targets: 8 velocities x 5 grip models x 100 ms at 10 kHz built in < 1 s;
``current(v, grip)`` < 20 us per call.
"""

from __future__ import annotations

import math
import statistics
import time

import numpy as np

from benchmarks.timing import median_time

from devices.model import ZpkModel
from stimuli.hfam import BuildSettings, build_library
from stimuli.recordings import Tap

FS_HZ = 10000.0


def _pair(f_hz, zeta):
    w = 2 * math.pi * f_hz
    wd = w * math.sqrt(1 - zeta * zeta)
    return [complex(-zeta * w, wd), complex(-zeta * w, -wd)]


def _inputs():
    t = np.arange(-50, 1001) / FS_HZ
    taps = []
    for i, v in enumerate(np.linspace(0.03, 0.35, 16)):
        a = 400 * v * np.exp(-t / 0.008) * np.sin(2 * np.pi * (140 + 150 * v) * t)
        taps.append(Tap(i, float(v), t, np.where(t > 0, a, 0.0)))
    models = []
    for g, f_res in zip((0.0, 2.5, 5.0, 7.5, 10.0), (150.0, 135.0, 129.0, 120.0, 110.0)):
        zeros = [0.0, -2 * math.pi * 5.0]
        poles = _pair(f_res, 0.15) + _pair(30.0, 0.7) + [-2 * math.pi * 1500.0]
        models.append((f"grip{g}", ZpkModel(zeros, poles, 1e6, delay_s=1.5e-4, grip_N=g)))
    return taps, models



def main() -> None:
    taps, models = _inputs()
    settings = BuildSettings(n_velocities=8)
    lib, _ = build_library(taps, FS_HZ, models, settings, force_per_amp_N_A=2.35)  # warm-up
    assert lib.currents_A.shape == (8, 5, 1000)
    build_s = median_time(lambda: build_library(taps, FS_HZ, models, settings, force_per_amp_N_A=2.35), 5)
    print(f"build 8 velocities x 5 grips x 100 ms @ 10 kHz: median {build_s * 1e3:.0f} ms "
          f"(target < 1000 ms, ratio {build_s / 1.0:.2f})")

    rng = np.random.default_rng(0)
    vs = rng.uniform(0.01, 0.5, 2000).tolist()
    gs = rng.uniform(-1.0, 12.0, 2000).tolist()
    buf = np.empty(1000)

    def per_call(fn, n=2000):
        t0 = time.perf_counter()
        for v, g in zip(vs[:n], gs[:n]):
            fn(v, g)
        return (time.perf_counter() - t0) / n

    current = statistics.median(per_call(lib.current) for _ in range(7))
    into = statistics.median(per_call(lambda v, g: lib.current_into(v, g, buf)) for _ in range(7))
    print(f"current(v, grip): median {current * 1e6:.1f} us/call (target < 20 us, ratio {current / 20e-6:.2f})")
    print(f"current_into(v, grip, buf): median {into * 1e6:.1f} us/call (no allocation)")


if __name__ == "__main__":
    main()
