"""Figures of the virtual-wall demo in the project style (figstyle): PNG + SVG + CSV of the plotted data.

* :func:`contact_figure`: handle acceleration at contact for the firm wall,
  pulse, decaying sinusoid, HFAM and the real sample at one velocity
  (thesis Figures 4.11 / 4.20);
* :func:`hfam_grid_figure`: HFAM at three velocities x three grips against
  the real recordings, with the current transients (Figure 4.13);
* :func:`library_figure`: the library's target accelerations and currents (Figure 4.8), drawn by
  ``stimuli show``'s plot (one implementation of Figure 4.8);
* :func:`bode_figure`: the identified current -> handle acceleration models
  per grip over their ETFE curves (Figures 3.8/3.12), drawn by the identification's Bode plot.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
from matplotlib import colormaps

import figstyle
from devices.identify.etfe import Etfe
from devices.identify.figures import bode_plot
from stimuli.cli_show import plot_library

# demo panel titles -> the rendering's entry in the project palette (one colour per rendering everywhere)
RENDERING_KEYS = {"firm wall 680 N/m": "firm", "pulse over firm": "pulse_firm",
                  "decaying sinusoid over firm": "sinusoid_firm", "HFAM over firm": "hfam_firm",
                  "real wood on foam": "wood_on_foam"}


def _plt():
    """pyplot inside the project style (entered for the rest of the process's figure code)."""
    ctx = figstyle.style()
    plt = ctx.__enter__()
    _STYLE_STACK.append(ctx)
    return plt


_STYLE_STACK: list = []


def _rendering_color(title: str) -> str:
    return figstyle.color(RENDERING_KEYS.get(title, title))


def _t_ms(n: int, fs_hz: float, pre_s: float) -> np.ndarray:
    return (np.arange(n) - int(round(pre_s * fs_hz))) / fs_hz * 1e3


def contact_figure(panels: list[tuple[str, np.ndarray]], reference: np.ndarray, fs_hz: float, pre_s: float,
                   velocity_m_s: float, grip_N: float, path: Path) -> Path:
    """Stacked panels of handle acceleration around impact, the real sample's dashed in each.

    Parameters
    ----------
    panels : list of (title, accel window)
        Windows of equal length (m/s^2), impact at ``pre_s``.
    reference : ndarray
        The real sample's window, drawn dashed in every virtual panel.
    """
    plt = _plt()
    n = len(panels)
    t = _t_ms(len(reference), fs_hz, pre_s)
    fig, axes = plt.subplots(n, 1, figsize=figstyle.figsize("page", height_in=1.15 * n + 0.8), sharex=True,
                             sharey=True, layout="constrained")
    axes = np.atleast_1d(axes)
    lim = 1.1 * max(np.nanmax(np.abs(w)) for _, w in panels + [("ref", reference)])
    data = {"t_ms": t}
    for ax, (title, w) in zip(axes, panels):
        is_ref = w is reference
        if not is_ref:
            ax.plot(t, reference, "--", color="0.6", lw=0.9, label="real wood on foam (reference)")
        ax.plot(t, w, color=_rendering_color(title), lw=1.0)
        ax.set_title(title, loc="left", fontsize=7.5, pad=2)
        ax.axvline(0.0, color="0.3", lw=0.7, ls=(0, (2, 2)), label="contact (t = 0)")
        ax.set_ylim(-lim, lim)
        ax.set_ylabel("accel. (m/s²)")
        data[f"{title} accel_m_s2"] = w
    data["reference accel_m_s2"] = reference
    axes[-1].set_xlabel("time after impact (ms)")
    handles = [h for h in axes[0].lines if not h.get_label().startswith("_")] if n > 1 else []
    handles = handles or [ax.lines[-1] for ax in axes[:1]]
    fig.legend(handles=handles, loc="outside lower right", ncol=2)
    fig.suptitle(f"Handle acceleration at contact, {velocity_m_s:g} m/s, grip {grip_N:g} N (sim device; "
                 "same scale in every panel)", fontsize=8.5)
    return _save(fig, path, data)


def hfam_grid_figure(cells: dict, references: dict, currents: dict, fixed: dict, velocities, grips, fs_hz: float,
                     pre_s: float, path: Path) -> Path:
    """Figure 4.13: rows = velocities, columns = grips (accelerations) plus one column of currents.

    Parameters
    ----------
    cells : dict (velocity, grip) -> accel window of HFAM (grip-compensated)
    references : dict velocity -> real sample window
    currents : dict (velocity, grip) -> commanded current window (A)
    fixed : dict (velocity, grip) -> accel window with the medium-grip transient at every grip (may be empty)
    """
    plt = _plt()
    nv, ng = len(velocities), len(grips)
    fig, axes = plt.subplots(nv, ng + 1, figsize=figstyle.figsize("page", height_in=1.55 * nv + 0.9), sharex=True,
                             squeeze=False, layout="constrained")
    n = len(next(iter(references.values())))
    t = _t_ms(n, fs_hz, pre_s)

    colors = colormaps[figstyle.palette()["sequential"]](np.linspace(0.0, 0.8, ng))
    hfam_color, fixed_color = figstyle.color("hfam_firm"), figstyle.color("hfam_fixed_grip_firm")
    data = {"t_ms": t}
    for i, v in enumerate(velocities):
        lim = 1.15 * max(np.max(np.abs(references[v])),
                         max(np.max(np.abs(cells[(v, g)])) for g in grips))
        for j, g in enumerate(grips):
            ax = axes[i, j]
            if (v, g) in fixed:
                ax.plot(t, fixed[(v, g)], color=fixed_color, lw=0.7, ls=":",
                        label="medium-grip transient (no compensation)")
                data[f"fixed {v:g} m/s {g:g} N accel_m_s2"] = fixed[(v, g)]
            ax.plot(t, cells[(v, g)], color=hfam_color, lw=1.0, label="HFAM, grip-interpolated")
            ax.plot(t, references[v], "--", color="black", lw=0.8, label="real recording")
            data[f"hfam {v:g} m/s {g:g} N accel_m_s2"] = cells[(v, g)]
            ax.set_ylim(-lim, lim)
            if i == 0:
                ax.set_title(f"grip {g:g} N", fontsize=8)
            if j == 0:
                ax.set_ylabel(f"{v:g} m/s\naccel. (m/s²)")
        data[f"real {v:g} m/s accel_m_s2"] = references[v]
        ax = axes[i, ng]
        for j, g in enumerate(grips):
            ax.plot(t, currents[(v, g)], color=colors[j], lw=0.9, label=f"current at {g:g} N")
            data[f"current {v:g} m/s {g:g} N A"] = currents[(v, g)]
        ax.set_ylabel("current (A)")
        if i == 0:
            ax.set_title("current transients", fontsize=8)
    handles = {h.get_label(): h for ax in (axes[0, 0], axes[0, ng]) for h in ax.lines}
    fig.legend(handles=list(handles.values()), loc="outside lower center", ncol=3)
    for ax in axes[-1]:
        ax.set_xlabel("time (ms)")
        ax.set_xlim(t[0], min(t[-1], 60.0))
    fig.suptitle("HFAM over the firm wall vs the real sample, per velocity and grip (cf. thesis Fig. 4.13)",
                 fontsize=8.5)
    return _save(fig, path, data)


def library_figure(library, grip_N: float, path: Path) -> Path:
    """Figure 4.8: the HFAM library's target accelerations and current transients, drawn by
    ``stimuli show`` (:func:`stimuli.cli_show.plot_library`; one implementation of Figure 4.8)."""
    return plot_library(library, Path(path), force=True)   # the demo checked its --out


def bode_figure(etfe_npz: Path, model_set, path: Path) -> Path:
    """ETFE per grip with the fitted zpk models, drawn by the identification's Bode plot
    (:func:`devices.identify.figures.bode_plot`: wrapped phase, low coherence faint, resonance and -3 dB)."""
    data = np.load(etfe_npz)
    f, H, grips = data["f_hz"], data["H"], data["grip_N"]
    coh = data["coherence"] if "coherence" in data.files else np.ones(H.shape)
    curves = [Etfe(f, H[k], H[k], coh[k], "accel_m_s2", 1, float(g), f"grip {g:g} N") for k, g in enumerate(grips)]
    return bode_plot(curves, list(model_set.models["accel_m_s2"]), path,
                     title="Identified sim device: ETFE (solid) and fitted models (dashed) per grip",
                     force=True)   # the demo checked its --out


def penetration_figure(penetration_m: dict, labels: dict, path: Path,
                       taps_text: str = "velocities x grips", marks_mm: dict | None = None) -> Path:
    """Mean peak penetration per rendering with its spread (thesis Figure 4.19 style).

    Parameters
    ----------
    penetration_m : dict
        Rendering name -> sequence of per-tap maximum penetrations (m).
    labels : dict
        Rendering name -> axis label.
    path : Path
        PNG to write.
    taps_text : str
        What the spread is over (axis label).
    marks_mm : dict or None
        Label -> depth (mm) drawn as a dashed vertical line (the thesis's 0.25 mm and 2 mm of section 4.5.5).

    Returns
    -------
    Path
    """
    plt = _plt()
    names = [n for n in labels if n in penetration_m and len(penetration_m[n])]
    mean = [1e3 * float(np.mean(penetration_m[n])) for n in names]
    sd = [1e3 * float(np.std(penetration_m[n])) for n in names]
    fig, ax = plt.subplots(figsize=figstyle.figsize("page", height_in=3.8))
    y = np.arange(len(names))
    colors = [figstyle.color(n) for n in names]
    # light bars, black whiskers on top: the real sample's black bar hid its own (black) whisker
    ax.barh(y, mean, color=colors, alpha=0.5)
    ax.errorbar(mean, y, xerr=sd, fmt="none", ecolor="black", elinewidth=1.0, capsize=3, zorder=3)
    for k, (label, x) in enumerate((marks_mm or {}).items()):
        ax.axvline(x, color="0.3", linestyle=("--", ":")[k % 2], linewidth=1.0, label=label)
    if marks_mm:
        ax.legend(loc="upper right", fontsize="small")
    ax.set_yticks(y, [labels[n] for n in names])
    ax.invert_yaxis()
    ax.set_xlabel(f"mean peak penetration (mm), bars: +/- 1 s.d. over {taps_text}")
    ax.set_title("Penetration per rendering and sample (cf. thesis Figure 4.19)")
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    return _save(fig, path, {"rendering": names, "mean_penetration_mm": mean, "sd_penetration_mm": sd})


def _save(fig, path: Path, data=None) -> Path:
    """Save as PNG (returned) plus SVG and the plotted data as CSV (figstyle.save), then leave the style."""
    paths = figstyle.save(fig, path, data, force=True)   # the demo checked its --out
    while _STYLE_STACK:
        with contextlib.suppress(Exception):
            _STYLE_STACK.pop().__exit__(None, None, None)
    return paths["png"]
