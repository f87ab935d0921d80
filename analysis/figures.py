"""Figures 4.17-4.20 of the realism study, in the project style (figstyle), each as PNG + SVG + CSV.

Every figure has a ``build_*`` function returning ``(figure, data)`` (the data table is what is
plotted, and what the CSV beside the figure holds) and a ``fig_*`` function that builds and saves
it. Figures are drawn from the aggregated tables (``sample_summary``, ``pairwise_ttests``) and a
single tap per sample, so their cost does not grow with the number of subjects.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.collections import PathCollection
from matplotlib.colors import TwoSlopeNorm
from matplotlib.patches import Rectangle
from matplotlib.textpath import TextPath
from matplotlib.transforms import Affine2D, IdentityTransform

import figstyle

# cells of Fig. 4.18 without a p-value: white with a grey hatch, outside both colour scales
NO_P_STYLE = dict(facecolor="white", edgecolor="#888888", hatch="////", linewidth=0.0)
# log10 of the smallest Holm p the colour scale resolves (smaller ones get its darkest colour)
LOG_P_FLOOR = -4.0
DZ_LIMIT = 2.0   # |d_z| at the ends of the effect-size colour scale


def _label(sample: str, labels: dict | None = None) -> str:
    """The sample's label: the catalog's (``labels``, from session.json) if it has one, else the palette's."""
    if labels and sample in labels:
        return labels[sample]
    return figstyle.sample_style(sample)["label"]


def stars(p: np.ndarray, alpha: float = 0.05) -> np.ndarray:
    """Significance stars of (Holm-adjusted) p-values: ``***`` < 0.001, ``**`` < 0.01, ``*`` < alpha.

    Parameters
    ----------
    p : array of float
        p-values (NaN gives ``""``).
    alpha : float
        Significance level of the single star.

    Returns
    -------
    ndarray of str, same shape as ``p``
    """
    p = np.asarray(p, dtype=float)
    out = np.full(p.shape, "", dtype=object)
    with np.errstate(invalid="ignore"):
        out[p < alpha] = "*"
        out[p < min(alpha, 0.01)] = "**"
        out[p < min(alpha, 0.001)] = "***"
    return out


def _fix_layout(fig) -> None:
    """Compute ``fig``'s constrained layout now and keep it (the layout engine is set to none).

    An active layout engine redoes the whole layout, measuring every tick label again, in every draw
    of :func:`figstyle.save`; once is enough for a figure that is not resized, and a figure without an
    active engine is measured once and drawn once per format (no draw only to lay it out).
    Called inside :func:`figstyle.style`, so the layout sees the fonts the figure is saved with.
    """
    fig.get_layout_engine().execute(fig)
    fig.set_layout_engine("none")


