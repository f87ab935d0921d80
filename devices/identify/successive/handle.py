"""Stage 7: the handle, assembled and not held: handle mass from swept sines under a virtual spring, compared
on encoder position and handle acceleration (thesis sec. 3.5.2 "Handle and User Impedance")."""

from __future__ import annotations

import time

import numpy as np

from .bench import Bench
from .common import ModelBuilder, StageError, StageResult, fit_on_model, log_grid_init
from .experiment import Experiment, chirp

CONFIG = "assembled"


def identify_handle(bench: Bench, builder: ModelBuilder, amplitudes_A=(0.3, 1.0)) -> StageResult:
    """Identify ``mechanics.m_h_kg`` (user absent, grip 0).

    Parameters
    ----------
    bench : Bench
        The device under test (configured by this stage).
    builder : ModelBuilder
        The built-up model; the identified values are added to ``builder.values``.
    amplitudes_A : sequence of float
        Swept-sine amplitudes (A).

    Returns
    -------
    StageResult

    Raises
    ------
    StageError
        If the fit misses (NRMSE > 0.3): e.g. the handle is still locked or held.
    """
    t0 = time.perf_counter()
    bench.configure(CONFIG)
    fs = bench.info.servo_rate_hz
    exps = [Experiment(f"free handle sweep {a:g} A", chirp(fs, a, 20.0, 500.0, 0.4), np.zeros(int(0.4 * fs)),
                       800.0, 1.0, grip_N=0.0) for a in amplitudes_A]
    traces = [bench.run(e) for e in exps]
    m0 = log_grid_init(builder, CONFIG, exps, traces, "mechanics.m_h_kg", 1e-4, 1.0, n=17, channel="xa")
    vals, err, sims = fit_on_model(builder, CONFIG, exps, traces, {"mechanics.m_h_kg": (m0, m0 / 3, m0 * 3)},
                                   channel="xa", log_params=("mechanics.m_h_kg",))
    if err > 0.3:
        raise StageError(f"handle stage: free-handle sweeps fit poorly (NRMSE {err:.2f}); is the handle free "
                         "and nobody holding it?")
    builder.values.update(vals)
    fig = {"sweeps": [(e.ff_A, t.a_m_s2, s.a_m_s2) for e, t, s in zip(exps, traces, sims)], "fs_hz": fs,
           "amplitudes_A": list(amplitudes_A)}
    return StageResult("handle", CONFIG, vals, {"mechanics.m_h_kg": err}, figure_data=fig,
                       notes=[f"handle mass {vals['mechanics.m_h_kg'] * 1e3:.3f} g (NRMSE {err:.4f})"],
                       elapsed_s=time.perf_counter() - t0)
