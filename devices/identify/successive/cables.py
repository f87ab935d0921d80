"""Stage 4: the cables, with the drum locked: quasi-static stiffness from a slow force cycle, then stiffness
and damping from a swept sine fitted on the built-up simulation (thesis sec. 3.5.2 "Cables", Figure 3.17)."""

from __future__ import annotations

import time

import numpy as np

from .bench import Bench
from .common import ModelBuilder, StageError, StageResult, fit_on_model
from .experiment import Experiment, chirp

CONFIG = "drum_locked"
# a cable drive's stiffness in handle space: well above a linkage's, far below a rigid body's
PLAUSIBLE_K_N_M = (2e3, 1e7)


def quasi_static_stiffness(bench: Bench, amplitude_A: float, f_hz: float = 2.0, cycles: int = 2,
                           grip_N: float = 0.0, name: str = "slow force cycle"):
    """Slope of force against encoder position for a slow sinusoidal current (N/m) and the trace."""
    fs = bench.info.servo_rate_hz
    kf = bench.info.force_per_amp_N_A
    n = int(cycles * fs / f_hz)
    ff = amplitude_A * np.sin(2 * np.pi * f_hz * np.arange(n) / fs)
    tr = bench.run(Experiment(name, ff, grip_N=grip_N))
    k, _ = np.polyfit(tr.x_m, tr.i_A * kf, 1) if np.ptp(tr.x_m) > 0 else (np.inf, 0.0)
    return float(k), tr


def identify_cables(bench: Bench, builder: ModelBuilder, sweep_amplitude_A: float = 1.0) -> StageResult:
    """Identify ``mechanics.k_c_N_m`` and ``mechanics.b_c_Ns_m``.

    Parameters
    ----------
    bench : Bench
        The device under test (configured by this stage).
    builder : ModelBuilder
        The built-up model; the identified values are added to ``builder.values``.
    sweep_amplitude_A : float
        Swept-sine amplitude (A); the slow cycle uses twice that (at most 75 % of peak).

    Returns
    -------
    StageResult

    Raises
    ------
    StageError
        If the quasi-static stiffness is implausible (outside ``PLAUSIBLE_K_N_M``: e.g. the drum is not
        locked) or the dynamic fit misses the measurement (NRMSE > 0.3).
    """
    t0 = time.perf_counter()
    bench.configure(CONFIG)
    fs = bench.info.servo_rate_hz
    amp = min(0.75 * bench.info.current_peak_A, 2.0 * sweep_amplitude_A)
    k_qs, tr_qs = quasi_static_stiffness(bench, amp)
    if not (PLAUSIBLE_K_N_M[0] <= k_qs <= PLAUSIBLE_K_N_M[1]):
        raise StageError(f"cable stage: implausible quasi-static stiffness {k_qs:.4g} N/m (expected "
                         f"{PLAUSIBLE_K_N_M[0]:g}..{PLAUSIBLE_K_N_M[1]:g} N/m): is the drum locked and are the "
                         "cables connected?")
    exps = [Experiment("cable sweep", chirp(fs, sweep_amplitude_A, 20.0, 1000.0, 0.5)),
            Experiment("cable sweep near resonance", chirp(fs, 2 * sweep_amplitude_A, 100.0, 600.0, 0.5))]
    traces = [bench.run(e) for e in exps]
    m = builder.values["mechanics.m_m_kg"]
    b0 = 0.1 * 2 * np.sqrt(k_qs * m)
    vals, err, sims = fit_on_model(builder, CONFIG, exps, traces,
                                   {"mechanics.k_c_N_m": (k_qs, k_qs / 4, k_qs * 4),
                                    "mechanics.b_c_Ns_m": (b0, b0 / 100, b0 * 100)},
                                   log_params=("mechanics.k_c_N_m", "mechanics.b_c_Ns_m"))
    if err > 0.3:
        raise StageError(f"cable stage: swept-sine response fits poorly (NRMSE {err:.2f}); is the drum locked?")
    builder.values.update(vals)
    fig = {"qs_F": tr_qs.i_A * bench.info.force_per_amp_N_A, "qs_x": tr_qs.x_m, "k_qs": k_qs,
           "sweep": (exps[0].ff_A, traces[0].x_m, sims[0].x_m), "fs_hz": fs}
    return StageResult("cables", CONFIG, vals, {k: err for k in vals}, figure_data=fig,
                       notes=[f"quasi-static slope {k_qs:.0f} N/m (encoder-limited); swept-sine fit k_c "
                              f"{vals['mechanics.k_c_N_m']:.0f} N/m, b_c {vals['mechanics.b_c_Ns_m']:.3f} N s/m "
                              f"(NRMSE {err:.4f})"], elapsed_s=time.perf_counter() - t0)
