"""The report's model sections: "Models" and "Evidence for no difference" (text, tables, figure).

Each section is a :class:`Section` (title, plain-language lines, tables, figures) that
:mod:`analysis.report` renders into report.md and report.html like its other sections.
"""

from __future__ import annotations

import html
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from analysis import figures
from analysis.bayes import JZS_R, evidence_words


def _n(name) -> str:
    """A name from the data inside a section line, between analysis.report's name markers (escaped there when
    the line is written as markdown or HTML)."""
    return f"\x02{name}\x03"

ORDINAL_FIGURE = "fig_ordinal_probs.png"
ORDINAL_CAPTION = ("Ordinal model: probability of each realism rating 1–7 per sample from the proportional-odds "
                   "model at the mean incoming velocity, samples sorted by their expected rating. Read a bar "
                   "from left (rating 1, dark) to right (rating 7, light): the wider the light end, the more "
                   "often the sample is rated realistic. The observed shares are in the figure's CSV.")


@dataclass(frozen=True)
class Section:
    """One report section: ``lines`` (markdown ``**`` emphasis), ``tables`` as (title, DataFrame, CSV name),
    ``figures`` as (PNG path, caption), ``html_extra`` (already-escaped HTML appended in report.html only)."""

    title: str
    lines: list
    tables: list = field(default_factory=list)
    figures: list = field(default_factory=list)
    html_extra: str = ""


def _inverse(bf: float) -> float:
    """1/bf, with 1/0 = inf (a Bayes factor above ~1e308 is stored as inf, its inverse as 0)."""
    return float("inf") if bf == 0 else 1.0 / bf


def _p(p: float) -> str:
    return "p < 0.001" if p < 1e-3 else f"p = {p:.3f}"


def _ci(lo: float, hi: float) -> str:
    return f"95 % CI {lo:.2f} to {hi:.2f}"


def mixed_lines(models, alpha: float) -> list[str]:
    """Plain-language reading of the mixed model: structure, EMMs, velocity, contrasts vs the t-tests."""
    info = models.mixed
    if not info.get("fitted"):
        return ["**Linear mixed model**: not fitted (the reason is below)."]
    cov = info.get("covariates", [])
    terms = ["sample"] + [{"velocity_m_s": "incoming velocity", "grip_N": "grip"}[c] for c in cov]
    v_mean = info.get("centres", {}).get("velocity_m_s", (np.nan,))[0]
    out = [f"**Linear mixed model** (statsmodels MixedLM, REML) of {info['n_attempts']} valid attempts by "
           f"{info['n_subjects']} subjects: rating ~ {' + '.join(terms)}, {info['structure']} per subject. "
           "It uses every attempt (unbalanced cells weigh what they hold) and each subject's own rating level."]
    emm = models.emm.sort_values("emm", ascending=False)
    if len(emm):
        top, low = emm.iloc[0], emm.iloc[-1]
        at = f" at the mean incoming velocity ({v_mean:.3f} m/s)" if np.isfinite(v_mean) else ""
        out.append(f"Estimated marginal means{at}: highest {_n(top['sample'])} {top['emm']:.2f} "
                   f"({_ci(top['ci_low'], top['ci_high'])}), lowest {_n(low['sample'])} {low['emm']:.2f} "
                   f"({_ci(low['ci_low'], low['ci_high'])}); all in models_emm.csv.")
    vel = models.fixed[(models.fixed["model"] == "mixed") & (models.fixed["term"] == "velocity_m_s")]
    if len(vel):
        r = vel.iloc[0]
        sig = "a significant" if r["p"] < alpha else "no significant"
        out.append(f"Incoming velocity has {sig} effect on the rating within samples: {r['estimate']:+.2f} rating "
                   f"points per m/s ({_ci(r['ci_low'], r['ci_high'])}, {_p(r['p'])}), i.e. "
                   f"{r['estimate'] * 0.05:+.2f} points for a tap 0.05 m/s faster.")
    c = models.contrasts
    if len(c):
        sig = int((c["p_holm"] < alpha).sum())
        have = c["ttest_mean_diff"].notna()
        agree = int(c.loc[have, "same_direction"].sum())
        both = have & c["ttest_p_holm"].notna()
        same_sig = int(((c.loc[both, "p_holm"] < alpha) == (c.loc[both, "ttest_p_holm"] < alpha)).sum())
        text = (f"{sig} of {len(c)} pairwise contrasts differ (Wald z, Holm p < {alpha}; models_contrasts.csv). "
                f"Agreement with the paired t-tests on per-subject means: same direction in {agree} of "
                f"{int(have.sum())} pairs, same significance verdict in {same_sig} of {int(both.sum())}.")
        flips = c[have & ~c["same_direction"].astype(bool)]
        if len(flips):
            text += " Opposite directions (all small differences): " + ", ".join(
                f"{_n(r.sample_a)}–{_n(r.sample_b)} ({r.estimate:+.2f} vs {r.ttest_mean_diff:+.2f})"
                for r in flips.head(6).itertuples()) + ("; …" if len(flips) > 6 else "") + "."
        out.append(text)
        out.append("Reading: where the model and the t-tests agree, the conclusions do not depend on averaging each "
                   "subject's attempts first or on how fast the taps were; a disagreement in direction only "
                   "occurs for differences near zero.")
    return out


