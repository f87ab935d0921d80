"""Figures of the psychometric fits, in the project style (figstyle), each as PNG + SVG + CSV.

* :func:`build_curves`: proportion correct (or "yes") per intensity and the fitted psi of each condition,
  pooled over subjects, with each subject's own fits in small panels beside it. Rules: the y axis shows the
  whole 0-1 range (yes/no) or chance to 1 (n-AFC) with points below chance drawn as arrows at the bottom edge;
  every point's area is proportional to its trial count; each threshold is drawn with its interval (an end
  beyond the drawn range, or open, as an arrow at the edge); the axis words come from the task (proportion
  correct, "yes" or "comparison harder") and the intensity's unit from the experiment, in physical units for a
  log10 session (log axis); a fit's flags are named in its legend entry (pooled) or counted in its panel's
  title (subjects).
* :func:`build_tracks`: staircase tracks (intensity by trial), correct responses filled, errors open,
  reversals ringed, catch trials as crosses (at the bottom edge when they have no intensity).

Compute and draw are apart: the numbers come from :mod:`analysis.psychophysics`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.ticker import FixedLocator, FuncFormatter, MaxNLocator, NullFormatter, NullLocator

import figstyle
from psychophysics.adaptive import reversals
from psychophysics.fitting import aggregate
from psychophysics.psychometric import psi
from analysis.psychophysics import ALL, POOLED, GroupFit, Proportion, Trials

#: the most tracks drawn in one staircase figure (the rest are listed in its title)
MAX_TRACKS = 12
#: the most subjects drawn as small panels beside the pooled fit (the rest are in the CSV and fits.csv)
MAX_SUBJECTS = 16
#: marker area (pt^2) of the level with the most trials; the others scale with their count
MAX_AREA = 70.0
#: how far (share of the tested range) the x axis may extend past the data to show a threshold or its interval
X_SLACK = 0.5
#: words of the varied parameters (experiment.config.vary)
VARIED_WORDS = {"stiffness_N_m": "stiffness", "amplitude_Ns_m": "transient amplitude", "gain": "transient gain"}
#: units as printed
UNIT_TEXT = {"N*s/m": "N·s/m"}


@dataclass(frozen=True)
class AxisWords:
    """What a psychometric figure's axes say: the x and y labels, the intensity's unit, and whether trials.csv's
    intensity is log10 of the physical value (then drawn in physical units on a log axis)."""

    x_label: str
    y_label: str
    unit: str
    log10_scale: bool = False


def axis_words(experiment: dict, alternatives: int, intensity_label: str | None = None) -> AxisWords:
    """The axis words of a task (module docstring): y from the task, x from the varied parameter and its unit.

    Parameters
    ----------
    experiment : dict
        ``session.json["experiment"]`` (empty for a plain CSV).
    alternatives : int
        n of the n-AFC task; 1 for yes/no.
    intensity_label : str, optional
        ``--intensity-label``: the x label as given (with its unit in parentheses).
    """
    kind = experiment.get("kind")
    config = experiment.get("config") if isinstance(experiment.get("config"), dict) else {}
    unit = UNIT_TEXT.get(experiment.get("intensity_unit") or "", experiment.get("intensity_unit") or "")
    log10 = experiment.get("intensity_scale") == "log10"
    if alternatives != 1:
        y = "proportion correct (1)"
    elif kind == "discrimination":
        y = "proportion 'comparison harder' (1)"
    else:
        y = "proportion 'yes' (1)"
    if intensity_label:
        return AxisWords(intensity_label, y, unit, log10)
    what = VARIED_WORDS.get(config.get("vary", ""), "")
    if kind == "discrimination" and what:
        x = f"comparison {what}"
    elif what:
        x = what
    else:
        x = "intensity"
    x = f"{x} ({unit or 'stimulus units'})"
    if log10 and not unit:
        x = f"10^intensity ({'stimulus units'})"
    return AxisWords(x, y, unit, log10)


def _label(condition: str) -> str:
    return "all trials" if condition in (ALL, "") else figstyle.sample_style(condition)["label"]


def _physical(x, words: AxisWords):
    x = np.asarray(x, dtype=float)
    return 10.0 ** x if words.log10_scale else x


def log_ticks(lo: float, hi: float, most: int = 5) -> list[float]:
    """Up to ``most`` readable ticks (1, 1.5, 2, 3, 5, 7 x 10^k) between ``lo`` and ``hi`` (> 0) for a log axis,
    spread evenly in log: plain numbers instead of matplotlib's ``3x10^0`` minor labels, which collide."""
    if not (lo > 0 and hi > lo):
        return []
    e0, e1 = math.floor(math.log10(lo)) - 1, math.ceil(math.log10(hi)) + 1
    cands = sorted({float(f"{m * 10.0 ** e:.6g}") for e in range(e0, e1 + 1) for m in (1, 1.5, 2, 3, 5, 7)})
    cands = [c for c in cands if lo <= c <= hi]
    if len(cands) < 2:
        return [float(f"{lo:.2g}"), float(f"{hi:.2g}")] if hi / lo > 1.05 else [float(f"{lo:.3g}")]
    idx = np.unique(np.round(np.linspace(0, len(cands) - 1, min(most, len(cands)))).astype(int))
    return [cands[i] for i in idx]


