"""Figures of the adaptive methods, in the project's figure style (docs/figures.md): a staircase track with
its reversals marked, and the precision of an estimate against the number of trials.

Plotting only: the numbers come from :mod:`psychophysics.simulate` (or a session's trials); each figure is saved
with :func:`figstyle.save` as PNG, SVG and the plotted numbers (``.plot.csv``).
"""

from __future__ import annotations

import math

import figstyle

#: axis labels (every numeric axis names its unit, docs/figures.md)
TRIAL_LABEL = "trial (number)"
INTENSITY_LABEL = "intensity (stimulus units)"


def _minor_label(value: float, _pos=None) -> str:
    """A log axis's minor tick label: only at 2 and 5 times a power of ten (the others stay unlabelled)."""
    if value <= 0:
        return ""
    lead = value / 10.0 ** math.floor(math.log10(value))
    return f"{value:g}" if any(abs(lead - d) < 1e-6 for d in (2.0, 5.0)) else ""


def plot_track(track: list[dict], path, reference: float | None = None, estimate: float | None = None,
               title: str = "", log_axis: bool = True) -> dict:
    """Staircase track: each trial's intensity, correct (filled) or not (open), reversals ringed.

    Parameters
    ----------
    track : list of dict
        Rows with ``trial``, ``intensity``, ``correct`` (0/1) and ``reversal`` (0/1), in trial order.
    path : str or Path
        Figure file (``staircase.png`` -> ``.png``, ``.svg``, ``.plot.csv``).
    reference : float or None
        The true value the method tracks (a horizontal line).
    estimate : float or None
        The method's estimate (a dashed horizontal line).
    title : str
        Axes title (e.g. the method's name).
    log_axis : bool
        Logarithmic intensity axis (for log-spaced ranges).

    Returns
    -------
    dict
        Format -> path written (:func:`figstyle.save`).
    """
    series = figstyle.palette()["series"]
    trials = [r["trial"] for r in track]
    xs = [r["intensity"] for r in track]
    ok = [r for r in track if r["correct"]]
    bad = [r for r in track if not r["correct"]]
    rev = [r for r in track if r["reversal"]]
    with figstyle.style() as plt:
        fig, ax = plt.subplots(figsize=figstyle.figsize("column", aspect=0.7))
        ax.plot(trials, xs, color=series[6], lw=0.8, zorder=1)
        ax.plot([r["trial"] for r in ok], [r["intensity"] for r in ok], "o", ms=3.5, color=series[0],
                label="correct", zorder=3)
        ax.plot([r["trial"] for r in bad], [r["intensity"] for r in bad], "o", ms=3.5, mfc="white",
                color=series[1], label="incorrect", zorder=3)
        ax.plot([r["trial"] for r in rev], [r["intensity"] for r in rev], "s", ms=7, mfc="none", mew=0.9,
                color=series[7], label="reversal", zorder=4)
        if reference is not None:
            ax.axhline(reference, color=series[2], lw=1.0, label="true target")
        if estimate is not None:
            ax.axhline(estimate, color=series[5], lw=1.0, ls="--", label="estimate")
        if log_axis:
            ax.set_yscale("log")
            ax.yaxis.set_major_formatter(plt.FuncFormatter(lambda v, _pos: f"{v:g}"))   # 0.5, not 5 x 10^-1
            ax.yaxis.set_minor_formatter(plt.FuncFormatter(_minor_label))
        ax.set_xlabel(TRIAL_LABEL)
        ax.set_ylabel(INTENSITY_LABEL)
        if title:
            ax.set_title(title)
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
        data = {"trial": trials, "intensity": xs, "correct": [r["correct"] for r in track],
                "reversal": [r["reversal"] for r in track],
                "reference": [reference] * len(track), "estimate": [estimate] * len(track)}
        return figstyle.save(fig, path, data, force=True)   # into the output folder the command checked


def plot_precision(rows: list[dict], path, title: str = "") -> dict:
    """Precision against trials: median and 90th-percentile absolute error (%) of the estimate over runs.

    Parameters
    ----------
    rows : list of dict
        :func:`psychophysics.simulate.precision_table` rows (``trials``, ``median_abs_error_pct``,
        ``p90_abs_error_pct``, ``bias_pct``).
    path : str or Path
        Figure file (``precision.png``).
    title : str
        Axes title.

    Returns
    -------
    dict
        Format -> path written.
    """
    series = figstyle.palette()["series"]
    k = [r["trials"] for r in rows]
    med = [r["median_abs_error_pct"] for r in rows]
    p90 = [r["p90_abs_error_pct"] for r in rows]
    bias = [r["bias_pct"] for r in rows]
    with figstyle.style() as plt:
        fig, ax = plt.subplots(figsize=figstyle.figsize("column", aspect=0.7))
        ax.plot(k, med, "o-", ms=3, color=series[0], label="median |error|")
        ax.plot(k, p90, "s--", ms=3, color=series[1], label="90th pct |error|")
        ax.plot(k, bias, "^:", ms=3, color=series[2], label="bias")
        ax.axhline(0.0, color=series[6], lw=0.6)
        ax.set_xlabel("trials per run (number)")
        ax.set_ylabel("threshold error (%)")
        if title:
            ax.set_title(f"{title}, {rows[-1]['runs']} runs")
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
        data = {"trials": k, "median_abs_error_pct": med, "p90_abs_error_pct": p90, "bias_pct": bias}
        return figstyle.save(fig, path, data, force=True)   # into the output folder the command checked
