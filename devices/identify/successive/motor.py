"""Stage 3: the motor alone (cables disconnected): friction by slow closed-loop motion, mass by step responses
under a virtual spring (thesis sec. 3.5.2 "Motor and Encoder", eq. 3.19, Figure 3.16)."""

from __future__ import annotations

import time

import numpy as np

from .bench import Bench
from .common import ModelBuilder, StageError, StageResult, fit_on_model, log_grid_init
from .experiment import Experiment, step_sequence, virtual_spring_kd
from .friction import slow_motion_friction

CONFIG = "motor_only"


def step_experiments(fs: float, mass_guess_kg: float, gains=(500.0, 1500.0), steps_m=(0.002, -0.001, 0.0005),
                     hold_s: float = 0.12) -> list[Experiment]:
    """Position steps under PD virtual springs (lightly damped oscillations highlight the inertia); the damping
    gain keeps about 10 % of critical damping for ``mass_guess_kg`` (a few times off is harmless)."""
    ref = step_sequence(fs, steps_m, hold_s)
    return [Experiment(f"steps kp {kp:g}", np.zeros(ref.size), ref, kp, virtual_spring_kd(kp, mass_guess_kg, fs_hz=fs))
            for kp in gains]


def identify_motor(bench: Bench, builder: ModelBuilder) -> StageResult:
    """Identify ``mechanics.c_m_N``, ``mechanics.b_m_Ns_m`` (slow motion) and ``mechanics.m_m_kg`` (steps).

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
        If the fitted step responses miss the measurement by more than 30 % (NRMSE): wrong configuration.
    """
    t0 = time.perf_counter()
    bench.configure(CONFIG)
    fs = bench.info.servo_rate_hz
    c, b, rel, fig = slow_motion_friction(bench)
    builder.values.update({"mechanics.c_m_N": c, "mechanics.b_m_Ns_m": b})
    # mass guess from the motor's data sheet scale (eq. 3.19 order of magnitude): rho^2 J / h^2 with J ~ 1e-6
    info = bench.info
    m_guess = info.gear_ratio ** 2 * 1e-6 / info.handle_length_m ** 2
    exps = step_experiments(fs, m_guess)
    traces = [bench.run(e) for e in exps]
    m0 = log_grid_init(builder, CONFIG, exps, traces, "mechanics.m_m_kg", 1e-4, 1.0, n=17)
    vals, err, sims = fit_on_model(builder, CONFIG, exps, traces,
                                   {"mechanics.m_m_kg": (m0, m0 / 3, m0 * 3)}, log_params=("mechanics.m_m_kg",))
    if err > 0.3:
        raise StageError(f"motor stage: step responses fit poorly (NRMSE {err:.2f}); are the cables "
                         "disconnected and the motor free?")
    builder.values.update(vals)
    fig.update({"steps": [(e.ref_m, t.x_m, s.x_m) for e, t, s in zip(exps, traces, sims)], "fs_hz": fs})
    return StageResult("motor", CONFIG, {"mechanics.c_m_N": c, "mechanics.b_m_Ns_m": b, **vals},
                       {"mechanics.c_m_N": rel, "mechanics.b_m_Ns_m": rel, "mechanics.m_m_kg": err},
                       figure_data=fig, notes=[f"friction {c * 1e3:.2f} mN + {b:.4f} N s/m * v; mass "
                                               f"{vals['mechanics.m_m_kg'] * 1e3:.3f} g (step NRMSE {err:.4f})"],
                       elapsed_s=time.perf_counter() - t0)