def ordinal_lines(models, alpha: float) -> list[str]:
    """Plain-language reading of the proportional-odds model and its assumption."""
    info = models.ordinal
    if not info.get("fitted"):
        return ["**Ordinal model**: not fitted (the reason is below)."]
    probs = models.probabilities
    wide = probs.pivot(index="sample", columns="rating", values="p_model")
    expected = (wide * wide.columns.to_numpy()[None, :]).sum(axis=1).sort_values(ascending=False)
    mode = wide.idxmax(axis=1)
    high = (wide[[c for c in wide.columns if c >= 5]].sum(axis=1)).sort_values(ascending=False)
    out = [f"**Ordinal model** (statsmodels OrderedModel, proportional odds, logit) of the same {info['n_attempts']} "
           "attempts and fixed effects, treating the ratings as ordered categories rather than numbers; subjects "
           "enter through cluster-robust standard errors (population-averaged effects, see docs/analysis.md).",
           f"Most likely rating: {', '.join(f'{_n(s)} {int(mode[s])}' for s in expected.index[:4])}, …; probability "
           f"of a rating of 5 or more: highest {_n(high.index[0])} {high.iloc[0]:.0%}, lowest {_n(high.index[-1])} "
           f"{high.iloc[-1]:.0%} (figure below, models_ordinal_probabilities.csv).",
           "Assumption (proportional odds): each sample shifts all the cut-points between adjacent ratings by the "
           "same log-odds, so one number per sample describes it. This is assumed, not tested here; compare the "
           "model's and the observed shares per rating (the figure's CSV) to see where it fits less well."]
    if len(models.emm):
        rank_lin = models.emm.sort_values("emm", ascending=False)["sample"].tolist()
        same = rank_lin[:3] == expected.index[:3].tolist()
        out.append("The ordinal and the linear model " + ("rank the top three samples alike."
                                                          if same else "rank the top three samples differently: "
                                                          f"{', '.join(map(_n, rank_lin[:3]))} vs "
                                                          f"{', '.join(map(_n, expected.index[:3]))}."))
    return out


def wilcoxon_lines(pairwise: pd.DataFrame, alpha: float) -> list[str]:
    """The non-parametric check: Wilcoxon signed-rank (Holm) beside the t-tests, per group."""
    out = []
    for g, sub in pairwise.groupby("group", sort=False):
        ok = sub["p_holm"].notna() & sub["wilcoxon_p_holm"].notna()
        if not ok.any():
            continue
        t_sig = sub.loc[ok, "p_holm"] < alpha
        w_sig = sub.loc[ok, "wilcoxon_p_holm"] < alpha
        out.append(f"**Non-parametric check, {g} subjects**: the Wilcoxon signed-rank test (Holm) finds "
                   f"{int(w_sig.sum())} of {int(ok.sum())} pairs different, the paired t-test {int(t_sig.sum())}; "
                   f"they agree on {int((t_sig == w_sig).sum())} pairs (columns wilcoxon_* of pairwise_ttests.csv). "
                   "Reading: where they agree, the t-test's verdict does not rest on normally distributed differences.")
    return out


