"""Stage 6: the linkage, with the handle locked: the five hysteresis parameters k_lp, k_ln, f_lp, f_ln, gamma
from slow force/position loops (thesis sec. 3.5.2 "Linkage", sec. 3.5.3 eq. 3.20-3.31, Figure 3.20), then
the linkage damping b_l from swept sines at several amplitudes (Figure 3.21)."""

from __future__ import annotations

import time

import numpy as np

from .bench import Bench
from .common import ModelBuilder, StageError, StageResult, fit_on_model
from .experiment import Experiment, chirp

CONFIG = "handle_locked"
HYST = ("mechanics.k_lp_N_m", "mechanics.k_ln_N_m", "mechanics.f_lp_N", "mechanics.f_ln_N",
        "mechanics.gamma_l_rad_m")


def loop_current(fs: float, amplitudes_A=(3.0, 1.0, 0.3), f_hz: float = 2.0) -> np.ndarray:
    """Slow force cycles of decreasing amplitude, ``A(t) sin(2 pi f t)``: 1.5 cycles of the largest (virgin
    curve and a full loop), then one cycle of each smaller one (minor loops show the transition shape,
    i.e. gamma); the amplitude changes at zero crossings."""
    cycles = [1.5] + [1.0] * (len(amplitudes_A) - 1)
    n_half = int(round(fs / f_hz / 2))
    amp = np.concatenate([np.full(int(round(2 * c)) * n_half, a) for a, c in zip(amplitudes_A, cycles)])
    t = np.arange(amp.size) / fs
    return amp * np.sin(2 * np.pi * f_hz * t)


def linkage_loop(tr, kf: float, k_c: float, c_m: float, c_d: float):
    """Linkage deflection (m) and force (N) from a quasi-static loop: the cable stretch and the Coulomb
    friction of motor and drum (identified before) are removed from encoder position and motor force."""
    F_m = tr.i_A * kf
    dx = np.gradient(tr.x_m)
    sgn = np.sign(np.convolve(dx, np.ones(25) / 25, mode="same"))
    F_cable = F_m - c_m * sgn
    # x_d = x_m + stretch; the cable pulls the drum through F_cable = k_c (x_m - x_d)
    x_l = tr.x_m - F_cable / k_c
    F_l = F_cable - c_d * sgn
    return x_l, F_l, sgn


def asymptotes(x_l, F_l, sgn):
    """Lines f + k x through the outer half of the increasing and decreasing branches (eq. 3.20-3.21)."""
    out = []
    for s in (1.0, -1.0):
        sel = sgn == s
        if sel.sum() < 10:
            raise StageError("linkage stage: the slow loop has no increasing/decreasing branch")
        x, F = x_l[sel], F_l[sel]
        lim = 0.5 * np.max(np.abs(x_l))
        far = (x > lim) if s > 0 else (x < -lim)
        far2 = (x < -lim) if s > 0 else (x > lim)
        # the increasing branch converges to its asymptote for large positive deflections, and vice versa;
        # use both ends of each branch only where it has travelled far from the last reversal
        use = far if far.sum() > 10 else np.ones_like(far)
        k, f = np.polyfit(x[use], F[use], 1)
        out.append((float(k), float(f), int(far2.sum())))
    (kp, fp, _), (kn, fn, _) = out
    return kp, fp, kn, fn


