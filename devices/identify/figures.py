"""Bode plots of ETFE curves with fitted models over them (like thesis Figures 3.8, 3.9, 3.12)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..model import ZpkModel
from .etfe import Etfe

YLABEL = {"accel_m_s2": "|A_h / I_m|  (dB re 1 m/s^2/A)", "position_m": "|X_m / I_m|  (dB re 1 m/A)"}


def bode_plot(curves: list[Etfe], models: list[ZpkModel | None], path, title: str = "") -> Path:
    """Write a PNG: ETFE curves (solid) and their fitted models (dashed, same colour).

    Parameters
    ----------
    curves : list of Etfe
    models : list of ZpkModel or None
        One per curve (None: no model for that curve), or one shared model
        drawn in black when ``len(models) == 1 < len(curves)``.
    path : str or Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_m, ax_p) = plt.subplots(2, 1, figsize=(7.5, 6.5), sharex=True)
    with np.errstate(divide="ignore"):  # a curve of zeros (output never moved) plots as -inf: nothing drawn
        _draw(ax_m, ax_p, curves, models, plt)
    ax_m.set_ylabel(YLABEL.get(curves[0].output, "dB") if curves else "dB")
    ax_p.set_ylabel("phase (deg)")
    ax_p.set_xlabel("frequency (Hz)")
    for ax in (ax_m, ax_p):
        ax.grid(True, which="both", alpha=0.3)
    if any(c.label for c in curves):
        ax_m.legend(fontsize=8, title="solid: ETFE, dashed: model", title_fontsize=8)
    ax_m.set_title(title)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _draw(ax_m, ax_p, curves, models, plt) -> None:
    colors = plt.cm.viridis(np.linspace(0.0, 0.85, max(len(curves), 1)))
    shared = len(models) == 1 and len(curves) > 1
    for c, color in zip(curves, colors):
        # above the quantization-resolvable band the estimate is noise: thin line, no phase
        ok = c.f_hz <= c.resolvable_hi_hz
        ax_m.semilogx(c.f_hz[ok], 20 * np.log10(np.abs(c.H[ok])), color=color, lw=1.2, label=c.label or None)
        ax_m.semilogx(c.f_hz[~ok], 20 * np.log10(np.abs(c.H[~ok])), color=color, lw=0.4, alpha=0.5)
        ax_p.semilogx(c.f_hz[ok], np.degrees(np.unwrap(np.angle(c.H[ok]))), color=color, lw=1.2)
    pairs = [(models[0], "black", None)] if shared else [(m, col, c) for m, col, c in zip(models, colors, curves)]
    for m, color, c in pairs:
        if m is None:
            continue
        f = c.f_hz if c is not None else curves[0].f_hz
        if m.band_hz is not None:  # draw models only where they were fitted
            f = f[(f >= m.band_hz[0]) & (f <= m.band_hz[1])]
        h = m.frequency_response(f)
        ax_m.semilogx(f, 20 * np.log10(np.abs(h)), "--", color=color, lw=1.5)
        ph = np.unwrap(np.angle(h))
        if c is not None and f.size:  # draw the model's phase on the same 360-degree branch as its curve
            i0 = int(np.searchsorted(c.f_hz, f[0]))
            ph_c = np.unwrap(np.angle(c.H[: i0 + 1]))[-1]
            ph -= 2 * np.pi * np.round((ph[0] - ph_c) / (2 * np.pi))
        ax_p.semilogx(f, np.degrees(ph), "--", color=color, lw=1.5)