def _set_log_ticks(axis, lo, hi, most=5):
    ticks = log_ticks(lo, hi, most)
    axis.set_major_locator(FixedLocator(ticks))
    axis.set_major_formatter(FuncFormatter(lambda v, pos: f"{v:g}"))
    axis.set_minor_locator(NullLocator())
    axis.set_minor_formatter(NullFormatter())


def _panel(ax, trials, keep, fits, words, y_lo, n_max, rows, panel, log_x, legend):
    """Draw the points, curves and thresholds of ``fits`` (one per condition) on ``ax``; add plot rows."""
    data_x = []
    for g in fits:
        mask = keep if g.condition == ALL else keep & (trials.condition == g.condition)
        if panel != POOLED:
            mask = mask & (trials.subject == panel)
        levels, n, k = aggregate(trials.intensity[mask], trials.correct[mask])
        data_x.append(levels)
    if not data_x:
        return
    allx = np.concatenate(data_x)
    lo, hi = float(allx.min()), float(allx.max())
    span = (hi - lo) or 1.0
    # the drawn x range: the data, plus thresholds and interval ends within X_SLACK of it
    x_lo, x_hi = lo - 0.04 * span, hi + 0.04 * span
    for g in fits:
        for v in (g.fit.threshold, *g.fit.threshold_ci):
            if math.isfinite(v) and lo - X_SLACK * span <= v <= hi + X_SLACK * span:
                x_lo, x_hi = min(x_lo, v - 0.03 * span), max(x_hi, v + 0.03 * span)
    if log_x and not words.log10_scale and x_lo <= 0:
        x_lo = lo * 0.9
    for g, levels in zip(fits, data_x):
        f = g.fit
        st = figstyle.sample_style(g.condition) if g.condition != ALL else figstyle.sample_style("all trials")
        mask = keep if g.condition == ALL else keep & (trials.condition == g.condition)
        if panel != POOLED:
            mask = mask & (trials.subject == panel)
        levels, n, k = aggregate(trials.intensity[mask], trials.correct[mask])
        prop = k / n
        area = MAX_AREA * n / n_max
        clipped = prop < y_lo + 0.005
        y_drawn = np.where(clipped, y_lo + 0.015, prop)
        xp = _physical(levels, words)
        ax.scatter(xp[~clipped], y_drawn[~clipped], s=area[~clipped], facecolor="none", edgecolor=st["color"],
                   linewidth=0.8, zorder=3)
        if clipped.any():
            ax.scatter(xp[clipped], y_drawn[clipped], s=area[clipped], marker="v", facecolor=st["color"],
                       edgecolor=st["color"], linewidth=0.6, zorder=3)
        xs = np.linspace(x_lo, x_hi, 300)
        if f.function == "weibull":
            xs = np.geomspace(max(x_lo, lo * 0.5), x_hi, 300)
        flags = ", ".join(fl.name for fl in f.flags)
        lo_ci, hi_ci = f.threshold_ci
        text = (f"{_label(g.condition)}: {'PSE' if f.alternatives == 1 else 'threshold'} "
                f"{_physical(f.threshold, words):.3g} [{_num(lo_ci, words)}, {_num(hi_ci, words)}]"
                + (f" {words.unit}" if words.unit and words.unit != "1" else "") + (f" (flags: {flags})" if flags else ""))
        ax.plot(_physical(xs, words), psi(xs, f.threshold, f.slope, f.guess, f.lapse, f.function), color=st["color"],
                linestyle=st["linestyle"], label=text if legend else None)
        y_thr = f.guess + (1 - f.guess - f.lapse) * 0.5
        t_draw = min(max(f.threshold, x_lo), x_hi)
        ends = []
        for end, edge in ((lo_ci, x_lo), (hi_ci, x_hi)):
            ends.append(end if math.isfinite(end) and x_lo <= end <= x_hi else edge)
        xe = _physical(np.array([ends[0], t_draw, ends[1]]), words)
        ax.plot([xe[0], xe[2]], [y_thr, y_thr], color=st["color"], linewidth=1.2, zorder=4)
        for end, x_end, marker in ((lo_ci, xe[0], "<"), (hi_ci, xe[2], ">")):
            inside = math.isfinite(end) and x_lo <= end <= x_hi
            ax.plot([x_end], [y_thr], marker="|" if inside else marker, color=st["color"], markersize=6 if inside else 4,
                    zorder=4)
        ax.plot([xe[1]], [y_thr], marker="o", markersize=3.5, color=st["color"], zorder=5)
        for i in range(len(levels)):
            rows.append([panel, g.condition, "point", float(xp[i]), int(n[i]), int(k[i]), float(prop[i]),
                         float(y_drawn[i]), int(clipped[i]), float(area[i]), "", "", "", flags])
        rows.append([panel, g.condition, "threshold", float(_physical(f.threshold, words)), "", "", "", y_thr, 0, "",
                     float(_physical(f.threshold, words)), _ci_cell(lo_ci, words), _ci_cell(hi_ci, words), flags])
    if log_x:
        ax.set_xscale("log")
        x0, x1 = (_physical(x_lo, words), _physical(x_hi, words)) if words.log10_scale else (x_lo, x_hi)
        ax.set_xlim(x0, x1)
        _set_log_ticks(ax.xaxis, float(x0), float(x1), 5 if panel == POOLED else 3)
    else:
        ax.set_xlim(x_lo, x_hi)
        ax.xaxis.set_major_locator(MaxNLocator(5 if panel == POOLED else 3))
    ax.set_ylim(y_lo, 1.04)