# ------------------------------------------------------------------------------------ Figure 4.17
def build_ratings(summary: pd.DataFrame, labels: dict | None = None):
    """Figure 4.17: mean realism per sample with 95 % CIs, sorted by mean (highest on top).

    Parameters
    ----------
    summary : DataFrame
        ``sample_summary`` (needs ``sample, mean_rating, median_rating, ci95_low_rating,
        ci95_high_rating, n_subjects``).

    Returns
    -------
    fig : Figure
    data : DataFrame
        One row per sample in plotted order: ``y`` (row position, 0 at the top), mean, CI, median, and
        ``ci_cut_at_scale`` (the CI runs past 1 or 7: drawn to the scale's end with an arrowhead, and said in
        the legend).
    """
    s = summary.sort_values("mean_rating", ascending=False, kind="stable").reset_index(drop=True)
    k = len(s)
    y = np.arange(k, dtype=float)
    data = pd.DataFrame({"sample": s["sample"], "y": y, "mean_rating": s["mean_rating"],
                         "ci95_low_rating": s["ci95_low_rating"], "ci95_high_rating": s["ci95_high_rating"],
                         "median_rating": s["median_rating"], "n_subjects": s["n_subjects"]})
    data["ci_cut_at_scale"] = (data["ci95_high_rating"] > 7.0) | (data["ci95_low_rating"] < 1.0)
    with figstyle.style() as plt:
        fig, ax = plt.subplots(figsize=figstyle.figsize("column", height_in=0.22 * k + 1.1))
        for i, r in data.iterrows():
            st = figstyle.sample_style(r["sample"])
            ax.errorbar(r["mean_rating"], r["y"], xerr=[[r["mean_rating"] - r["ci95_low_rating"]],
                                                        [r["ci95_high_rating"] - r["mean_rating"]]],
                        fmt=st["marker"], color=st["color"], ms=5, lw=1.2, capsize=2.5,
                        label="mean, 95 % CI" if i == 0 else None)
        ax.plot(data["median_rating"], y, "|", color="0.35", ms=7, mew=1.2, label="median")
        # a t-interval of a few subjects can run past the 1-7 scale: the axis stops at the scale, so say where
        # an interval is cut (an arrowhead at the edge, and in the legend) instead of cutting it silently
        for edge, marker, side in ((7.0, ">", data["ci95_high_rating"] > 7.0), (1.0, "<", data["ci95_low_rating"] < 1.0)):
            if side.any():
                ax.plot(np.full(int(side.sum()), edge), y[side.to_numpy()], marker, color="0.2", ms=4, clip_on=False,
                        label="CI cut at the scale's end" if "CI cut at the scale's end" not in
                        ax.get_legend_handles_labels()[1] else None)
        ax.set_yticks(y, [_label(v, labels) for v in data["sample"]])
        ax.invert_yaxis()
        ax.set_xlim(1, 7)
        ax.set_xlabel("realism rating (1–7)")
        ax.grid(axis="y", visible=False)
        n = int(s["n_subjects"].max()) if k else 0
        handles, labels = ax.get_legend_handles_labels()
        ax.legend(handles, labels, loc="lower left", bbox_to_anchor=(0.0, 1.01), ncol=2, borderaxespad=0,
                  handletextpad=0.3, title=f"{n} subjects", alignment="left")
    return fig, data


def fig_ratings(summary: pd.DataFrame, path: Path, labels: dict | None = None) -> dict:
    """Write Figure 4.17 (:func:`build_ratings`) as PNG, SVG and CSV; returns the paths."""
    fig, data = build_ratings(summary, labels)
    return figstyle.save(fig, path, data, force=True)   # into the report folder the command owns


# ------------------------------------------------------------------------------------ Figure 4.18
def _matrices(pairwise: pd.DataFrame, samples) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric Holm-p and antisymmetric d_z (row minus column) matrices, NaN where untested."""
    k = len(samples)
    index = {s: i for i, s in enumerate(samples)}
    holm = np.full((k, k), np.nan)
    dz = np.full((k, k), np.nan)
    ia = pairwise["sample_a"].map(index).to_numpy()
    ib = pairwise["sample_b"].map(index).to_numpy()
    holm[ia, ib] = holm[ib, ia] = pairwise["p_holm"].to_numpy(dtype=float)
    d = pairwise["cohen_dz"].to_numpy(dtype=float) if "cohen_dz" in pairwise else np.full(len(ia), np.nan)
    dz[ia, ib], dz[ib, ia] = d, -d
    return holm, dz


def _bf10_matrix(pairwise: pd.DataFrame, samples) -> np.ndarray:
    """Symmetric matrix (k, k) of the pairs' JZS BF10, NaN where untested or without the column."""
    k = len(samples)
    bf = np.full((k, k), np.nan)
    if "bf10" in pairwise:
        index = {s: i for i, s in enumerate(samples)}
        ia = pairwise["sample_a"].map(index).to_numpy()
        ib = pairwise["sample_b"].map(index).to_numpy()
        bf[ia, ib] = bf[ib, ia] = pairwise["bf10"].to_numpy(dtype=float)
    return bf


def p_norm(alpha: float = 0.05):
    """Colour normalisation of Figure 4.18: log10 of the Holm p, diverging at log10(alpha)."""

    return TwoSlopeNorm(vcenter=float(np.log10(alpha)), vmin=LOG_P_FLOOR, vmax=0.0)


