"""Figures of the psychometric fits (issue 34), in the project style (figstyle), each as PNG + SVG + CSV.

* :func:`build_curves`: proportion correct per intensity (points sized by their trial count) and the
  fitted psi per condition, with the threshold and its bootstrap interval drawn at psi(threshold);
* :func:`build_tracks`: staircase tracks (intensity by trial), correct responses filled, errors open,
  reversals ringed, catch trials as crosses.

Compute and draw are apart: the numbers come from :mod:`analysis.psychophysics`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import figstyle
from psychophysics.adaptive import reversals
from psychophysics.fitting import aggregate
from psychophysics.psychometric import psi
from analysis.psychophysics import ALL, POOLED, GroupFit, Proportion, Trials

#: the most tracks drawn in one staircase figure (the rest are listed in its title)
MAX_TRACKS = 12


def _label(condition: str) -> str:
    return "all trials" if condition in (ALL, "") else figstyle.sample_style(condition)["label"]


def build_curves(trials: Trials, fits: list[GroupFit], intensity_label: str = "intensity"):
    """The pooled psychometric function of each condition over its data.

    Parameters
    ----------
    trials : Trials
    fits : list of GroupFit
        From :func:`analysis.psychophysics.fit_groups`; the pooled fit of each condition is drawn.
    intensity_label : str
        The x axis label, with its unit in parentheses (e.g. ``"comparison stiffness (N/m)"``).

    Returns
    -------
    fig : Figure
    data : dict of columns
        ``condition, intensity, n_trials, n_correct, proportion_correct`` per level.
    """
    pooled = [g for g in fits if g.subject == POOLED]
    per_condition = [g for g in pooled if g.condition != ALL] or pooled
    keep = ~trials.is_catch
    rows = {"condition": [], "intensity": [], "n_trials": [], "n_correct": [], "proportion_correct": []}
    with figstyle.style() as plt:
        fig, ax = plt.subplots(figsize=figstyle.figsize("column", aspect=0.75))
        for g in per_condition:
            mask = keep if g.condition == ALL else keep & (trials.condition == g.condition)
            levels, n, k = aggregate(trials.intensity[mask], trials.correct[mask])
            st = figstyle.sample_style(g.condition) if g.condition != ALL else figstyle.sample_style("all trials")
            f = g.fit
            size = 8 + 60 * n / max(float(n.max()), 1.0)
            ax.scatter(levels, k / n, s=size, facecolor="none", edgecolor=st["color"], linewidth=0.8, zorder=3)
            lo, hi = float(levels.min()), float(levels.max())
            if f.function == "weibull":
                xs = np.geomspace(lo, hi, 300)
            else:
                pad = 0.05 * (hi - lo)
                xs = np.linspace(lo - pad, hi + pad, 300)
            ax.plot(xs, psi(xs, f.threshold, f.slope, f.guess, f.lapse, f.function), color=st["color"],
                    linestyle=st["linestyle"], label=f"{_label(g.condition)}: threshold {f.threshold:.3g}")
            y_thr = f.guess + (1 - f.guess - f.lapse) * 0.5
            if np.isfinite(f.threshold_ci).all():
                ax.errorbar([f.threshold], [y_thr], xerr=[[f.threshold - f.threshold_ci[0]],
                                                          [f.threshold_ci[1] - f.threshold]],
                            fmt="|", color=st["color"], capsize=3, elinewidth=1.0, zorder=4)
            for lv, nn, kk in zip(levels, n, k):
                rows["condition"].append(g.condition)
                rows["intensity"].append(float(lv))
                rows["n_trials"].append(int(nn))
                rows["n_correct"].append(int(kk))
                rows["proportion_correct"].append(float(kk / nn))
        if per_condition and per_condition[0].fit.function == "weibull":
            ax.set_xscale("log")
        guess = per_condition[0].fit.guess if per_condition else 0.0
        ax.set_ylim(min(guess, 0.5) - 0.05 if guess > 0 else -0.03, 1.03)
        ax.set_xlabel(intensity_label)
        ax.set_ylabel("proportion correct (1)" if guess > 0 else "proportion 'yes' (1)")
        ci = per_condition[0].fit.ci_level if per_condition else 0.95
        ax.set_title(f"Psychometric fits (bars: {ci:.0%} CI of the threshold)", loc="left")
        ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.22), borderaxespad=0, ncol=1)
    return fig, rows


def fig_curves(trials: Trials, fits: list[GroupFit], path: Path, intensity_label: str = "intensity") -> dict:
    """Write :func:`build_curves` as PNG, SVG and CSV into the command's own output folder; returns the paths."""
    fig, data = build_curves(trials, fits, intensity_label)
    return figstyle.save(fig, path, data, force=True)


def build_tracks(trials: Trials, intensity_label: str = "intensity"):
    """Staircase tracks: each (subject, staircase) in trial order, reversals marked.

    Parameters
    ----------
    trials : Trials
    intensity_label : str
        The y axis label with its unit.

    Returns
    -------
    fig : Figure
    data : dict of columns
        ``subject, staircase, trial, intensity, correct, is_catch, reversal`` per drawn trial.
    """
    keys = []
    for s, c in zip(trials.subject, trials.staircase):
        if (s, c) not in keys:
            keys.append((s, c))
    shown = keys[:MAX_TRACKS]
    rows = {"subject": [], "staircase": [], "trial": [], "intensity": [], "correct": [], "is_catch": [],
            "reversal": []}
    with figstyle.style() as plt:
        fig, ax = plt.subplots(figsize=figstyle.figsize("page", height_in=2.8))
        for subject, stair in shown:
            mask = (trials.subject == subject) & (trials.staircase == stair)
            order = np.argsort(trials.trial[mask], kind="stable")
            t = trials.trial[mask][order]
            x = trials.intensity[mask][order]
            ok = trials.correct[mask][order].astype(bool)
            catch = trials.is_catch[mask][order]
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
                ax.scatter(t[catch], x[catch], s=14, marker="x", color=line.get_color(), zorder=3)
            for i in range(len(x)):
                rows["subject"].append(subject)
                rows["staircase"].append(stair)
                rows["trial"].append(int(t[i]))
                rows["intensity"].append(float(x[i]))
                rows["correct"].append(int(ok[i]))
                rows["is_catch"].append(int(catch[i]))
                rows["reversal"].append(int(rev[i]))
        ax.set_xlabel("trial (1)")
        ax.set_ylabel(intensity_label)
        more = f"; {len(keys) - len(shown)} more not drawn" if len(keys) > len(shown) else ""
        ax.set_title(f"Staircase tracks (filled: correct, open: error, ringed: reversal{more})", loc="left")
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0)
    return fig, rows


def fig_tracks(trials: Trials, path: Path, intensity_label: str = "intensity") -> dict:
    """Write :func:`build_tracks` as PNG, SVG and CSV into the command's own output folder; returns the paths."""
    fig, data = build_tracks(trials, intensity_label)
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
