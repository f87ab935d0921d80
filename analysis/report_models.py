"""The report's sections "Models" and "Evidence for no difference" (text, tables, figure).

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
from analysis.failures import attempt
from analysis.models import CAUTION_SUBJECTS


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


def _pairs(rows, n: int = 6) -> str:
    """Up to ``n`` sample pairs of a contrasts table, named, then "…"."""
    rows = list(rows)
    return ", ".join(f"{_n(r.sample_a)}–{_n(r.sample_b)}" for r in rows[:n]) + (", …" if len(rows) > n else "")


def caution_line(n_subjects: int) -> str | None:
    """The plain caution of a study with fewer than :data:`analysis.models.CAUTION_SUBJECTS` subjects, or None."""
    if n_subjects >= CAUTION_SUBJECTS:
        return None
    return (f"**Caution: {n_subjects} subject(s)**, fewer than {CAUTION_SUBJECTS}. Both models estimate how much "
            f"subjects differ from only {n_subjects} people, so their standard errors are themselves uncertain; the "
            "mixed model's t tests allow for that (Satterthwaite degrees of freedom: their false-positive rate stayed "
            "near α in simulated studies of 3 and 6 subjects, docs/analysis.md), but read every model result as a "
            "check of the paired t-tests, not as a finding of its own, and plan the next study's size "
            "(python -m analysis plan).")


def mixed_lines(models, alpha: float) -> list[str]:
    """Plain-language reading of the mixed model: structure, EMMs, velocity, contrasts vs the t-tests."""
    info = models.mixed
    if not info.get("fitted"):
        return ["**Linear mixed model**: not fitted (the reason is below)."]
    cov = info.get("covariates", [])
    terms = ["sample"] + [{"velocity_m_s": "incoming velocity", "grip_N": "grip"}[c] for c in cov]
    v_mean = info.get("centres", {}).get("velocity_m_s", (np.nan,))[0]
    out = [f"**Linear mixed model** (REML, t tests with Satterthwaite degrees of freedom) of {info['n_attempts']} "
           f"valid attempts by {info['n_subjects']} subjects: rating ~ {' + '.join(terms)}, random terms: "
           f"{info['structure']}. It uses every attempt (unbalanced cells weigh what they hold), each subject's "
           "own rating level and each subject's own view of each sample (so that a few subjects' many attempts "
           "are not counted as many subjects)."]
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
                   f"points per m/s ({_ci(r['ci_low'], r['ci_high'])}, t({r['df']:.1f}) = {r['t']:.2f}, "
                   f"{_p(r['p'])}), i.e. {r['estimate'] * 0.05:+.2f} points for a tap 0.05 m/s faster.")
    c = models.contrasts
    if len(c):
        sig = c["p_holm"] < alpha
        out.append(f"{int(sig.sum())} of {len(c)} pairwise contrasts differ (t tests, Satterthwaite df "
                   f"{c['df'].min():.1f}–{c['df'].max():.1f}, Holm p < {alpha}; models_contrasts.csv).")
        out.append(comparison_line(c, alpha))
    return out


def comparison_line(c: pd.DataFrame, alpha: float) -> str:
    """The mixed model's contrasts beside the paired t-tests, worded as what they are: where the verdicts agree,
    where they do not (named), and where the directions differ (named, with both differences)."""
    have = c["ttest_mean_diff"].notna() & c["ttest_p_holm"].notna()
    if not have.any():
        return "No paired t-test to set beside the contrasts (fewer than 3 subjects rated both samples of every pair)."
    m = c[have]
    model_sig, t_sig = m["p_holm"] < alpha, m["ttest_p_holm"] < alpha
    both, neither = int((model_sig & t_sig).sum()), int((~model_sig & ~t_sig).sum())
    model_only, t_only = m[model_sig & ~t_sig], m[~model_sig & t_sig]
    flips = m[~m["same_direction"].astype(bool)]
    if len(model_only) + len(t_only) == 0:
        text = (f"The mixed model and the paired t-tests on per-subject means give the same verdict on all {len(m)} "
                f"pairs ({both} different, {neither} not).")
    else:
        text = (f"The mixed model and the paired t-tests on per-subject means **disagree on "
                f"{len(model_only) + len(t_only)} of {len(m)} pairs**: the model alone finds {len(model_only)} "
                "different" + (f" ({_pairs(model_only.itertuples())})" if len(model_only) else "")
                + f", the t-tests alone {len(t_only)}" + (f" ({_pairs(t_only.itertuples())})" if len(t_only) else "")
                + f"; they agree on {both} pairs being different and {neither} not. The model judges each pair "
                "against the spread of all samples' attempts and subject × sample views (more degrees of freedom), a "
                "t-test against that pair's own per-subject differences alone (subjects − 1 degrees of freedom): "
                "where only one finds a difference, treat it as unsettled.")
    if len(flips):
        text += (f" The two estimate opposite directions for {len(flips)} pair(s): "
                 + ", ".join(f"{_n(r.sample_a)}–{_n(r.sample_b)} ({r.estimate:+.2f} vs {r.ttest_mean_diff:+.2f})"
                             for r in flips.head(6).itertuples()) + ("; …" if len(flips) > 6 else "") + ".")
    else:
        text += " Every pair's difference has the same sign in both."
    return text


def ordinal_lines(models, alpha: float) -> list[str]:
    """Plain-language reading of the proportional-odds model, its cut points and its assumption."""
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
           f"enter through cluster-robust standard errors with t tests on {info.get('df', float('nan')):.0f} degrees "
           "of freedom (subjects − 1; population-averaged effects, see docs/analysis.md).",
           f"Most likely rating: {', '.join(f'{_n(s)} {int(mode[s])}' for s in expected.index[:4])}, …; probability "
           f"of a rating of 5 or more: highest {_n(high.index[0])} {high.iloc[0]:.0%}, lowest {_n(high.index[-1])} "
           f"{high.iloc[-1]:.0%} (figure below, models_ordinal_probabilities.csv).",
           "Assumption (proportional odds): each sample shifts all the cut-points between adjacent ratings by the "
           "same log-odds, so one number per sample describes it. This is assumed, not tested here; compare the "
           "model's and the observed shares per rating (the figure's CSV) to see where it fits less well."]
    cuts = models.fixed[(models.fixed["model"] == "ordinal") & models.fixed["term"].str.startswith("cut ")]
    if len(cuts):
        out.append("Cut points between adjacent ratings (latent log-odds scale of the reference sample at the mean "
                   "velocity, increasing): " + ", ".join(f"{r.term[4:]} {r.estimate:.2f}" for r in cuts.itertuples())
                   + " (rows cut a|b of models_fixed_effects.csv).")
    if len(models.emm):
        rank_lin = models.emm.sort_values("emm", ascending=False)["sample"].tolist()
        same = rank_lin[:3] == expected.index[:3].tolist()
        out.append("The ordinal and the linear model " + ("rank the top three samples alike."
                                                          if same else "rank the top three samples differently: "
                                                          f"{', '.join(map(_n, rank_lin[:3]))} vs "
                                                          f"{', '.join(map(_n, expected.index[:3]))}."))
    return out


def wilcoxon_lines(pairwise: pd.DataFrame, alpha: float) -> list[str]:
    """The non-parametric check: Wilcoxon signed-rank (Holm) beside the t-tests, per group, disagreement said as such."""
    out = []
    for g, sub in pairwise.groupby("group", sort=False):
        ok = sub["p_holm"].notna() & sub["wilcoxon_p_holm"].notna()
        if not ok.any():
            continue
        t_sig = sub.loc[ok, "p_holm"] < alpha
        w_sig = sub.loc[ok, "wilcoxon_p_holm"] < alpha
        same = int((t_sig == w_sig).sum())
        line = (f"**Non-parametric check, {g} subjects**: the Wilcoxon signed-rank test (Holm) finds "
                f"{int(w_sig.sum())} of {int(ok.sum())} pairs different, the paired t-test {int(t_sig.sum())}; ")
        if same == int(ok.sum()):
            line += ("they give the same verdict on every pair (columns wilcoxon_* of pairwise_ttests.csv): the "
                     "t-test's verdicts do not rest on normally distributed differences.")
        else:
            line += (f"**they differ on {int(ok.sum()) - same} pairs** (same verdict on {same}; columns wilcoxon_* "
                     "of pairwise_ttests.csv): there, the t-test's verdict rests on its assumption of normally "
                     "distributed differences.")
            n_max = int(sub.loc[ok, "n"].max())
            floor = 2.0 / 2.0 ** n_max           # the exact signed-rank test's smallest two-sided p
            if floor * int(ok.sum()) >= alpha and w_sig.sum() == 0:
                line += (f" With {n_max} subjects the signed-rank test cannot give a p below {floor:.3g}, so after "
                         f"Holm over {int(ok.sum())} pairs it cannot find any difference: here it says nothing either "
                         "way.")
        out.append(line)
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
    an earlier report's copy is removed when it is not drawn. Each reading, table and figure is its own part:
    one that cannot be written says why in its section, the others are written (analysis.failures).
    """
    alpha = res.config.alpha
    models = res.models
    lines, tables, figs, problems = [], [], [], []
    if models is not None:
        def readings():
            caution = caution_line(int(res.matrix.counts.sum(axis=1).astype(bool).sum()))
            fitted = models.mixed.get("fitted") or models.ordinal.get("fitted")
            return [caution] if caution and fitted else []

        lines += attempt("the caution on few subjects", problems, readings, default=[], failed="not written")
        lines += attempt("the reading of the linear mixed model", problems, mixed_lines, models, alpha,
                         default=["**Linear mixed model**: its reading could not be written (below)."],
                         failed="not written")
        lines += attempt("the reading of the ordinal model", problems, ordinal_lines, models, alpha,
                         default=["**Ordinal model**: its reading could not be written (below)."],
                         failed="not written")
        lines += [f"Note: {n}" for n in models.notes]
        tables = [("Mixed and ordinal models: fixed effects (models_fixed_effects.csv)", models.fixed),
                  ("Mixed model: estimated marginal means (models_emm.csv)", models.emm),
                  ("Mixed model: pairwise contrasts (models_contrasts.csv)", models.contrasts)]
        png = out / ORDINAL_FIGURE
        drawn = None
        if draw and models.ordinal.get("fitted") and len(models.probabilities):
            drawn = attempt("the ordinal model's figure", problems, figures.fig_ordinal_probs, models.probabilities,
                            png, failed="not drawn")
        if drawn is not None:
            figs.append((Path(drawn["png"]), ORDINAL_CAPTION))
        else:
            for ext in ("png", "svg", "plot.csv"):
                stale = png.with_suffix("." + ext)
                if stale.exists():
                    stale.unlink()
    lines += attempt("the non-parametric check", problems, wilcoxon_lines, res.pairwise, alpha, default=[],
                     failed="not written")
    lines += [f"Note: {p[0].upper()}{p[1:]}" for p in problems]
    model_section = Section("Models", lines, tables, figs)
    problems = []
    evidence = Section("Evidence for no difference",
                       attempt("the reading of the evidence", problems, evidence_lines, res, default=[],
                               failed="not written"),
                       html_extra=attempt("the BF10 matrix", problems, bf_matrix_html, res.pairwise,
                                          res.study.catalog, default="", failed="not written"))
    evidence.lines.extend(f"Note: {p[0].upper()}{p[1:]}" for p in problems)
    return [model_section, evidence]