def _star_marks(ax, st: np.ndarray, white: np.ndarray, group: str, fontsize: float = 5.5) -> None:
    """Draw the significance stars ``st`` (k x k strings) centred in their cells of ``ax``: one
    collection per star count (gid ``stars_<group>_<count>``), white where ``white`` else black.

    The stars are the glyphs of the figure font as paths (``TextPath``), a few hundred marks in three
    collections: as Text artists each mark was laid out and measured in every draw (four per saved
    figure), the figure's largest cost.
    """

    for n in (1, 2, 3):
        i, j = np.nonzero(st == "*" * n)
        if not i.size:
            continue
        glyphs = TextPath((0, 0), "*" * n, size=fontsize)        # vertices in points
        box = glyphs.get_extents()
        glyphs = glyphs.transformed(Affine2D().translate(-(box.x0 + box.x1) / 2, -(box.y0 + box.y1) / 2))
        # as a scatter plot's markers: placed in data coordinates, drawn in points (sizes=[1]: one point
        # per path unit, so the glyphs keep their size in points)
        ax.add_collection(PathCollection([glyphs], sizes=[1.0], offsets=np.column_stack([j, i]),
                                         offset_transform=ax.transData, transform=IdentityTransform(),
                                         linewidths=0.0,
                                         facecolors=np.where(white[i, j], "white", "black"),
                                         gid=f"stars_{group}_{n}", in_layout=False), autolim=False)


def build_pvalues(pairwise: pd.DataFrame, samples, alpha: float = 0.05, labels: dict | None = None):
    """Figure 4.18: Holm-adjusted p of the paired t-tests (colour and stars) and Cohen's d_z.

    One row of panels per group: left the Holm-adjusted p-values on a log scale that diverges at
    ``alpha`` (purple = significant, orange = not) with stars from the same values, right the
    effect size d_z of row minus column (blue = row rated lower, red = higher). Cells without a
    test are hatched. The stars are drawn as glyph paths (:func:`_star_marks`), and the
    constrained layout is computed once here and kept (:func:`_fix_layout`).

    Returns
    -------
    fig : Figure
    data : DataFrame
        One row per plotted cell: ``group, row, col, sample_row, sample_col, p_holm, log10_p_holm,
        stars, cohen_dz`` (row minus column) and ``bf10`` (JZS Bayes factor of the pair's t-test).
    """

    groups = list(dict.fromkeys(pairwise["group"]))
    k = len(samples)
    labels = [_label(s, labels) for s in samples]
    rows = []
    norm = p_norm(alpha)
    with figstyle.style() as plt:
        fig, axes = plt.subplots(len(groups), 2, figsize=figstyle.figsize("page", height_in=3.5 * len(groups)),
                                 squeeze=False, layout="constrained")
        im_p = im_d = None
        for r, g in enumerate(groups):
            sub = pairwise[pairwise["group"] == g]
            holm, dz = _matrices(sub, samples)
            bf = _bf10_matrix(sub, samples)
            with np.errstate(divide="ignore"):
                logp = np.log10(holm)
            st = stars(holm, alpha)
            ax_p, ax_d = axes[r]
            im_p = ax_p.imshow(np.ma.masked_invalid(logp), cmap="PuOr_r", norm=norm)
            im_d = ax_d.imshow(np.ma.masked_invalid(dz), cmap=figstyle.palette()["effect"], vmin=-DZ_LIMIT,
                               vmax=DZ_LIMIT)
            for ax in (ax_p, ax_d):
                for i, j in zip(*np.nonzero(np.isnan(holm))):
                    ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, **NO_P_STYLE))
                ax.set_xticks(range(k), labels, rotation=60, ha="right", rotation_mode="anchor", fontsize=6)
                ax.set_yticks(range(k), labels if ax is ax_p else [], fontsize=6)
                ax.grid(False)
            # the stars sit inside their cells, so inside the axes: out of the layout and tight-box passes
            with np.errstate(invalid="ignore"):
                _star_marks(ax_p, st, norm(logp) < 0.25, g)
            n = int(sub["n"].max()) if len(sub) else 0
            # y=1.0: where matplotlib's automatic placement puts them here (ticks below, fixed labels: no
            # offset text), without its measuring every tick label again in each layout pass
            ax_p.set_title(f"{g} subjects (n = {n}): Holm-adjusted p", loc="left", y=1.0)
            ax_d.set_title(f"{g} subjects: effect size d_z", loc="left", y=1.0)
            for i in range(k):
                for j in range(k):
                    rows.append({"group": g, "row": i, "col": j, "sample_row": samples[i], "sample_col": samples[j],
                                 "p_holm": holm[i, j], "log10_p_holm": logp[i, j], "stars": st[i, j],
                                 "cohen_dz": dz[i, j], "bf10": bf[i, j]})
        if im_p is not None:
            ticks = [t for t in (-4, -3, -2, np.log10(alpha), -1, 0) if LOG_P_FLOOR <= t <= 0]
            cb = fig.colorbar(im_p, ax=axes[:, 0].tolist(), location="bottom", shrink=0.85, extend="min",
                              ticks=ticks)
            cb.ax.set_xticklabels([f"{10 ** t:g}" for t in ticks])
            cb.set_label(f"Holm-adjusted p (1, log scale); * < {alpha:g}, ** < 0.01, *** < 0.001")
            cb2 = fig.colorbar(im_d, ax=axes[:, 1].tolist(), location="bottom", shrink=0.85, extend="both")
            cb2.set_label("Cohen's d_z of row − column (1)")
            fig.legend(handles=[Rectangle((0, 0), 1, 1, label="no test (same sample, or pair excluded)",
                                          **NO_P_STYLE)], loc="outside upper right", fontsize=6.5)
        _fix_layout(fig)
    return fig, pd.DataFrame(rows)


