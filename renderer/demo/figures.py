"""Figures of the virtual-wall demo (matplotlib, Agg backend, PNG).

* :func:`contact_figure`: handle acceleration at contact for the firm wall,
  pulse, decaying sinusoid, HFAM and the real sample at one velocity
  (thesis Figures 4.11 / 4.20);
* :func:`hfam_grid_figure`: HFAM at three velocities x three grips against
  the real recordings, with the current transients (Figure 4.13);
* :func:`library_figure`: the library's target accelerations and currents (Figure 4.8);
* :func:`bode_figure`: the identified current -> handle acceleration models
  per grip over their ETFE curves (Figures 3.8/3.12).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


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
    fig, axes = plt.subplots(n, 1, figsize=(7.5, 1.55 * n + 0.9), sharex=True, sharey=True)
    axes = np.atleast_1d(axes)
    lim = 1.1 * max(np.nanmax(np.abs(w)) for _, w in panels + [("ref", reference)])
    for ax, (title, w) in zip(axes, panels):
        is_ref = w is reference
        if not is_ref:
            ax.plot(t, reference, "--", color="0.55", lw=0.9, label="real wood on foam")
        ax.plot(t, w, color="k" if is_ref else "C0", lw=1.0, label=title)
        ax.text(0.99, 0.9, title, transform=ax.transAxes, ha="right", va="top", fontsize=9)
        ax.axvline(0.0, color="0.8", lw=0.6)
        ax.set_ylim(-lim, lim)
        ax.set_ylabel("m/s$^2$", fontsize=8)
        ax.tick_params(labelsize=8)
    axes[-1].set_xlabel("time after impact (ms)")
    axes[0].legend(loc="lower right", fontsize=7, frameon=False)
    fig.suptitle(f"Handle acceleration at contact, {velocity_m_s:g} m/s, grip {grip_N:g} N "
                 "(sim device; dashed: real sample)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


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
    fig, axes = plt.subplots(nv, ng + 1, figsize=(2.6 * (ng + 1), 1.9 * nv + 0.8), sharex=True, squeeze=False)
    n = len(next(iter(references.values())))
    t = _t_ms(n, fs_hz, pre_s)
    colors = plt.cm.viridis(np.linspace(0.0, 0.8, ng))
    for i, v in enumerate(velocities):
        lim = 1.15 * max(np.max(np.abs(references[v])),
                         max(np.max(np.abs(cells[(v, g)])) for g in grips))
        for j, g in enumerate(grips):
            ax = axes[i, j]
            if (v, g) in fixed:
                ax.plot(t, fixed[(v, g)], color="C3", lw=0.7, alpha=0.7,
                        label="medium-grip transient (no compensation)")
            ax.plot(t, cells[(v, g)], color=colors[j], lw=1.0, label="HFAM, grip-interpolated")
            ax.plot(t, references[v], "k--", lw=0.8, label="real recording")
            ax.set_ylim(-lim, lim)
            ax.tick_params(labelsize=7)
            if i == 0:
                ax.set_title(f"grip {g:g} N", fontsize=9)
            if j == 0:
                ax.set_ylabel(f"{v:g} m/s\naccel (m/s$^2$)", fontsize=8)
        ax = axes[i, ng]
        for j, g in enumerate(grips):
            ax.plot(t, currents[(v, g)], color=colors[j], lw=0.9, label=f"{g:g} N")
        ax.tick_params(labelsize=7)
        if i == 0:
            ax.set_title("current (A)", fontsize=9)
            ax.legend(fontsize=6, frameon=False)
    axes[0, 0].legend(fontsize=6, loc="lower right", frameon=False)
    for ax in axes[-1]:
        ax.set_xlabel("time (ms)", fontsize=8)
        ax.set_xlim(t[0], min(t[-1], 60.0))
    fig.suptitle("HFAM over the firm wall vs the real sample, per velocity and grip (cf. thesis Fig. 4.13)",
                 fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def library_figure(library, grip_N: float, path: Path) -> Path:
    """Figure 4.8: target accelerations (top) and current transients at ``grip_N`` (bottom) per velocity."""
    plt = _plt()
    grips = np.asarray(library.grips_N)
    j = int(np.argmin(np.abs(grips - grip_N)))
    t = (np.arange(library.n_samples) + 1) / library.fs_hz * 1e3
    fig, (ax_a, ax_i) = plt.subplots(2, 1, figsize=(7.0, 6.0), sharex=True)
    colors = plt.cm.viridis(np.linspace(0.0, 0.9, len(library.velocities_m_s)))
    for i, v in enumerate(library.velocities_m_s):
        if library.desired_accel_m_s2 is not None:
            ax_a.plot(t, library.desired_accel_m_s2[i], color=colors[i], lw=0.8, label=f"{v:.3f} m/s")
        ax_i.plot(t, library.currents_A[i, j], color=colors[i], lw=0.8)
    ax_a.set_ylabel("recorded acceleration (m/s$^2$)")
    ax_a.legend(fontsize=7, ncol=2, frameon=False)
    ax_i.set_ylabel(f"current at grip {grips[j]:g} N (A)")
    ax_i.set_xlabel("time after impact (ms)")
    for ax in (ax_a, ax_i):
        ax.grid(alpha=0.3)
    fig.suptitle("HFAM library for wood on foam (cf. thesis Fig. 4.8)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def bode_figure(etfe_npz: Path, model_set, path: Path) -> Path:
    """ETFE magnitude/phase per grip (solid) with the fitted zpk models (dashed)."""
    plt = _plt()
    data = np.load(etfe_npz)
    f, H, grips = data["f_hz"], data["H"], data["grip_N"]
    models = model_set.models["accel_m_s2"]
    fig, (ax_m, ax_p) = plt.subplots(2, 1, figsize=(7.0, 6.0), sharex=True)
    colors = plt.cm.viridis(np.linspace(0.0, 0.85, len(grips)))
    for k, (g, m) in enumerate(zip(grips, models)):
        ax_m.semilogx(f, 20 * np.log10(np.abs(H[k])), color=colors[k], lw=1.0, label=f"grip {g:g} N")
        ax_p.semilogx(f, np.degrees(np.unwrap(np.angle(H[k]))), color=colors[k], lw=1.0)
        fm = f if m.band_hz is None else f[(f >= m.band_hz[0]) & (f <= m.band_hz[1])]
        h = m.frequency_response(fm)
        ph = np.unwrap(np.angle(h))
        ph0 = np.unwrap(np.angle(H[k]))[np.searchsorted(f, fm[0])] if fm.size else 0.0
        if fm.size:
            ph -= 2 * np.pi * np.round((ph[0] - ph0) / (2 * np.pi))
        ax_m.semilogx(fm, 20 * np.log10(np.abs(h)), "--", color=colors[k], lw=1.3)
        ax_p.semilogx(fm, np.degrees(ph), "--", color=colors[k], lw=1.3)
    ax_m.set_ylabel("|A_h / I_m| (dB re 1 m/s$^2$/A)")
    ax_p.set_ylabel("phase (deg)")
    ax_p.set_xlabel("frequency (Hz)")
    ax_m.legend(fontsize=7, frameon=False)
    for ax in (ax_m, ax_p):
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle("Identified sim device: ETFE (solid) and fitted models (dashed) per grip", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def _save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    tmp.replace(path)
    return path
