"""Figures of the method of adjustment and of magnitude estimation, in the project style (figstyle), each as PNG,
SVG and the plotted numbers (CSV). The numbers come from :mod:`analysis.adjustment` and :mod:`analysis.magnitude`.

* :func:`build_adjustment_subjects`: every subject's settings per condition, its PSE with its interval, the
  reference;
* :func:`build_adjustment_pooled`: PSE / reference per condition, subjects and their mean with its interval;
* :func:`build_magnitude_loglog`: normalised numbers against the stimulus on log-log axes, the geometric mean
  at each level and the fitted power law per condition;
* :func:`build_magnitude_exponents`: every subject's exponent with its interval, and the pooled mean.
"""

from __future__ import annotations

import numpy as np
from matplotlib.ticker import NullFormatter, ScalarFormatter

import figstyle


def _plain_log_axis(axis) -> None:
    """Plain numbers at the decades of a log axis and no minor labels (3 x 10^2 and 4 x 10^2 ran together)."""
    fmt = ScalarFormatter()
    fmt.set_scientific(False)
    axis.set_major_formatter(fmt)
    axis.set_minor_formatter(NullFormatter())


def _label(name: str) -> str:
    return figstyle.sample_style(name)["label"]


def build_adjustment_subjects(trials, subjects, value_label: str):
    """Settings per subject in one panel per condition; returns ``(fig, data)``."""
    conditions = sorted(subjects["condition"].unique(), key=lambda c: float(subjects.loc[
        subjects["condition"] == c, "reference"].iloc[0]))
    names = sorted(subjects["subject"].unique())
    data = {"subject": [], "condition": [], "final_value": [], "matched": []}
    with figstyle.style() as plt:
        fig, axes = plt.subplots(1, len(conditions), figsize=figstyle.figsize("page", aspect=0.36), sharey=True,
                                 squeeze=False)
        for ax, cond in zip(axes[0], conditions):
            ref = float(subjects.loc[subjects["condition"] == cond, "reference"].iloc[0])
            for i, name in enumerate(names):
                t = trials[(trials["subject"] == name) & (trials["condition"] == cond)]
                ax.plot(np.full(len(t), i) + np.linspace(-0.15, 0.15, max(len(t), 1))[:len(t)], t["final_value"],
                        "o", ms=2.5, color="0.55", mfc="none", mew=0.6)
                s = subjects[(subjects["subject"] == name) & (subjects["condition"] == cond)].iloc[0]
                ax.errorbar([i], [s["pse"]], yerr=[[s["pse"] - s["pse_low"]], [s["pse_high"] - s["pse"]]], fmt="D",
                            ms=3.5, color=figstyle.color("firm"), capsize=2, lw=0.8)
                for v, m in zip(t["final_value"], t["matched"]):
                    data["subject"].append(name)
                    data["condition"].append(cond)
                    data["final_value"].append(float(v))
                    data["matched"].append(int(m))
            ax.axhline(ref, color="0.2", ls="--", lw=0.8)
            ax.set_xticks(range(len(names)), names, rotation=90 if len(names) > 6 else 0)
            ax.set_title(f"reference {cond}", loc="left")
            ax.set_xlabel("subject")
            ax.set_yscale("log")
            _plain_log_axis(ax.yaxis)
        axes[0][0].set_ylabel(value_label)
        fig.suptitle("Method of adjustment: settings (circles), PSE (diamonds, 95 % CI), reference (dashed)",
                     x=0.01, y=1.0, ha="left", va="bottom", fontsize="medium")
        fig.subplots_adjust(bottom=0.3 if len(names) > 6 else 0.2, top=0.86)
    return fig, data