def fig_pvalues(pairwise: pd.DataFrame, samples, path: Path, alpha: float = 0.05, labels: dict | None = None) -> dict:
    """Write Figure 4.18 (:func:`build_pvalues`) as PNG, SVG and CSV; returns the paths."""
    fig, data = build_pvalues(pairwise, samples, alpha, labels)
    return figstyle.save(fig, path, data, force=True)   # into the report folder the command owns


# ------------------------------------------------------------------------------------ Figure 4.19
def build_penetration(summary: pd.DataFrame, labels: dict | None = None):
    """Figure 4.19: mean penetration depth vs mean realism rating, error bars ±1 SD.

    Vertical bars: SD of the penetration depths of the individual taps; horizontal bars: SD of
    the ratings of the attempts.

    Returns
    -------
    fig : Figure
    data : DataFrame
        ``sample, mean_rating, sd_rating, penetration_mean_mm, penetration_sd_mm``.
    """
    data = pd.DataFrame({"sample": summary["sample"], "mean_rating": summary["mean_rating"],
                         "sd_rating": summary["sd_rating_attempts"],
                         "penetration_mean_mm": summary["penetration_mean_m"] * 1e3,
                         "penetration_sd_mm": summary["penetration_sd_m"] * 1e3})
    with figstyle.style() as plt:
        fig, ax = plt.subplots(figsize=figstyle.figsize("page", height_in=3.2))
        for r in data.itertuples():
            st = figstyle.sample_style(r.sample)
            ax.errorbar(r.mean_rating, r.penetration_mean_mm, xerr=r.sd_rating, yerr=r.penetration_sd_mm,
                        fmt=st["marker"], color=st["color"], ms=6, elinewidth=0.8, capsize=2,
                        label=_label(r.sample, labels))
        ax.set_xlabel("mean realism rating (1–7)")
        ax.set_ylabel("mean penetration depth (mm)")
        ax.set_ylim(bottom=0)
        ax.set_title("Penetration depth vs realism (error bars: ±1 SD)", loc="left")
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0)
    return fig, data


def fig_penetration(summary: pd.DataFrame, path: Path, labels: dict | None = None) -> dict:
    """Write Figure 4.19 (:func:`build_penetration`) as PNG, SVG and CSV; returns the paths."""
    fig, data = build_penetration(summary, labels)
    return figstyle.save(fig, path, data, force=True)   # into the report folder the command owns


# ------------------------------------------------------------------------------------ Figure 4.20
WINDOW_MS = (-10.0, 60.0)   # the same time window in every panel


