"""Teleoperation testbed speed: a whole simulated session vs real time, and the CIMM model step per tick.

Master + slave + controller + CIMM model at 5 kHz (targets: >= 10x real time for the whole
session; CIMM model step <= 5 us per servo tick).
"""

from __future__ import annotations

import time

import numpy as np

from devices.sim import teleop_kernel as K
from devices.sim.params import default_params
from devices.sim.teleop import ENVIRONMENTS, CimmModel, Testbed
from renderer.teleop.models import cimm_params
from renderer.teleop.session import TeleopConfig, default_path, run_session


def main() -> None:
    """Print the real-time factor of a ten-tap session and the CIMM cost per tick."""
    P = default_params()
    tb = Testbed(P, P, environment=ENVIRONMENTS["hard"])
    cimm = CimmModel(cimm_params()[0])
    path, cr = default_path(tb.servo_rate_hz, 1.0, n_taps=10)
    sim_s = len(path) / tb.servo_rate_hz
    times = {}
    for ctrl in ("pf", "pf+cimm"):
        run_session(tb, TeleopConfig(controller=ctrl, lam=2.0), path[:500], cimm=cimm)  # compile / warm
        walls = []
        for _ in range(5):
            t0 = time.perf_counter()
            run_session(tb, TeleopConfig(controller=ctrl, lam=2.0), path, cimm=cimm, impact_ticks=cr)
            walls.append(time.perf_counter() - t0)
        med, best = float(np.median(walls)), min(walls)
        times[ctrl] = med
        print(f"   {ctrl:8s}: {sim_s:.1f} s session in {med:.3f} s (median of 5; best {best:.3f} s) = "
              f"{sim_s / med:.1f}x real time (target >= 10x)")
    p = tb.pack(cimm)
    s = tb.initial_state(0.0, 1.0)
    f = 2.0 * np.sin(2 * np.pi * 80 * np.arange(len(path)) / tb.servo_rate_hz)
    x = np.zeros_like(f)
    K.cimm_model_run(p, s, f[:100], x[:100])  # compile / warm
    best = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        K.cimm_model_run(p, s, f, x)
        best = min(best, time.perf_counter() - t0)
    per_tick_us = best / len(f) * 1e6
    print(f"   CIMM model step: {per_tick_us:.3f} us per servo tick "
          f"({int(round(tb.servo_rate_hz ** -1 / cimm.step_s))} substeps of {cimm.step_s * 1e6:.0f} us; "
          f"target <= 5 us)")


if __name__ == "__main__":
    main()
