"""Stage 5: the drum, with the linkage disconnected: friction by slow closed-loop motion of motor and drum,
then mass, viscous and Coulomb friction from step responses under virtual springs of several gains and
magnitudes fitted on the built-up simulation (thesis sec. 3.5.2 "Drum", Figure 3.19)."""

from __future__ import annotations

import time

import numpy as np

from .bench import Bench
from .common import ModelBuilder, StageError, StageResult, fit_on_model, log_grid_init
from .experiment import Experiment, step_sequence, virtual_spring_kd
from .friction import slow_motion_friction

CONFIG = "linkage_off"


def identify_drum(bench: Bench, builder: ModelBuilder) -> StageResult:
    """Identify ``mechanics.m_d_kg``, ``mechanics.b_d_Ns_m``, ``mechanics.c_d_N``.

    Parameters
    ----------
    bench : Bench
        The device under test (configured by this stage).
    builder : ModelBuilder
        The built-up model; the identified values are added to ``builder.values``.

    Returns
    -------
    StageResult

    Raises
    ------
    StageError
        If the step responses fit poorly (NRMSE > 0.3): wrong configuration (drum locked, linkage on).
    """
    t0 = time.perf_counter()
    bench.configure(CONFIG)
    fs = bench.info.servo_rate_hz
    c_tot, b_tot, rel, fig = slow_motion_friction(bench, speeds_m_s=(0.05, 0.15, 0.3), distance_m=0.06)
    c_d = max(c_tot - builder.values["mechanics.c_m_N"], 0.0)
    b_d = max(b_tot - builder.values["mechanics.b_m_Ns_m"], 0.0)
    builder.values.update({"mechanics.c_d_N": c_d, "mechanics.b_d_Ns_m": b_d})
    exps = []
    m_guess = 2 * builder.values["mechanics.m_m_kg"]
    for kp, steps in ((600.0, (0.003, -0.002, 0.0)), (2000.0, (0.001, -0.0005, 0.0))):
        kd = virtual_spring_kd(kp, m_guess, fs_hz=fs)
        ref = step_sequence(fs, steps, 0.12)
        exps.append(Experiment(f"steps kp {kp:g}", np.zeros(ref.size), ref, kp, kd))
    traces = [bench.run(e) for e in exps]
    m0 = log_grid_init(builder, CONFIG, exps, traces, "mechanics.m_d_kg", 1e-4, 1.0, n=17)
    vals, err, sims = fit_on_model(builder, CONFIG, exps, traces,
                                   {"mechanics.m_d_kg": (m0, m0 / 3, m0 * 3)}, log_params=("mechanics.m_d_kg",))
    if err > 0.3:
        raise StageError(f"drum stage: step responses fit poorly (NRMSE {err:.2f}); is the linkage disconnected "
                         "and the drum free?")
    builder.values.update(vals)
    fig.update({"steps": [(e.ref_m, t.x_m, s.x_m) for e, t, s in zip(exps, traces, sims)], "fs_hz": fs})
    return StageResult("drum", CONFIG, {"mechanics.c_d_N": c_d, "mechanics.b_d_Ns_m": b_d, **vals},
                       {"mechanics.c_d_N": rel, "mechanics.b_d_Ns_m": rel, "mechanics.m_d_kg": err},
                       figure_data=fig,
                       notes=[f"motor+drum friction {c_tot * 1e3:.2f} mN + {b_tot:.4f} N s/m * v -> drum "
                              f"{c_d * 1e3:.2f} mN, {b_d:.4f} N s/m; drum mass {vals['mechanics.m_d_kg'] * 1e3:.3f} g "
                              f"(step NRMSE {err:.4f})"], elapsed_s=time.perf_counter() - t0)