def build_accelerations(taps: dict, samples, target_v_m_s: float, ncols: int = 3, labels: dict | None = None):
    """Figure 4.20: one small panel per sample, own y scale, same window, contact at t = 0 marked.

    Parameters
    ----------
    taps : dict
        Sample -> :class:`analysis.traces.Tap` (time from impact ``t_s`` in s, ``accel_m_s2``).
    samples : sequence of str
        Catalog order (panel order).
    target_v_m_s : float
        The common incoming velocity the taps were picked near (m/s).

    Returns
    -------
    fig : Figure
    data : DataFrame
        Long format: ``sample, panel, v_in_m_s, t_ms, accel_m_s2`` for the plotted window.
    """
    present = [s for s in samples if s in taps]
    n = len(present)
    cols = min(ncols, max(n, 1))
    rows_n = int(np.ceil(n / cols)) if n else 1
    parts = []
    with figstyle.style() as plt:
        fig, axes = plt.subplots(rows_n, cols, figsize=figstyle.figsize("page", height_in=1.35 * rows_n + 0.7),
                                 sharex=True, squeeze=False, layout="constrained")
        for p, (ax, s) in enumerate(zip(axes.flat, present)):
            tap = taps[s]
            t_ms = tap.t_s * 1e3
            sel = (t_ms >= WINDOW_MS[0]) & (t_ms <= WINDOW_MS[1])
            st = figstyle.sample_style(s)
            ax.plot(t_ms[sel], tap.accel_m_s2[sel], color=st["color"], lw=0.8)
            ax.axvline(0.0, color="0.3", lw=0.7, ls=(0, (2, 2)), label="contact (t = 0)")
            peak = float(np.max(np.abs(tap.accel_m_s2[sel]))) if sel.any() else 1.0
            lim = 1.1 * peak if peak > 0 else 1.0
            ax.set_ylim(-lim, lim)
            ax.set_xlim(*WINDOW_MS)
            # y=1.0 where the automatic placement puts it (ticks below; no offset text on the y axis for
            # limits between 1e-4 and 1e5), without its measuring all tick labels in each layout pass
            ax.set_title(f"{_label(s, labels)}  (v = {tap.v_in_m_s:.3f} m/s)", loc="left", fontsize=7,
                         y=1.0 if 1e-4 <= lim < 1e5 else None)
            parts.append(pd.DataFrame({"sample": s, "panel": p, "v_in_m_s": tap.v_in_m_s, "t_ms": t_ms[sel],
                                       "accel_m_s2": tap.accel_m_s2[sel]}))
        for ax in list(axes.flat)[n:]:
            ax.axis("off")
        for ax in axes[-1]:
            ax.set_xlabel("time from contact (ms)")
        for ax in axes[:, 0]:
            ax.set_ylabel("acceleration (m/s²)")
        fig.suptitle(f"Handle acceleration at an incoming velocity near {target_v_m_s:.3f} m/s "
                     "(each panel on its own scale)", fontsize=8.5)
        if n:
            fig.legend(handles=[axes.flat[0].lines[-1]], loc="outside lower right")
        _fix_layout(fig)
    data = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(
        columns=["sample", "panel", "v_in_m_s", "t_ms", "accel_m_s2"])
    return fig, data


def fig_accelerations(taps: dict, samples, target_v_m_s: float, path: Path, labels: dict | None = None) -> dict:
    """Write Figure 4.20 (:func:`build_accelerations`) as PNG, SVG and CSV; returns the paths."""
    fig, data = build_accelerations(taps, samples, target_v_m_s, labels=labels)
    return figstyle.save(fig, path, data, force=True)   # into the report folder the command owns


