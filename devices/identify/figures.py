"""Bode plots of ETFE curves with fitted models over them (like thesis Figures 3.8, 3.9, 3.12).

Phase is unwrapped over the trusted bins and shifted by whole turns so the lowest trusted bin lies
in (-180, 180] deg; bins with low coherence (or above the quantization-resolvable band) are drawn
faint in magnitude and left out of the phase; each fitted model is drawn over its curve with its
resonance (magnitude peak) and the -3 dB point above the peak marked. Saved with the project
style (figstyle) as PNG, SVG and a CSV of the plotted values.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib import colormaps
from matplotlib.lines import Line2D
from scipy.signal import find_peaks

import figstyle

if TYPE_CHECKING:  # annotations only: devices.model loads scipy.signal (~1 s)
    from ..model import ZpkModel
    from .etfe import Etfe

YLABEL = {"accel_m_s2": "|A_h / I_m| (dB re 1 m/s²/A)", "position_m": "|X_m / I_m| (dB re 1 m/A)"}
# bins whose magnitude-squared coherence is below this are drawn faint and get no phase
COHERENCE_MIN = 0.6


def wrap_phase_deg(H: np.ndarray, trusted: np.ndarray | None = None) -> np.ndarray:
    """Phase of ``H`` in degrees, unwrapped along frequency and shifted by whole turns into (-180, 180]
    at the first trusted bin; untrusted bins are NaN.

    Parameters
    ----------
    H : ndarray of complex, shape (m,)
        Frequency response in increasing frequency order.
    trusted : ndarray of bool, shape (m,), optional
        Bins to use (default all).

    Returns
    -------
    ndarray, shape (m,)
        Phase in deg.
    """
    H = np.asarray(H)
    ok = np.ones(H.shape, dtype=bool) if trusted is None else np.asarray(trusted, dtype=bool)
    out = np.full(H.shape, np.nan)
    if ok.any():
        ph = np.degrees(np.unwrap(np.angle(H[ok])))
        ph -= 360.0 * np.ceil((ph[0] - 180.0) / 360.0)      # first trusted bin into (-180, 180]
        out[ok] = ph
    return out


def resonance_and_3db(f_hz: np.ndarray, H: np.ndarray) -> tuple[float, float, float]:
    """Resonance (the most prominent interior peak of the magnitude) and the first frequency above it 3 dB
    below the peak.

    The resonance is a local maximum standing at least 1 dB above the magnitude on both sides
    (``scipy.signal.find_peaks`` with a prominence of 1 dB), not the largest value in the band: a position
    response (x/i, falling as 1/f^2) is largest at the band's low edge, and its 80-115 Hz resonance was
    marked at 10 Hz. No interior peak: NaN for all three (no marker).

    Parameters
    ----------
    f_hz : ndarray, shape (m,)
        Increasing frequencies, Hz.
    H : ndarray of complex, shape (m,)

    Returns
    -------
    f_peak_hz, peak_db, f_3db_hz : float
        ``f_3db_hz`` is NaN when the magnitude does not fall 3 dB below the peak within ``f_hz``
        (linear interpolation in dB between bins).
    """
    with np.errstate(divide="ignore"):
        mag = 20 * np.log10(np.abs(H))
    finite = np.isfinite(mag)
    if not finite.any():
        return float("nan"), float("nan"), float("nan")
    peaks, props = find_peaks(np.where(finite, mag, np.min(mag[finite]) - 100.0), prominence=1.0)
    if not peaks.size:
        return float("nan"), float("nan"), float("nan")
    i = int(peaks[np.argmax(props["prominences"])])
    peak = float(mag[i])
    below = np.flatnonzero(mag[i:] <= peak - 3.0)
    if not below.size:
        return float(f_hz[i]), peak, float("nan")
    j = i + int(below[0])
    f0, f1, m0, m1 = f_hz[j - 1], f_hz[j], mag[j - 1], mag[j]
    f3 = f0 + (peak - 3.0 - m0) * (f1 - f0) / (m1 - m0) if m1 != m0 else f1
    return float(f_hz[i]), peak, float(f3)


def bode_plot(curves: list[Etfe], models: list[ZpkModel | None], path, title: str = "", force: bool = False) -> Path:
    """Write ``path`` (PNG) plus SVG and ``.plot.csv``: ETFE curves (solid) and their fitted models (dashed).

    Parameters
    ----------
    curves : list of Etfe
    models : list of ZpkModel or None
        One per curve (None: no model for that curve), or one shared model
        drawn in black when ``len(models) == 1 < len(curves)``.
    path : str or Path
        PNG to write; ``.svg`` and ``.plot.csv`` are written beside it.
    title : str
    force : bool
        Replace existing files; otherwise ``ValueError`` (naming them) before drawing if any exists.

    Returns
    -------
    Path
        The PNG.
    """
    figstyle.check_outputs(path, force=force)
    with np.errstate(divide="ignore", invalid="ignore"):
        lines = bode_lines(curves, models)
    with figstyle.style() as plt:
        fig, (ax_m, ax_p) = plt.subplots(2, 1, figsize=figstyle.figsize("page", height_in=5.2), sharex=True)
        _draw(ax_m, ax_p, lines, _grip_colors(len(curves)))
        ax_m.set_ylabel(YLABEL.get(curves[0].output, "magnitude (dB)") if curves else "magnitude (dB)")
        ax_p.set_ylabel("phase (deg)")
        ax_p.set_xlabel("frequency (Hz)")
        for ax in (ax_m, ax_p):
            ax.grid(True, which="both", alpha=0.3)

        handles, labels = ax_m.get_legend_handles_labels()
        handles += [Line2D([], [], color="0.3", lw=1.2, label="ETFE (coherence ≥ %.1f)" % COHERENCE_MIN),
                    Line2D([], [], color="0.3", lw=0.6, alpha=0.35, label="low coherence / unresolved"),
                    Line2D([], [], color="0.3", lw=1.4, ls="--", label="fitted model"),
                    Line2D([], [], color="0.3", ls="none", marker="^", label="resonance (model peak)"),
                    Line2D([], [], color="0.3", ls="none", marker="v", mfc="white", label="−3 dB below the peak")]
        ax_m.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0)
        if title:
            ax_m.set_title(title, loc="left")
        paths = figstyle.save(fig, path, bode_table(lines), force=force)
    return paths["png"]


def preload_figures() -> None:
    """Import matplotlib (with the project style's backend) now, e.g. while other processes work, or
    before forking processes that draw figures."""
    with figstyle.style():
        pass


def _grip_colors(n: int) -> list:
    return [colormaps[figstyle.palette()["sequential"]](x) for x in np.linspace(0.0, 0.85, max(n, 1))]


def bode_lines(curves: list[Etfe], models: list[ZpkModel | None]) -> dict:
    """What :func:`bode_plot` draws, computed (no matplotlib).

    Returns
    -------
    dict
        ``etfe``: one dict per curve (``label``, ``f_hz``, ``magnitude_db``, ``phase_deg`` (NaN where not
        trusted), ``coherence``, ``trusted``); ``models``: one dict per drawn model (``index``: its curve's
        index or None for a shared model, ``label``, ``f_hz``, ``magnitude_db``, ``phase_deg`` on the curve's
        360-degree branch, ``resonance``: (f_hz, dB) or None, ``minus_3db``: (f_hz, dB) or None).
    """
    shared = len(models) == 1 and len(curves) > 1
    etfes, drawn = [], []
    for c in curves:
        coh = np.asarray(c.coherence) if c.coherence is not None else np.ones(c.f_hz.shape)
        trusted = (c.f_hz <= c.resolvable_hi_hz) & (coh >= COHERENCE_MIN)
        etfes.append({"label": c.label, "f_hz": c.f_hz, "magnitude_db": 20 * np.log10(np.abs(c.H)),
                      "phase_deg": wrap_phase_deg(c.H, trusted), "coherence": coh, "trusted": trusted})
    pairs = [(models[0], None, None)] if shared else [(m, i, c) for i, (m, c) in enumerate(zip(models, curves))]
    for m, i, c in pairs:
        if m is None:
            continue
        f = c.f_hz if c is not None else curves[0].f_hz
        if m.band_hz is not None:  # draw models only where they were fitted
            f = f[(f >= m.band_hz[0]) & (f <= m.band_hz[1])]
        if not f.size:
            continue
        h = m.frequency_response(f)
        mag = 20 * np.log10(np.abs(h))
        ph = np.degrees(np.unwrap(np.angle(h)))
        ref = None
        if c is not None:   # the model's phase on the same 360-degree branch as its curve where it starts
            data_ph = wrap_phase_deg(c.H, (c.f_hz <= c.resolvable_hi_hz)
                                     & (np.asarray(c.coherence) >= COHERENCE_MIN))
            k = int(np.searchsorted(c.f_hz, f[0]))
            near = np.flatnonzero(np.isfinite(data_ph))
            if near.size:
                ref = data_ph[near[np.argmin(np.abs(near - k))]]
        ph -= 360.0 * (np.round((ph[0] - ref) / 360.0) if ref is not None else np.ceil((ph[0] - 180.0) / 360.0))
        f_pk, pk, f3 = resonance_and_3db(f, h)
        drawn.append({"index": i, "label": c.label if c is not None else "shared model", "f_hz": f,
                      "magnitude_db": mag, "phase_deg": ph,
                      "resonance": (f_pk, pk) if np.isfinite(f_pk) else None,
                      "minus_3db": (f3, pk - 3.0) if np.isfinite(f3) else None})
    return {"etfe": etfes, "models": drawn}


def _draw(ax_m, ax_p, lines: dict, colors: list) -> None:
    """Plot :func:`bode_lines` (curve ``i`` in ``colors[i]``, a shared model in black)."""
    for e, color in zip(lines["etfe"], colors):
        mag, trusted = e["magnitude_db"], e["trusted"]
        ax_m.semilogx(e["f_hz"], np.where(trusted, np.nan, mag), color=color, lw=0.6, alpha=0.35)
        ax_m.semilogx(e["f_hz"], np.where(trusted, mag, np.nan), color=color, lw=1.2, label=e["label"] or None)
        ax_p.semilogx(e["f_hz"], e["phase_deg"], color=color, lw=1.2)
    for d in lines["models"]:
        color = "black" if d["index"] is None else colors[d["index"]]
        ax_m.semilogx(d["f_hz"], d["magnitude_db"], "--", color=color, lw=1.4)
        ax_p.semilogx(d["f_hz"], d["phase_deg"], "--", color=color, lw=1.4)
        if d["resonance"] is not None:
            ax_m.plot(*d["resonance"], "^", color=color, ms=6, mec="black", mew=0.5)
        if d["minus_3db"] is not None:
            ax_m.plot(*d["minus_3db"], "v", color=color, mfc="white", ms=6, mew=1.0)


def _g9(values) -> list:
    """``%.9g`` text of each value, empty for NaN (what ``DataFrame.to_csv(float_format="%.9g")`` writes)."""
    return ["" if v != v else "%.9g" % v for v in np.asarray(values, dtype=float).tolist()]


def bode_table(lines: dict) -> tuple[list, list]:
    """The figure's CSV as (header, rows of text): one row per plotted bin of every curve (``kind`` etfe)
    and model (``kind`` model), then the resonance and -3 dB marks; empty cells where a column does not
    apply. Columns curve, kind, f_hz, magnitude_db, phase_deg, coherence, trusted."""
    cols = []
    for e in lines["etfe"]:
        n = e["f_hz"].size
        cols.append(([e["label"] or ""] * n, ["etfe"] * n, _g9(e["f_hz"]), _g9(e["magnitude_db"]),
                     _g9(e["phase_deg"]), _g9(e["coherence"]), [str(bool(t)) for t in e["trusted"]]))
    for d in lines["models"]:
        n = d["f_hz"].size
        cols.append(([d["label"] or ""] * n, ["model"] * n, _g9(d["f_hz"]), _g9(d["magnitude_db"]),
                     _g9(d["phase_deg"]), [""] * n, [""] * n))
    for d in lines["models"]:
        for kind in ("resonance", "minus_3db"):
            if d[kind] is not None:
                cols.append(([d["label"] or ""], [kind], *([x] for x in _g9(d[kind])), [""], [""], [""]))
    header = ["curve", "kind", "f_hz", "magnitude_db", "phase_deg"]
    if lines["etfe"]:
        header += ["coherence", "trusted"]
    rows = [list(r[: len(header)]) for c in cols for r in zip(*c)]
    if not rows:  # nothing drawn: an empty table (a blank line)
        return [], []
    return header, rows
