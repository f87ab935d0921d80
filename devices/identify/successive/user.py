"""Stage 8: the user's impedance from held sweeps at several grips and its grip dependence (thesis sec. 3.5.2
"Handle and User Impedance", Figure 3.22; stiffness and damping rising linearly with grip from zero)."""

from __future__ import annotations

import time

import numpy as np
from scipy.signal import savgol_filter

from .bench import Bench
from .common import ModelBuilder, StageError, StageResult, default_person, fit_on_model, nrmse
from .experiment import Experiment, chirp

CONFIG = "assembled"
NOMINAL_GRIP_N = 2.0


def _regression_init(tr, kf: float, mass: float, c: float, b_dev: float) -> tuple[float, float]:
    """Rigid-body estimate: kf i = M a + (b_dev + b_u) v + c sgn(v) + k_u x, solved for k_u, b_u."""

    fs = tr.fs_hz
    x = savgol_filter(tr.x_m, 101, 3)
    v = savgol_filter(tr.x_m, 101, 3, deriv=1) * fs
    a = savgol_filter(tr.x_m, 101, 3, deriv=2) * fs * fs
    F = np.concatenate([[0.0], tr.i_A[:-1]]) * kf - mass * a - b_dev * v - c * np.sign(v)
    A = np.column_stack([x, v])
    (k, b), *_ = np.linalg.lstsq(A[200:-200], F[200:-200], rcond=None)
    return float(k), float(b)


def _grid_init(builder: ModelBuilder, exps, trs) -> tuple[float, float]:
    """Best (k_u, b_u) at the nominal grip on a coarse log grid (1-3000 N/m, 0.3-300 N s/m)."""
    best, best_e = (100.0, 10.0), np.inf
    for k in np.geomspace(1.0, 3000.0, 8):
        for b in np.geomspace(0.3, 300.0, 7):
            sims = builder.simulate_each(CONFIG, exps, {"user.k_u_N_m": float(k), "user.b_u_Ns_m": float(b),
                                                        "user.nominal_grip_N": NOMINAL_GRIP_N}, quantized=False)
            errs = []
            for t, s_ in zip(trs, sims):
                errs.append(nrmse(t.x_m, s_.x_m))
                if sum(errs) > best_e * (1.0 + 1e-12):
                    break   # the other experiments only add to it (the margin: any summation's rounding)
            else:
                e = sum(errs)
                if e < best_e:
                    best, best_e = (float(k), float(b)), e
    return best


def _fit_grip(builder: ModelBuilder, exps, trs, k0: float, b0: float):
    """k_u, b_u (expressed at the nominal grip) fitted to one grip's held responses."""
    return fit_on_model(builder, CONFIG, exps, trs,
                        {"user.k_u_N_m": (k0, k0 / 8, k0 * 8), "user.b_u_Ns_m": (b0, b0 / 8, b0 * 8)},
                        fixed={"user.nominal_grip_N": NOMINAL_GRIP_N}, max_nfev=40, channel="xa",
                        log_params=("user.k_u_N_m", "user.b_u_Ns_m"))


