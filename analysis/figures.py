"""Figures 4.17-4.20 as PNG files (matplotlib, Agg backend)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

DPI = 110
# cells of Fig. 4.18 without a p-value: a colour outside the grey scale, so NaN never reads as p = 1
NO_P_STYLE = dict(facecolor="#f2d0d0", edgecolor="#b03030", hatch="///", linewidth=0.0)


def _labels(samples) -> list[str]:
    return [s.replace("_", " ") for s in samples]


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return path


def fig_ratings(summary: pd.DataFrame, path: Path) -> Path:
    """Figure 4.17: mean realism per sample (bars) with median markers and SE caps (per-subject means)."""
    x = np.arange(len(summary))
    fig, ax = plt.subplots(figsize=(9, 4.2))
    colors = ["#8c6d46" if k == "real" else "#5b84b1" for k in summary["kind"]]
    ax.bar(x, summary["mean_rating"], color=colors, edgecolor="black", linewidth=0.6, label="mean")
    ax.errorbar(x, summary["mean_rating"], yerr=summary["sem_rating"], fmt="none", ecolor="black", capsize=4,
                label="standard error")
    ax.plot(x, summary["median_rating"], "o", mfc="white", mec="black", label="median")
    ax.set_xticks(x, _labels(summary["sample"]), rotation=40, ha="right")
    ax.set_ylim(1, 7)
    ax.set_ylabel("realism rating (1-7)")
    n = int(summary["n_subjects"].max()) if len(summary) else 0
    ax.set_title(f"Realism ratings per sample ({n} subjects; brown = real, blue = virtual)")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def _p_matrix(pairwise: pd.DataFrame, samples) -> tuple[np.ndarray, np.ndarray]:
    k = len(samples)
    index = {s: i for i, s in enumerate(samples)}
    p = np.full((k, k), np.nan)
    holm = np.full((k, k), np.nan)
    ia = pairwise["sample_a"].map(index).to_numpy()
    ib = pairwise["sample_b"].map(index).to_numpy()
    p[ia, ib] = p[ib, ia] = pairwise["p"].to_numpy()
    holm[ia, ib] = holm[ib, ia] = pairwise["p_holm"].to_numpy()
    return p, holm


def fig_pvalues(pairwise: pd.DataFrame, samples, path: Path) -> Path:
    """Figure 4.18: p-values of the paired t-tests as shaded matrices, one panel per group.

    Light = high p (indistinguishable), dark = low p; '*' marks Holm-adjusted p < 0.05.
    Cells without a p-value (a sample against itself, or a pair excluded from the
    tests) are hatched in red, so they cannot be mistaken for p = 1 (white).
    """
    group_names = list(dict.fromkeys(pairwise["group"]))
    fig, axes = plt.subplots(1, len(group_names), figsize=(6.6 * len(group_names), 5.8), squeeze=False)
    fig.subplots_adjust(wspace=0.55)
    labels = _labels(samples)
    im = None
    for ax, g in zip(axes[0], group_names):
        sub = pairwise[pairwise["group"] == g]
        p, holm = _p_matrix(sub, samples)
        im = ax.imshow(p, cmap="gray", vmin=0.0, vmax=1.0)
        for i, j in zip(*np.nonzero(np.isnan(p))):
            ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, **NO_P_STYLE))
        for i, j in zip(*np.nonzero(holm < 0.05)):
            ax.text(j, i, "*", ha="center", va="center", color="white", fontsize=9)
        n = int(sub["n"].max()) if len(sub) else 0
        ax.set_title(f"{g} subjects (n = {n})")
        ax.set_xticks(range(len(samples)), labels, rotation=60, ha="right", fontsize=7)
        ax.set_yticks(range(len(samples)), labels, fontsize=7)
    if im is not None:
        fig.colorbar(im, ax=axes[0].tolist(), shrink=0.8, label="p (paired t-test); * Holm p < 0.05")
        fig.legend(handles=[Rectangle((0, 0), 1, 1, label="n/a: no test (same sample, or pair excluded)",
                                      **NO_P_STYLE)], loc="lower left", fontsize=8, frameon=False)
    return _save(fig, path)


def fig_penetration(summary: pd.DataFrame, path: Path) -> Path:
    """Figure 4.19: mean penetration depth vs mean rating, error bars one SD (taps; attempts' ratings)."""
    fig, ax = plt.subplots(figsize=(7, 5))
    pen_mm = summary["penetration_mean_m"].to_numpy() * 1e3
    ax.errorbar(summary["mean_rating"], pen_mm, yerr=summary["penetration_sd_m"].to_numpy() * 1e3,
                xerr=summary["sd_rating_attempts"], fmt="o", capsize=3, color="#5b84b1", ecolor="#999999")
    for name, x, y in zip(summary["sample"], summary["mean_rating"], pen_mm):
        ax.annotate(name.replace("_", " "), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7)
    ax.set_xlabel("mean realism rating (1-7)")
    ax.set_ylabel("mean penetration depth (mm)")
    ax.set_title("Penetration depth vs realism (error bars: 1 SD)")
    ax.grid(alpha=0.3)
    return _save(fig, path)


def fig_accelerations(taps: dict, samples, target_v_m_s: float, path: Path) -> Path:
    """Figure 4.20: typical handle acceleration per sample for taps near a common incoming velocity."""
    present = [s for s in samples if s in taps]
    n = len(present)
    cols = 3 if n > 4 else max(n, 1)
    rows = int(np.ceil(n / cols)) if n else 1
    fig, axes = plt.subplots(rows, cols, figsize=(4.0 * cols, 2.2 * rows), squeeze=False, sharex=True)
    lim = max((float(np.max(np.abs(taps[s].accel_m_s2))) for s in present), default=1.0) * 1.05
    for ax, s in zip(axes.flat, present):
        tap = taps[s]
        ax.plot(tap.t_s * 1e3, tap.accel_m_s2, lw=0.8, color="black")
        ax.set_title(f"{s.replace('_', ' ')} (v = {tap.v_in_m_s:.3f} m/s)", fontsize=8)
        ax.set_ylim(-lim, lim)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("time from impact (ms)")
    for ax in axes[:, 0]:
        ax.set_ylabel("accel (m/s²)")
    fig.suptitle(f"Handle accelerations at an incoming velocity near {target_v_m_s:.3f} m/s", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)
