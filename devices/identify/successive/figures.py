"""One figure per successive-isolation stage (thesis Figures 3.16-3.22 style)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
from matplotlib.ticker import FixedLocator, NullFormatter, ScalarFormatter

import figstyle


def _size(height_in: float, width: str = "page") -> tuple[float, float]:
    """A stage figure's size (in): the project's page (7.2 in) or column width, ``height_in`` high."""

    return figstyle.figsize(width, height_in=height_in)


def _freq_axis(ax, lo_hz: float, hi_hz: float) -> None:
    """A log frequency axis from ``lo_hz`` to ``hi_hz`` labelled at 1-2-5 steps only (matplotlib labels the
    minor ticks of a span under two decades, and they ran into each other)."""
    ticks = [m * 10.0 ** e for e in range(0, 5) for m in (1, 2, 5) if lo_hz <= m * 10.0 ** e <= hi_hz]
    ax.set_xlim(lo_hz, hi_hz)
    ax.xaxis.set_major_locator(FixedLocator(ticks))
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.xaxis.set_minor_formatter(NullFormatter())


def _legend(ax) -> None:
    """The panel's legend beside it, outside the data (docs/figures.md); constrained layout makes the room."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=6, borderaxespad=0.0)


def stage_title(k: int, st, width_chars: int = 110, max_chars: int = 330) -> str:
    """Title of stage ``k`` (0-based): stage, configuration and notes, wrapped to lines of ``width_chars`` (a
    one-line title of 150 characters ran off the figure)."""
    text = f"stage {k + 1}: {st.stage} ({st.config}) - " + "; ".join(st.notes)
    if len(text) > max_chars:
        text = text[:max_chars - 1].rstrip() + "\u2026"
    return textwrap.fill(text, width_chars)


def stage_figures(result, out_dir) -> list[str]:
    """Write ``stage_<n>_<name>.png`` (and ``.svg``) for every stage with figure data, in the project's figure
    style (figstyle, docs/figures.md); returns the PNG paths."""
    out = Path(out_dir)
    paths = []
    with figstyle.style() as plt:
        for k, st in enumerate(result.stages):
            d = st.figure_data
            fn = _DRAW.get(st.stage) if d else None
            if fn is None:
                continue
            fig = fn(plt, d, st)
            fig.suptitle(stage_title(k, st), fontsize=7)
            p = out / f"stage_{k + 1}_{st.stage}.png"
            figstyle.save(fig, p, force=True)   # identify checked its --out (and --force) before measuring
            paths.append(str(p))
    return paths


def _timing(plt, d, st):
    """Servo periods as deviations from their median: a simulated clock's periods differ by floating-point
    noise only (a histogram of it read "1e-11+1e2"); the bins are never narrower than 0.1 us."""
    dt = np.asarray(d["dt_us"], dtype=float)
    med = float(np.median(dt))
    dev = dt - med
    half = max(float(np.max(np.abs(dev))), 1.0)
    fig, ax = plt.subplots(figsize=_size(2.6, "column"), layout="constrained")
    ax.hist(dev, bins=np.linspace(-half, half, min(51, int(2 * half / 0.1) + 1)))
    ax.set_xlabel(f"servo period \u2212 median {med:.3f} us (us)")
    ax.set_ylabel("periods (count)")
    if np.ptp(dt) < 1e-3:
        ax.text(0.02, 0.95, f"all {dt.size} periods equal (spread {np.ptp(dt) * 1e3:.1g} ns)",
                transform=ax.transAxes, va="top", fontsize=7)
    return fig


def _amplifier(plt, d, st):
    fig, (a1, a2) = plt.subplots(1, 2, figsize=_size(3.5), layout="constrained")
    a1.plot(d["levels_A"], d["measured_A"], "o", label="DC levels")
    a1.plot(d["sat_cmd_A"], d["sat_meas_A"], "s", label="beyond the limit")
    a1.set_xlabel("commanded (A)")
    a1.set_ylabel("measured (A)")
    _legend(a1)
    n = min(2000, d["cmd_A"].size)
    t = np.arange(n) / d["fs_hz"] * 1e3
    a2.plot(t, d["cmd_A"][:n], label="command")
    a2.plot(t, d["iamp_A"][:n], "--", label="amplifier output")
    a2.set_xlabel("time (ms)")
    _legend(a2)
    return fig