def identify_user(bench: Bench, builder: ModelBuilder, grips_N=(1.0, 2.0, 3.0, 4.0),
                  amplitude_A: float = 0.3) -> StageResult:
    """Identify ``user.k_u_N_m`` and ``user.b_u_Ns_m`` at ``user.nominal_grip_N`` (2 N).

    At each grip a current step (the hand's spring shows in the creep to its final deflection, its damping
    in the time constant b_u/k_u) and a low-frequency swept sine (1-40 Hz) are played while the user holds; k_u(g) and b_u(g) are fitted on the full model (encoder position), then lines
    through the origin give the per-newton slopes (k_u = s_k g).

    Parameters
    ----------
    bench : Bench
        The device under test (configured by this stage).
    builder : ModelBuilder
        The built-up model; the identified values are added to ``builder.values``.
    grips_N : sequence of float
        Grips the user holds at (N).
    amplitude_A : float
        Step and sweep amplitude (A).

    Returns
    -------
    StageResult

    Raises
    ------
    StageError
        If a grip's fit misses (NRMSE > 0.3) or no grip gives a positive stiffness.
    """
    t0 = time.perf_counter()
    bench.configure(CONFIG)
    info = bench.info
    fs, kf = info.servo_rate_hz, info.force_per_amp_N_A
    v = builder.values
    mass = v["mechanics.m_m_kg"] + v["mechanics.m_d_kg"] + v["mechanics.m_h_kg"]
    c = v["mechanics.c_m_N"] + v["mechanics.c_d_N"]
    b_dev = v["mechanics.b_m_Ns_m"] + v["mechanics.b_d_Ns_m"]
    person = default_person()
    per_grip = {}
    for g in grips_N:
        n = int(1.2 * fs)
        step = np.concatenate([np.full(n, amplitude_A), np.zeros(n)])
        exps = [Experiment(f"held step {g:g} N", step, grip_N=g),
                Experiment(f"held sweep {g:g} N", chirp(fs, amplitude_A, 1.0, 100.0, 1.0, taper_s=0.1), grip_N=g)]
        trs = [bench.run(e) for e in exps]
        k0, b0 = _regression_init(trs[0], kf, mass, c, b_dev)
        per_grip[g] = (exps, trs, max(k0, 1.0) * NOMINAL_GRIP_N / g, max(b0, 0.1) * NOMINAL_GRIP_N / g)
    m_arm = None
    order = list(grips_N)
    if person is not None:
        # a person with momentum: the hand mass behind the grip impedance is fitted with k_u, b_u at the
        # middle grip (from a coarse grid), then held for the other grips
        g_mid = grips_N[len(grips_N) // 2]
        exps, trs, _, _ = per_grip[g_mid]
        k0, b0 = _grid_init(builder, exps, trs)
        m0 = float(person.arm_mass_kg)
        vm, _, _ = fit_on_model(builder, CONFIG, exps, trs,
                                {"user.k_u_N_m": (k0, k0 / 8, k0 * 8), "user.b_u_Ns_m": (b0, b0 / 8, b0 * 8),
                                 "person.arm_mass_kg": (m0, m0 / 10, m0 * 10)},
                                fixed={"user.nominal_grip_N": NOMINAL_GRIP_N}, max_nfev=60, channel="xa",
                                log_params=("user.k_u_N_m", "user.b_u_Ns_m", "person.arm_mass_kg"))
        m_arm = vm["person.arm_mass_kg"]
        builder.values["person.arm_mass_kg"] = m_arm
        per_grip[g_mid] = (exps, trs, vm["user.k_u_N_m"], vm["user.b_u_Ns_m"])
        order = [g_mid] + [g for g in grips_N if g != g_mid]
    fits, prev = {}, None
    for g in order:
        exps, trs, k0, b0 = per_grip[g]
        if prev is not None:  # k_u, b_u at the nominal grip: the previous grip's values are the best start
            k0, b0 = prev
        res = _fit_grip(builder, exps, trs, k0, b0)
        if res[1] > 0.05:
            # the rigid-body estimate misses (e.g. a person whose muscles hold the hand): start from the
            # best point of a coarse grid instead
            k0, b0 = _grid_init(builder, exps, trs)
            res2 = _fit_grip(builder, exps, trs, k0, b0)
            res = res2 if res2[1] < res[1] else res
        fits[g] = res
        prev = (res[0]["user.k_u_N_m"], res[0]["user.b_u_Ns_m"])
    ks, bs, errs, fig_sw = [], [], [], []
    for g in grips_N:
        vals, err, sims = fits[g]
        if err > 0.3:
            raise StageError(f"user stage: held sweep at {g:g} N fits poorly (NRMSE {err:.2f}); was the handle "
                             "held steadily at that grip?")
        scale = NOMINAL_GRIP_N / g
        trs = per_grip[g][1]
        ks.append(vals["user.k_u_N_m"] / scale)
        bs.append(vals["user.b_u_Ns_m"] / scale)
        errs.append(err)
        fig_sw.append((g, trs[0].x_m, sims[0].x_m, trs[1].x_m, sims[1].x_m))
    g = np.asarray(grips_N, float)
    s_k = float(np.dot(g, ks) / np.dot(g, g))
    s_b = float(np.dot(g, bs) / np.dot(g, g))
    if s_k <= 0:
        raise StageError("user stage: no positive user stiffness identified")
    lin_k = float(np.sqrt(np.mean((np.asarray(ks) - s_k * g) ** 2)) / (s_k * g.mean()))
    lin_b = float(np.sqrt(np.mean((np.asarray(bs) - s_b * g) ** 2)) / (s_b * g.mean()))
    vals = {"user.k_u_N_m": s_k * NOMINAL_GRIP_N, "user.b_u_Ns_m": s_b * NOMINAL_GRIP_N,
            "user.nominal_grip_N": NOMINAL_GRIP_N}
    builder.values.update(vals)
    residuals = {"user.k_u_N_m": float(np.mean(errs)) + lin_k, "user.b_u_Ns_m": float(np.mean(errs)) + lin_b,
                 "user.nominal_grip_N": 0.0}
    notes = []
    if m_arm is not None:
        vals["person.arm_mass_kg"] = m_arm
        residuals["person.arm_mass_kg"] = float(np.mean(errs))
        notes.append(f"hand mass behind the grip impedance {m_arm * 1e3:.1f} g")
    fig = {"grips_N": list(grips_N), "k_u": ks, "b_u": bs, "s_k": s_k, "s_b": s_b, "sweeps": fig_sw, "fs_hz": fs}
    return StageResult("user", CONFIG, vals, residuals, figure_data=fig,
                       notes=notes + [f"k_u(g) = {s_k:.2f} N/m per N (linearity residual {lin_k:.3f}), b_u(g) = {s_b:.3f} "
                              f"N s/m per N ({lin_b:.3f}); per grip k_u " + ", ".join(f"{k:.1f}" for k in ks)
                              + " N/m, b_u " + ", ".join(f"{b:.2f}" for b in bs) + " N s/m"],
                       elapsed_s=time.perf_counter() - t0)
