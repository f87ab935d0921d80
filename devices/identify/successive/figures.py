"""One figure per successive-isolation stage (thesis Figures 3.16-3.22 style)."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np


def _plt():
    matplotlib.use("Agg")

    return plt


def stage_figures(result, out_dir) -> list[str]:
    """Write ``stage_<n>_<name>.png`` for every stage with figure data; returns the paths."""
    plt = _plt()
    out = Path(out_dir)
    paths = []
    for k, st in enumerate(result.stages):
        d = st.figure_data
        if not d:
            continue
        fn = _DRAW.get(st.stage)
        if fn is None:
            continue
        fig = fn(plt, d, st)
        fig.suptitle(f"stage {k + 1}: {st.stage} ({st.config}) - " + "; ".join(st.notes)[:150], fontsize=8)
        fig.tight_layout()
        p = out / f"stage_{k + 1}_{st.stage}.png"
        fig.savefig(p, dpi=80)
        plt.close(fig)
        paths.append(str(p))
    return paths


def _timing(plt, d, st):
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.hist(d["dt_us"], bins=50)
    ax.set_xlabel("servo period (us)")
    ax.set_ylabel("cycles")
    return fig


def _amplifier(plt, d, st):
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.5))
    a1.plot(d["levels_A"], d["measured_A"], "o", label="DC levels")
    a1.plot(d["sat_cmd_A"], d["sat_meas_A"], "s", label="beyond the limit")
    a1.set_xlabel("commanded (A)")
    a1.set_ylabel("measured (A)")
    a1.legend(fontsize=7)
    n = min(2000, d["cmd_A"].size)
    t = np.arange(n) / d["fs_hz"] * 1e3
    a2.plot(t, d["cmd_A"][:n], label="command")
    a2.plot(t, d["iamp_A"][:n], "--", label="amplifier output")
    a2.set_xlabel("time (ms)")
    a2.legend(fontsize=7)
    return fig


def _friction_and_steps(plt, d, st):
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.5))
    for v, x, F in zip(d["speed"], d["x"], d["F"]):
        a1.plot(x * 1e3, F * 1e3, lw=0.5, label=f"{v:g} m/s")
    a1.set_xlabel("position (mm)")
    a1.set_ylabel("force to move (mN)")
    a1.set_title("slow closed-loop motion (Fig. 3.16)", fontsize=8)
    a1.legend(fontsize=7)
    ref, xm, xs = d["steps"][0]
    t = np.arange(ref.size) / d["fs_hz"]
    a2.plot(t, ref * 1e3, "k:", label="reference")
    a2.plot(t, xm * 1e3, label="measured")
    a2.plot(t, xs * 1e3, "--", label="model")
    a2.set_xlabel("time (s)")
    a2.set_ylabel("position (mm)")
    a2.set_title("steps under a virtual spring", fontsize=8)
    a2.legend(fontsize=7)
    return fig


def _sweep_etfe(ax, u, xm, xs, fs, lo, hi):
    n = u.size
    U = np.fft.rfft(u)
    f = np.fft.rfftfreq(n, 1 / fs)
    sel = (f >= lo) & (f <= hi)
    for y, style, lab in ((xm, "-", "measured"), (xs, "--", "model")):
        H = np.fft.rfft(y - y.mean())[sel] / U[sel]
        ax.semilogx(f[sel], 20 * np.log10(np.abs(H) + 1e-30), style, label=lab)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("|x/i| (dB m/A)")
    ax.legend(fontsize=7)


def _cables(plt, d, st):
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.5))
    a1.plot(d["qs_x"] * 1e6, d["qs_F"], lw=0.7)
    a1.set_xlabel("motor position (um)")
    a1.set_ylabel("force (N)")
    a1.set_title(f"slow force cycle: slope {d['k_qs']:.0f} N/m", fontsize=8)
    u, xm, xs = d["sweep"]
    _sweep_etfe(a2, u, xm, xs, d["fs_hz"], 20, 1000)
    a2.set_title("resonance of motor on cables (Fig. 3.17)", fontsize=8)
    return fig


def _linkage(plt, d, st):
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.8))
    a1.plot(d["x_m"] * 1e3, d["F_m"], lw=0.8, label="measured")
    a1.plot(d["sim_x"] * 1e3, d["F_m"], "--", lw=0.8, label="model")
    a1.set_xlabel("motor position (mm)")
    a1.set_ylabel("motor force (N)")
    a1.set_title("hysteresis of cables and linkage in series (Fig. 3.20)", fontsize=8)
    a1.legend(fontsize=7)
    for (u, xm, xs), amp in zip(d["sweeps"], d["sweep_amplitudes_A"]):
        n = u.size
        U = np.fft.rfft(u)
        f = np.fft.rfftfreq(n, 1 / d["fs_hz"])
        sel = (f >= 20) & (f <= 500)
        for y, style in ((xm, "-"), (xs, "--")):
            H = np.fft.rfft(y - y.mean())[sel] / U[sel]
            a2.semilogx(f[sel], 20 * np.log10(np.abs(H) + 1e-30), style, lw=0.8,
                        label=f"{amp:g} A {'measured' if style == '-' else 'model'}")
    a2.set_xlabel("frequency (Hz)")
    a2.set_ylabel("|x/i| (dB m/A)")
    a2.set_title("amplitude-dependent resonance (Fig. 3.21)", fontsize=8)
    a2.legend(fontsize=6)
    return fig


def _handle(plt, d, st):
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for (u, am, asim), amp in zip(d["sweeps"], d["amplitudes_A"]):
        n = u.size
        U = np.fft.rfft(u)
        f = np.fft.rfftfreq(n, 1 / d["fs_hz"])
        sel = (f >= 20) & (f <= 500)
        for y, style in ((am, "-"), (asim, "--")):
            H = np.fft.rfft(y - y.mean())[sel] / U[sel]
            ax.semilogx(f[sel], 20 * np.log10(np.abs(H) + 1e-30), style, lw=0.8,
                        label=f"{amp:g} A {'measured' if style == '-' else 'model'}")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("|a/i| (dB m/s^2/A)")
    ax.legend(fontsize=7)
    return fig


def _user(plt, d, st):
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.5))
    g = np.asarray(d["grips_N"])
    a1.plot(g, d["k_u"], "o", label="k_u (N/m)")
    a1.plot(g, d["s_k"] * g, "-")
    a1.plot(g, d["b_u"], "s", label="b_u (N s/m)")
    a1.plot(g, d["s_b"] * g, "-")
    a1.set_xlabel("grip (N)")
    a1.set_title("user impedance vs grip", fontsize=8)
    a1.legend(fontsize=7)
    for gg, xm, xs, _, _ in d["sweeps"]:
        t = np.arange(xm.size) / d["fs_hz"]
        a2.plot(t, xm * 1e3, lw=0.8, label=f"{gg:g} N measured")
        a2.plot(t, xs * 1e3, "--", lw=0.8)
    a2.set_xlabel("time (s)")
    a2.set_ylabel("position (mm)")
    a2.set_title("held current steps (Fig. 3.22)", fontsize=8)
    a2.legend(fontsize=6)
    return fig


_DRAW = {"timing": _timing, "amplifier": _amplifier, "motor": _friction_and_steps, "drum": _friction_and_steps,
         "cables": _cables, "linkage": _linkage, "handle": _handle, "user": _user}