def build_adjustment_pooled(subjects, pooled):
    """PSE / reference per condition: each subject and the pooled mean with its interval; returns ``(fig, data)``."""
    data = {"condition": [], "subject": [], "pse_rel": []}
    conds = list(pooled.sort_values("reference")["condition"])
    with figstyle.style() as plt:
        fig, ax = plt.subplots(figsize=figstyle.figsize("column", aspect=0.75))
        for i, cond in enumerate(conds):
            g = subjects[subjects["condition"] == cond]
            rel = (g["pse"] / g["reference"]).to_numpy()
            ax.plot(np.full(len(rel), i) + np.linspace(-0.12, 0.12, max(len(rel), 1))[:len(rel)], rel, "o", ms=2.5,
                    color="0.55", mfc="none", mew=0.6)
            p = pooled[pooled["condition"] == cond].iloc[0]
            ax.errorbar([i + 0.3], [p["pse_rel"]], yerr=[[p["pse_rel"] - p["pse_rel_low"]],
                                                         [p["pse_rel_high"] - p["pse_rel"]]],
                        fmt="D", ms=4, color=figstyle.color("firm"), capsize=3, lw=1.0)
            for s, r in zip(g["subject"], rel):
                data["condition"].append(cond)
                data["subject"].append(s)
                data["pse_rel"].append(float(r))
        ax.axhline(1.0, color="0.2", ls="--", lw=0.8)
        ax.set_xticks(range(len(conds)), conds)
        ax.set_xlabel("reference (condition)")
        ax.set_ylabel("PSE / reference (1)")
        ax.set_title("Pooled PSE (diamonds: mean, 95 % CI)", loc="left")
    return fig, data


def build_magnitude_loglog(trials, pooled, x_label: str):
    """Normalised numbers against the stimulus on log-log axes with the group curve per condition."""
    data = {"condition": [], "level": [], "geometric_mean_number_norm": []}
    with figstyle.style() as plt:
        fig, ax = plt.subplots(figsize=figstyle.figsize("column", aspect=0.8))
        for cond in sorted(trials["condition"].unique()):
            st = figstyle.sample_style(cond)
            d = trials[trials["condition"] == cond]
            ax.plot(d["level"], d["number_norm"], ".", ms=2, color=st["color"], alpha=0.35)
            gm = np.exp(d.groupby("level")["ln_norm"].mean())
            p = pooled[pooled["condition"] == cond].iloc[0]
            xs = np.geomspace(gm.index.min(), gm.index.max(), 50)
            ax.plot(gm.index, gm.to_numpy(), st["marker"], color=st["color"], ms=4)
            ax.plot(xs, p["curve_k"] * xs ** p["curve_exponent"], color=st["color"], ls=st["linestyle"],
                    label=f"{_label(cond)}: exponent {p['exponent']:.2f} [{p['exponent_low']:.2f}, "
                          f"{p['exponent_high']:.2f}]")
            for lv, v in gm.items():
                data["condition"].append(cond)
                data["level"].append(float(lv))
                data["geometric_mean_number_norm"].append(float(v))
        ax.set_xscale("log")
        ax.set_yscale("log")
        _plain_log_axis(ax.xaxis)
        _plain_log_axis(ax.yaxis)
        ax.set_xlabel(x_label)
        ax.set_ylabel("number, normalised (1)")
        ax.set_title("Magnitude estimation (log-log)", loc="left")
        ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.22), borderaxespad=0)
    return fig, data


def build_magnitude_exponents(subjects, pooled):
    """Every subject's exponent with its 95 % interval, per condition, and the pooled mean (band)."""
    data = {"condition": [], "subject": [], "exponent": [], "exponent_low": [], "exponent_high": []}
    with figstyle.style() as plt:
        rows = subjects.sort_values(["condition", "subject"]).reset_index(drop=True)
        fig, ax = plt.subplots(figsize=figstyle.figsize("column", height_in=1.0 + 0.12 * len(rows)))
        for i, r in rows.iterrows():
            st = figstyle.sample_style(r["condition"])
            ax.errorbar([r["exponent"]], [i], xerr=[[r["exponent"] - r["exponent_low"]], [r["exponent_high"] - r["exponent"]]],
                        fmt="o", ms=2.5, color=st["color"], lw=0.7)
            for k in data:
                data[k].append(r[k])
        for _, p in pooled.iterrows():
            ax.axvspan(p["exponent_low"], p["exponent_high"], color=figstyle.color(p["condition"]), alpha=0.15, lw=0)
        ax.set_yticks(range(len(rows)), [f"{s} {_label(c)}" if pooled.shape[0] > 1 else s
                                         for s, c in zip(rows["subject"], rows["condition"])])
        ax.set_xlabel("Stevens exponent (1)")
        ax.set_title("Exponents (bars: 95 % CI; band: pooled mean)", loc="left")
    return fig, data


def save(builder, path, *args) -> dict:
    """Draw with ``builder`` and write PNG, SVG and CSV at ``path`` (the command's own folder)."""
    fig, data = builder(*args)
    return figstyle.save(fig, path, data, force=True)