# ------------------------------------------------------------------ ordinal model, planning
def build_ordinal_probs(probabilities: pd.DataFrame):
    """Probability of each rating 1-7 per sample from the proportional-odds model, as stacked bars.

    One horizontal bar per sample (sorted by the model's expected rating, highest on top), split
    into the probabilities of the ratings 1..7 (the sequential, colour-blind-safe ``cividis`` map:
    the ratings are ordered); the observed share of each rating is in the CSV beside it.

    Parameters
    ----------
    probabilities : DataFrame
        :attr:`analysis.models.ModelResults.probabilities` (``sample, rating, p_model, p_observed, n_attempts``).

    Returns
    -------
    fig : Figure
    data : DataFrame
        ``sample, y, rating, p_model, p_observed, left, expected_rating`` (``left``: where the segment starts).
    """
    wide = probabilities.pivot(index="sample", columns="rating", values="p_model")
    ratings = [int(c) for c in wide.columns]
    expected = (wide * np.array(ratings)[None, :]).sum(axis=1)
    order = expected.sort_values(ascending=False, kind="stable").index.tolist()
    p_model = wide.loc[order].to_numpy(dtype=float)          # (sample in plotted order, rating)
    # the observed share of each (sample, rating): its first row, as a lookup instead of a filter per segment
    observed: dict = {}
    for key, p_obs in zip(zip(probabilities["sample"], probabilities["rating"]), probabilities["p_observed"]):
        observed.setdefault(key, p_obs)
    rows = []
    for y, sample in enumerate(order):
        left = 0.0
        for c, r in enumerate(ratings):
            p = float(p_model[y, c])
            p_obs = observed.get((sample, r))
            rows.append({"sample": sample, "y": y, "rating": r, "p_model": p,
                         "p_observed": float(p_obs) if p_obs is not None else np.nan,
                         "left": left, "expected_rating": float(expected[sample])})
            left += p
    with figstyle.style() as plt:
        cmap = plt.get_cmap("cividis")
        fig, ax = plt.subplots(figsize=figstyle.figsize("page", height_in=0.25 * len(order) + 1.4),
                               layout="constrained")
        # every segment in one call, sample by sample as they are drawn (one call per segment cost as much as
        # the figure's layout); the legend shows the first sample's segment of each rating
        colors = [cmap(c / max(len(ratings) - 1, 1)) for c in range(len(ratings))]
        bars = ax.barh([row["y"] for row in rows], [row["p_model"] for row in rows],
                       left=[row["left"] for row in rows], color=colors * len(order), edgecolor="white",
                       linewidth=0.4)
        handles = list(bars.patches[:len(ratings)]) if order else []
        ax.set_yticks(range(len(order)), [_label(s) for s in order])
        ax.invert_yaxis()
        ax.set_xlim(0, 1)
        ax.set_xlabel("probability of each rating (1), at the mean incoming velocity")
        ax.set_title("Ordinal (proportional-odds) model: P(rating) per sample", loc="left")
        ax.legend(handles, [str(r) for r in ratings[:len(handles)]], title="rating", loc="upper left",
                  bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
        ax.grid(False)
        _fix_layout(fig)
    return fig, pd.DataFrame(rows)


def fig_ordinal_probs(probabilities: pd.DataFrame, path: Path) -> dict:
    """Write the ordinal model's P(rating) figure (:func:`build_ordinal_probs`) as PNG, SVG and CSV."""
    fig, data = build_ordinal_probs(probabilities)
    return figstyle.save(fig, path, data, force=True)   # into the report folder the command owns


def build_power_curves(curves: pd.DataFrame, plan: pd.DataFrame):
    """Power against the number of subjects, difference tests left and equivalence (TOST) right.

    Parameters
    ----------
    curves : DataFrame
        :func:`analysis.power.power_curves` (``row, test, label, n, power``).
    plan : DataFrame
        ``plan.csv`` (``power_target``, ``n_required`` per row): the target line and each row's n.

    Returns
    -------
    fig : Figure
    data : DataFrame
        ``curves`` with ``n_required`` of each row.
    """
    data = curves.merge(plan["n_required"].rename_axis("row").reset_index(), on="row", how="left")
    target = float(plan["power_target"].iloc[0]) if len(plan) else 0.8
    with figstyle.style() as plt:
        cmap = plt.get_cmap("cividis")
        fig, axes = plt.subplots(1, 2, figsize=figstyle.figsize("page", height_in=3.0), sharey=True,
                                 layout="constrained")
        for ax, test, title in ((axes[0], "difference", "difference (two-sided paired t-test)"),
                                (axes[1], "equivalence", "equivalence (paired TOST)")):
            sub = data[data["test"] == test]
            rows = list(dict.fromkeys(sub["row"]))
            for c, row in enumerate(rows):
                line = sub[sub["row"] == row]
                ax.plot(line["n"], line["power"], color=cmap(c / max(len(rows) - 1, 1)), linewidth=0.9)
            ax.axhline(target, color="0.3", linestyle="--", linewidth=0.8)
            ax.set_xlabel("subjects (1)")
            # no legend inside the data: one comparison is named in the title, many are counted (their
            # labels are in the CSV)
            which = sub["label"].iloc[0] if len(rows) == 1 else f"{len(rows)} comparisons"
            ax.set_title(f"{title}\n{which}" if rows else title, loc="left", fontsize=8)
            ax.set_ylim(0, 1.02)
            if not rows:
                ax.text(0.5, 0.5, "no comparison to plan", transform=ax.transAxes, ha="center", va="center")
        axes[0].set_ylabel(f"power (1); dashed: target {target:g}")
        _fix_layout(fig)
    return fig, data


def fig_power_curves(curves: pd.DataFrame, plan: pd.DataFrame, path: Path, force: bool = True) -> dict:
    """Write the power-curve figure (:func:`build_power_curves`) as PNG, SVG and CSV; returns the paths."""
    fig, data = build_power_curves(curves, plan)
    return figstyle.save(fig, path, data, force=force)