def evidence_lines(res) -> list[str]:
    """Plain-language evidence for no difference: TOST and BF01 per sample vs the reference, and inconclusive pairs."""
    cfg = res.config
    out = [f"Bayes factors compare 'no difference' with 'some difference' (JZS prior, Cauchy scale r = {JZS_R}, "
           "Rouder et al. 2009): BF01 = 1/BF10 above 3 is moderate, above 10 strong evidence for no difference; "
           "between 1/3 and 3 the data cannot tell. A non-significant t-test alone is not evidence for no difference."]
    for g, sub in res.equivalence.groupby("group", sort=False):
        parts = []
        for r in sub.itertuples():
            if not np.isfinite(r.bf01):
                continue
            tost = "equivalent" if r.equivalent else "not shown equivalent"
            parts.append(f"{_n(r.sample)}: {tost} within ±{r.margin:g} (TOST {_p(r.p_tost)}), "
                         f"{evidence_words(_inverse(r.bf01))}")
        if parts:
            out.append(f"**{g} subjects, each sample vs {_n(cfg.reference)}**: " + "; ".join(parts) + ".")
    for g, sub in res.pairwise.groupby("group", sort=False):
        bf = sub["bf10"]
        null = sub[bf < 1 / 3]
        unsure = sub[(bf >= 1 / 3) & (bf <= 3)]
        line = (f"**{g} subjects, all {len(sub)} pairs**: {len(null)} with at least moderate evidence for no "
                f"difference (BF01 > 3)")
        if len(null):
            line += ": " + ", ".join(f"{_n(r.sample_a)}–{_n(r.sample_b)} (BF01 = {_inverse(r.bf10):.1f})"
                                     for r in null.sort_values("bf10").head(8).itertuples()) + \
                ("; …" if len(null) > 8 else "")
        line += (f"; {len(unsure)} inconclusive (1/3 ≤ BF10 ≤ 3): for those, more subjects are needed "
                 "(python -m analysis plan --pilot DATA gives how many).")
        out.append(line)
    return out


def bf_matrix_html(pairwise: pd.DataFrame, samples) -> str:
    """HTML matrix of BF10 per pair and group (Figure 4.18's companion), each cell's hover naming the
    pair, its Holm p and BF10."""
    parts = []
    for g, sub in pairwise.groupby("group", sort=False):
        cell = {}
        for r in sub.itertuples():
            cell[(r.sample_a, r.sample_b)] = cell[(r.sample_b, r.sample_a)] = r
        head = "".join(f"<th scope='col'>{html.escape(s)}</th>" for s in samples)
        rows = []
        for a in samples:
            tds = []
            for b in samples:
                r = cell.get((a, b))
                if r is None or not np.isfinite(r.bf10):
                    tds.append("<td>–</td>")
                    continue
                tip = f"{a} vs {b}: Holm p = {r.p_holm:.3g}, BF10 = {r.bf10:.3g} ({evidence_words(r.bf10)})"
                tds.append(f"<td title='{html.escape(tip, quote=True)}'>{r.bf10:.2g}</td>")
            rows.append(f"<tr><th scope='row'>{html.escape(a)}</th>{''.join(tds)}</tr>")
        parts.append(f"<details><summary>BF10 matrix, {html.escape(str(g))} subjects (hover a cell for the pair, its "
                     f"Holm p and BF10; the same numbers as Figure 4.18)</summary><div class='table-wrap'><table>"
                     f"<thead><tr><th></th>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table></div></details>")
    return "".join(parts)


def sections(res, out: Path, draw: bool = True) -> list[Section]:
    """The "Models" and "Evidence for no difference" sections of ``res`` (an :class:`analysis.pipeline.Analysis`).

    ``draw``: write the ordinal model's figure into ``out`` (:data:`ORDINAL_FIGURE`) when the model was fitted;
    an earlier report's copy is removed when it is not drawn.
    """
    alpha = res.config.alpha
    models = res.models
    lines, tables, figs = [], [], []
    if models is not None:
        lines += mixed_lines(models, alpha) + ordinal_lines(models, alpha)
        lines += [f"Note: {n}" for n in models.notes]
        tables = [("Mixed and ordinal models: fixed effects (models_fixed_effects.csv)", models.fixed),
                  ("Mixed model: estimated marginal means (models_emm.csv)", models.emm),
                  ("Mixed model: pairwise contrasts (models_contrasts.csv)", models.contrasts)]
        png = out / ORDINAL_FIGURE
        if draw and models.ordinal.get("fitted") and len(models.probabilities):
            figs.append((Path(figures.fig_ordinal_probs(models.probabilities, png)["png"]), ORDINAL_CAPTION))
        else:
            for ext in ("png", "svg", "plot.csv"):
                stale = png.with_suffix("." + ext)
                if stale.exists():
                    stale.unlink()
    lines += wilcoxon_lines(res.pairwise, alpha)
    model_section = Section("Models", lines, tables, figs)
    evidence = Section("Evidence for no difference", evidence_lines(res),
                       html_extra=bf_matrix_html(res.pairwise, res.study.catalog))
    return [model_section, evidence]