def identify_linkage(bench: Bench, builder: ModelBuilder, sweep_amplitudes_A=(0.3, 1.0, 2.0)) -> StageResult:
    """Identify the hysteresis parameters and ``mechanics.b_l_Ns_m``.

    Parameters
    ----------
    bench : Bench
        The device under test (configured by this stage).
    builder : ModelBuilder
        The built-up model; the identified values are added to ``builder.values``.
    sweep_amplitudes_A : sequence of float
        Swept-sine amplitudes for b_l (A).

    Returns
    -------
    StageResult

    Raises
    ------
    StageError
        If the loop is implausible (non-positive slopes, offsets of the wrong sign) or a fit misses
        (NRMSE > 0.3): e.g. the handle is not locked.
    """
    t0 = time.perf_counter()
    bench.configure(CONFIG)
    info = bench.info
    fs, kf = info.servo_rate_hz, info.force_per_amp_N_A
    a_max = 0.75 * info.current_peak_A
    u = loop_current(fs, (a_max, a_max / 3, a_max / 10))
    exp = Experiment("slow force loops", u)
    tr = bench.run(exp)
    v = builder.values
    x_l, F_l, sgn = linkage_loop(tr, kf, v["mechanics.k_c_N_m"], v["mechanics.c_m_N"], v["mechanics.c_d_N"])
    kp, fp, kn, fn = asymptotes(x_l, F_l, sgn)
    if not (kp > 0 and kn > 0 and fp > fn):
        raise StageError(f"linkage stage: implausible loop (slopes {kp:.4g}, {kn:.4g} N/m, offsets {fp:.4g}, "
                         f"{fn:.4g} N); is the handle locked?")
    k_mean = 0.5 * (kp + kn)
    if k_mean < 10.0:
        raise StageError(f"linkage stage: implausible stiffness {k_mean:.3g} N/m; is the handle locked?")
    fixed = {"mechanics.hysteresis": True}
    span = max(fp - fn, 1e-3)
    init = {"mechanics.k_lp_N_m": kp, "mechanics.k_ln_N_m": kn, "mechanics.f_lp_N": max(fp, 1e-4),
            "mechanics.f_ln_N": min(fn, -1e-4)}
    # gamma: best of a log grid with the asymptotes from the loop, then all five together
    best, best_err = None, np.inf
    for g in np.geomspace(k_mean / span * 0.3, k_mean / span * 30, 9):
        sim = builder.simulate(CONFIG, [exp], {**init, "mechanics.gamma_l_rad_m": float(g)}, quantized=False)[0]
        e = float(np.linalg.norm(sim.x_m - tr.x_m))
        if e < best_err:
            best, best_err = float(g), e
    free = {"mechanics.k_lp_N_m": (kp, kp / 2, kp * 2), "mechanics.k_ln_N_m": (kn, kn / 2, kn * 2),
            "mechanics.f_lp_N": (init["mechanics.f_lp_N"], 1e-6, 2 * span),
            "mechanics.f_ln_N": (init["mechanics.f_ln_N"], -2 * span, -1e-6),
            "mechanics.gamma_l_rad_m": (best, best / 10, best * 10)}
    vals, err, sims = fit_on_model(builder, CONFIG, [exp], [tr], free, fixed=fixed, max_nfev=80,
                                   log_params=("mechanics.k_lp_N_m", "mechanics.k_ln_N_m",
                                               "mechanics.gamma_l_rad_m"))
    if err > 0.3 or not vals["mechanics.f_lp_N"] > vals["mechanics.f_ln_N"]:
        raise StageError(f"linkage stage: hysteresis model fits the loops poorly (NRMSE {err:.2f})")
    builder.values.update(vals)
    # b_l from swept sines at several amplitudes (the resonance moves with amplitude: hysteresis)
    sweeps = [Experiment(f"sweep {a:g} A", chirp(fs, a, 20.0, 500.0, 0.5)) for a in sweep_amplitudes_A]
    straces = [bench.run(e) for e in sweeps]
    k_m = 0.5 * (vals["mechanics.k_lp_N_m"] + vals["mechanics.k_ln_N_m"])
    m_tot = v["mechanics.m_m_kg"] + v["mechanics.m_d_kg"]
    b_hi = 2 * np.sqrt(k_m * m_tot)  # critical damping: far above any plausible linkage damping
    vb, err_b, ssims = fit_on_model(builder, CONFIG, sweeps, straces,
                                    {"mechanics.b_l_Ns_m": (0.02 * b_hi, 0.0, b_hi)}, max_nfev=30)
    builder.values.update(vb)
    fig = {"x_l": x_l, "F_l": F_l, "sim_x": sims[0].x_m, "x_m": tr.x_m, "F_m": tr.i_A * kf,
           "asymptotes_init": (kp, fp, kn, fn), "sweeps": [(e.ff_A, t.x_m, s.x_m) for e, t, s in
                                                          zip(sweeps, straces, ssims)], "fs_hz": fs,
           "sweep_amplitudes_A": list(sweep_amplitudes_A)}
    res = {k: err for k in vals}
    res["mechanics.b_l_Ns_m"] = err_b
    return StageResult("linkage", CONFIG, {**vals, **vb}, res, figure_data=fig,
                       notes=[f"loop asymptotes (first estimate) +: {fp:.3f} N + {kp:.0f} N/m x, -: {fn:.3f} N + "
                              f"{kn:.0f} N/m x; fitted gamma {vals['mechanics.gamma_l_rad_m']:.0f} rad/m, "
                              f"loop NRMSE {err:.4f}; b_l {vb['mechanics.b_l_Ns_m']:.4f} N s/m from "
                              f"{len(sweeps)} sweeps (NRMSE {err_b:.4f})"], elapsed_s=time.perf_counter() - t0)