def _friction_and_steps(plt, d, st):
    fig, (a1, a2) = plt.subplots(1, 2, figsize=_size(3.5), layout="constrained")
    for v, x, F in zip(d["speed"], d["x"], d["F"]):
        a1.plot(x * 1e3, F * 1e3, lw=0.5, label=f"{v:g} m/s")
    a1.set_xlabel("position (mm)")
    a1.set_ylabel("force to move (mN)")
    a1.set_title("slow closed-loop motion (Fig. 3.16)", fontsize=8)
    _legend(a1)
    ref, xm, xs = d["steps"][0]
    t = np.arange(ref.size) / d["fs_hz"]
    a2.plot(t, ref * 1e3, "k:", label="reference")
    a2.plot(t, xm * 1e3, label="measured")
    a2.plot(t, xs * 1e3, "--", label="model")
    a2.set_xlabel("time (s)")
    a2.set_ylabel("position (mm)")
    a2.set_title("steps under a virtual spring", fontsize=8)
    _legend(a2)
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
    _legend(ax)


def _cables(plt, d, st):
    fig, (a1, a2) = plt.subplots(1, 2, figsize=_size(3.5), layout="constrained")
    a1.plot(d["qs_x"] * 1e6, d["qs_F"], lw=0.7)
    a1.set_xlabel("motor position (um)")
    a1.set_ylabel("force (N)")
    a1.set_title(f"slow force cycle: slope {d['k_qs']:.0f} N/m", fontsize=8)
    u, xm, xs = d["sweep"]
    _sweep_etfe(a2, u, xm, xs, d["fs_hz"], 20, 1000)
    _freq_axis(a2, 20, 1000)
    a2.set_title("resonance of motor on cables (Fig. 3.17)", fontsize=8)
    return fig


def _linkage(plt, d, st):
    fig, (a1, a2) = plt.subplots(1, 2, figsize=_size(3.8), layout="constrained")
    a1.plot(d["x_m"] * 1e3, d["F_m"], lw=0.8, label="measured")
    a1.plot(d["sim_x"] * 1e3, d["F_m"], "--", lw=0.8, label="model")
    a1.set_xlabel("motor position (mm)")
    a1.set_ylabel("motor force (N)")
    a1.set_title("hysteresis of cables and linkage in series (Fig. 3.20)", fontsize=8)
    _legend(a1)
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
    _freq_axis(a2, 20, 500)
    a2.set_title("amplitude-dependent resonance (Fig. 3.21)", fontsize=8)
    _legend(a2)
    return fig


def _handle(plt, d, st):
    fig, ax = plt.subplots(figsize=_size(3.5, "column"), layout="constrained")
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
    _freq_axis(ax, 20, 500)
    _legend(ax)
    return fig


def _user(plt, d, st):
    fig, (a1, a2) = plt.subplots(1, 2, figsize=_size(3.5), layout="constrained")
    g = np.asarray(d["grips_N"])
    a1.plot(g, d["k_u"], "o", label="k_u (N/m)")
    a1.plot(g, d["s_k"] * g, "-")
    a1.plot(g, d["b_u"], "s", label="b_u (N s/m)")
    a1.plot(g, d["s_b"] * g, "-")
    a1.set_xlabel("grip (N)")
    a1.set_title("user impedance vs grip", fontsize=8)
    _legend(a1)
    for gg, xm, xs, _, _ in d["sweeps"]:
        t = np.arange(xm.size) / d["fs_hz"]
        a2.plot(t, xm * 1e3, lw=0.8, label=f"{gg:g} N measured")
        a2.plot(t, xs * 1e3, "--", lw=0.8)
    a2.set_xlabel("time (s)")
    a2.set_ylabel("position (mm)")
    a2.set_title("held current steps (Fig. 3.22)", fontsize=8)
    _legend(a2)
    return fig


_DRAW = {"timing": _timing, "amplifier": _amplifier, "motor": _friction_and_steps, "drum": _friction_and_steps,
         "cables": _cables, "linkage": _linkage, "handle": _handle, "user": _user}