def _num(v: float, words: AxisWords) -> str:
    if not math.isfinite(v):
        return "open" if not math.isnan(v) else "n/a"
    return f"{float(_physical(v, words)):.3g}"


def _ci_cell(v, words):
    return float(_physical(v, words)) if math.isfinite(v) else ""


def build_curves(trials: Trials, fits: list[GroupFit], words: AxisWords | str = "intensity"):
    """The pooled psychometric function of each condition over its data, and each subject's beside it.

    Parameters
    ----------
    trials : Trials
    fits : list of GroupFit
        From :func:`analysis.psychophysics.fit_groups`: the pooled fit of each condition is drawn large, each
        subject's fits (with several subjects) in small panels.
    words : AxisWords or str
        :func:`axis_words` (a plain string is taken as the x label of a linear n-AFC axis).

    Returns
    -------
    fig : Figure
    data : (header, rows)
        Per drawn point: ``panel`` (``(pooled)`` or the subject), ``condition``, ``kind`` (``point``),
        ``intensity`` (physical units), ``n_trials``, ``n_correct``, ``proportion``, ``y_drawn``, ``clipped``
        (drawn as an arrow at the bottom edge), ``marker_area``; per threshold (``kind = threshold``) its value
        and interval ends (empty where open); ``flags`` of the fit.
    """
    if isinstance(words, str):
        guess = fits[0].fit.guess if fits else 0.0
        words = AxisWords(words, "proportion correct (1)" if guess > 0 else "proportion 'yes' (1)", "")
    pooled = [g for g in fits if g.subject == POOLED]
    per_condition = [g for g in pooled if g.condition != ALL] or pooled
    subjects = sorted({g.subject for g in fits if g.subject != POOLED})
    shown = subjects[:MAX_SUBJECTS]
    keep = ~trials.is_catch & np.isfinite(trials.intensity)
    n_max = 1.0
    for g in fits:
        n_max = max(n_max, max(g.fit.n_per_level) if g.fit.n_per_level else 1.0)
    f0 = per_condition[0].fit if per_condition else None
    chance = f0.guess if f0 is not None and f0.alternatives > 1 else 0.0
    y_lo = chance - 0.06 if chance > 0 else -0.04
    log_x = words.log10_scale or (f0 is not None and f0.function == "weibull")
    header = ["panel", "condition", "kind", "intensity", "n_trials", "n_correct", "proportion", "y_drawn", "clipped",
              "marker_area", "threshold", "ci_low", "ci_high", "flags"]
    rows: list = []
    with figstyle.style() as plt:
        if shown:
            cols = min(4, math.ceil(math.sqrt(len(shown))))
            nrows = math.ceil(len(shown) / cols)
            fig = plt.figure(figsize=figstyle.figsize("page", height_in=max(2.8, 1.45 * nrows + 0.9)))
            grid = fig.add_gridspec(nrows, 2 + cols, width_ratios=[2.2, 0.35] + [1.0] * cols, wspace=0.45,
                                    hspace=0.75)
            ax = fig.add_subplot(grid[:, 0])
        else:
            fig, ax = plt.subplots(figsize=figstyle.figsize("column", aspect=0.75))
        _panel(ax, trials, keep, per_condition, words, y_lo, n_max, rows, POOLED, log_x, legend=True)
        ax.set_xlabel(words.x_label)
        ax.set_ylabel(words.y_label)
        ci = f0.ci_level if f0 is not None else 0.95
        ax.set_title(f"Pooled (bars: {ci:.0%} interval of the threshold)" if shown else
                     f"Psychometric fits (bars: {ci:.0%} interval of the threshold)", loc="left")
        if chance > 0:
            ax.axhline(chance, color="0.5", linewidth=0.6, linestyle=":")
        ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.22), borderaxespad=0, ncol=1)
        for i, subject in enumerate(shown):
            sub = fig.add_subplot(grid[i // cols, 2 + i % cols])
            own = [g for g in fits if g.subject == subject]
            _panel(sub, trials, keep, own, words, y_lo, n_max, rows, subject, log_x, legend=False)
            n_flags = sum(len(g.fit.flags) for g in own)
            sub.set_title(subject + (f" ({n_flags} flag{'s' if n_flags > 1 else ''})" if n_flags else ""),
                          loc="left", fontsize=7)
            sub.tick_params(labelsize=6)
            if i % cols:
                sub.set_yticklabels([])
            if chance > 0:
                sub.axhline(chance, color="0.5", linewidth=0.6, linestyle=":")
        if len(subjects) > len(shown):
            ax.text(0.0, 1.08, f"{len(subjects) - len(shown)} more subject(s) in fits.csv", transform=ax.transAxes,
                    fontsize=7)
    return fig, (header, rows)


def fig_curves(trials: Trials, fits: list[GroupFit], path: Path, words: AxisWords | str = "intensity") -> dict:
    """Write :func:`build_curves` as PNG, SVG and CSV into the command's own output folder; returns the paths."""
    fig, data = build_curves(trials, fits, words)
    return figstyle.save(fig, path, data, force=True)


def build_tracks(trials: Trials, words: AxisWords | str = "intensity"):
    """Staircase tracks: each (subject, staircase) in trial order, reversals marked.

    Parameters
    ----------
    trials : Trials
    words : AxisWords or str
        :func:`axis_words`, or the y axis label with its unit.

    Returns
    -------
    fig : Figure
    data : dict of columns
        ``subject, staircase, trial, intensity, correct, is_catch, reversal`` per drawn trial (intensity in
        physical units; empty for a catch trial without one, drawn at the bottom edge).
    """
    if isinstance(words, str):
        words = AxisWords(words, "", "")
    keys = []
    for s, c in zip(trials.subject, trials.staircase):
        if (s, c) not in keys:
            keys.append((s, c))
    shown = keys[:MAX_TRACKS]
    rows = {"subject": [], "staircase": [], "trial": [], "intensity": [], "correct": [], "is_catch": [],
            "reversal": []}
    finite = trials.intensity[np.isfinite(trials.intensity)]
    phys = _physical(finite, words) if len(finite) else np.array([1.0])
    log_y = words.log10_scale
    lo = float(phys.min())
    floor = lo / 1.3 if log_y else lo - 0.05 * (float(phys.max()) - lo or 1.0)
    with figstyle.style() as plt:
        fig, ax = plt.subplots(figsize=figstyle.figsize("page", height_in=2.8))
        for subject, stair in shown:
            mask = (trials.subject == subject) & (trials.staircase == stair)
            order = np.argsort(trials.trial[mask], kind="stable")
            t = trials.trial[mask][order]
            x = _physical(trials.intensity[mask][order], words)
            ok = trials.correct[mask][order].astype(bool)
            catch = trials.is_catch[mask][order]
            blank = catch & ~np.isfinite(x)
            name = " ".join(v for v in (subject, stair) if v) or "track"
            st = figstyle.sample_style(name)
            line, = ax.plot(t[~catch], x[~catch], color=st["color"], linewidth=0.8, label=name)
            ax.scatter(t[~catch & ok], x[~catch & ok], s=12, color=line.get_color(), zorder=3)
            ax.scatter(t[~catch & ~ok], x[~catch & ~ok], s=12, facecolor="white", edgecolor=line.get_color(),
                       zorder=3)
            rev = np.zeros(len(x), dtype=bool)
            idx = np.flatnonzero(~catch)
            rev[idx[reversals(x[~catch])]] = True
            ax.scatter(t[rev], x[rev], s=55, facecolor="none", edgecolor="black", linewidth=0.7, zorder=4)
            if catch.any():
                ax.scatter(t[catch], np.where(blank[catch], floor, x[catch]), s=14, marker="x",
                           color=line.get_color(), zorder=3)
            for i in range(len(x)):
                rows["subject"].append(subject)
                rows["staircase"].append(stair)
                rows["trial"].append(int(t[i]))
                rows["intensity"].append(float(x[i]) if np.isfinite(x[i]) else "")
                rows["correct"].append(int(ok[i]))
                rows["is_catch"].append(int(catch[i]))
                rows["reversal"].append(int(rev[i]))
        ax.set_xlabel("trial (1)")
        ax.set_ylabel(words.x_label)
        if log_y:
            ax.set_yscale("log")
            top = float(phys.max()) * 1.15
            ax.set_ylim(floor / 1.1, top)
            _set_log_ticks(ax.yaxis, floor / 1.1, top)
        more = f"; {len(keys) - len(shown)} more not drawn" if len(keys) > len(shown) else ""
        catches = " crosses: catch trials (at the bottom: no intensity)" if (trials.is_catch & ~np.isfinite(
            trials.intensity)).any() else ""
        ax.set_title(f"Staircase tracks (filled: correct, open: error, ringed: reversal{more}){catches}", loc="left")
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0)
    return fig, rows


def fig_tracks(trials: Trials, path: Path, words: AxisWords | str = "intensity") -> dict:
    """Write :func:`build_tracks` as PNG, SVG and CSV into the command's own output folder; returns the paths."""
    fig, data = build_tracks(trials, words)
    return figstyle.save(fig, path, data, force=True)


def build_proportions(props: list[Proportion], chance: float = 0.5):
    """Real-vs-virtual 2AFC: proportion correct per rendering (pooled over subjects) with its exact interval.

    Parameters
    ----------
    props : list of Proportion
        From :func:`analysis.psychophysics.proportions_correct`; the pooled rows are drawn.
    chance : float
        Drawn as a dashed line: a rendering at chance cannot be told from the real sample.

    Returns
    -------
    fig : Figure
    data : dict of columns
    """
    pooled = [p for p in props if p.subject == POOLED]
    rows = {"condition": [p.condition for p in pooled], "n_trials": [p.n_trials for p in pooled],
            "proportion_correct": [p.proportion for p in pooled], "ci_low": [p.ci_low for p in pooled],
            "ci_high": [p.ci_high for p in pooled], "p_vs_chance": [p.p_vs_chance for p in pooled]}
    with figstyle.style() as plt:
        fig, ax = plt.subplots(figsize=figstyle.figsize("column", height_in=0.3 * len(pooled) + 1.2))
        for i, p in enumerate(pooled):
            st = figstyle.sample_style(p.condition)
            ax.errorbar(p.proportion, i, xerr=[[p.proportion - p.ci_low], [p.ci_high - p.proportion]],
                        fmt=st["marker"], color=st["color"], capsize=2, elinewidth=0.8)
        ax.axvline(chance, color="0.4", linestyle="--", linewidth=0.8)
        ax.set_yticks(range(len(pooled)), [_label(p.condition) for p in pooled])
        ax.set_ylim(len(pooled) - 0.5, -0.5)
        ax.set_xlim(0.0, 1.02)
        ax.set_xlabel("proportion correct, 'which was real?' (1)")
        ax.set_title("Real vs virtual (dashed: chance)", loc="left")
    return fig, rows


def fig_proportions(props: list[Proportion], path: Path, chance: float = 0.5) -> dict:
    """Write :func:`build_proportions` as PNG, SVG and CSV into the command's own output folder; returns the paths."""
    fig, data = build_proportions(props, chance)
    return figstyle.save(fig, path, data, force=True)
