"""The study report: tables, figures, report.md and report.html (command: :mod:`analysis.cli_report`)."""

from __future__ import annotations

import base64
import html
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the heavy imports wait until a report is made, so --help stays fast
    import pandas as pd

    from analysis.pipeline import Analysis

FIGURES = {
    "fig_4_17_ratings.png": "Figure 4.17: mean realism rating per sample (bars), median of the per-subject means "
                            "(circles) and standard error across subjects (caps).",
    "fig_4_18_pvalues.png": "Figure 4.18: p-values of paired t-tests on per-subject mean ratings for every pair of "
                            "samples; light squares = indistinguishable, * = Holm-adjusted p < 0.05, red hatched = "
                            "n/a (a sample against itself, or a pair excluded from the tests).",
    "fig_4_19_penetration.png": "Figure 4.19: mean penetration depth versus mean realism rating per sample; "
                                "error bars one standard deviation.",
    "fig_4_20_accelerations.png": "Figure 4.20: typical handle accelerations per sample for taps at a common "
                                  "incoming velocity (from the saved traces).",
}


def _fmt(v) -> str:
    import numpy as np
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (float, np.floating)):
        if not np.isfinite(v):
            return "–"
        a = abs(v)
        return f"{v:.3g}" if (a >= 1e-3 or a == 0) and a < 1e5 else f"{v:.2e}"
    return str(v)


def markdown_table(df: pd.DataFrame) -> str:
    """A GitHub-flavoured markdown table of ``df`` (numbers to 3 significant digits)."""
    head = "| " + " | ".join(map(str, df.columns)) + " |"
    sep = "|" + "|".join("---" for _ in df.columns) + "|"
    body = ["| " + " | ".join(_fmt(v) for v in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join([head, sep, *body])


def _p(p: float) -> str:
    return "p < 0.001" if p < 1e-3 else f"p = {p:.3f}"


def summary_text(res: Analysis, fig_notes: list[str]) -> tuple[list[str], dict]:
    """Plain-language findings: omnibus, equivalence, significant pairs, velocity, exclusions.

    Returns the summary lines (markdown emphasis with ``**``) and, per group, one line per
    significantly different pair.
    """
    import numpy as np
    cfg, out, pairs = res.config, [], {}
    subj = res.study.subjects
    exp_counts = subj["experience"].value_counts()
    experience_words = {"none": "never used a haptic device", "few": "used one a few times",
                        "regular": "use one regularly"}
    out.append(f"{len(subj)} subjects ({', '.join(f'{n} {experience_words.get(e, e)}' for e, n in exp_counts.items())}); {len(res.study.catalog)} samples; {int(res.matrix.counts.sum())} valid testing "
               f"attempts analysed.")
    for g, sub in res.anova.groupby("group", sort=False):
        a = sub[sub["test"] == "rm_anova"].iloc[0]
        f = sub[sub["test"] == "friedman"].iloc[0]
        if not np.isfinite(a["statistic"]):
            out.append(f"**{g}**: not enough complete subjects for the omnibus tests.")
            continue
        verdict = "differ significantly" if a["p_gg"] < cfg.alpha else "do not differ significantly"
        out.append(f"**{g} subjects** (n = {a['n_subjects']}): ratings {verdict} between samples "
                   f"(repeated-measures ANOVA F({a['df1']:.0f}, {a['df2']:.0f}) = {a['statistic']:.2f}, "
                   f"Greenhouse–Geisser ε = {a['epsilon_gg']:.2f}, corrected {_p(a['p_gg'])}; "
                   f"Friedman χ²({f['df1']:.0f}) = {f['statistic']:.1f}, {_p(f['p'])}).")
    for g, sub in res.equivalence.groupby("group", sort=False):
        eq = sub[sub["equivalent"]]["sample"].tolist()
        out.append(f"**{g} subjects**: equivalent to {cfg.reference} within ±{cfg.margin:g} rating points "
                   f"(paired TOST, p < {cfg.alpha}): {', '.join(eq) if eq else 'none'}. Samples not shown "
                   "equivalent are not thereby shown different; that may just be too few subjects.")
    for g, sub in res.pairwise.groupby("group", sort=False):
        sig = sub[sub["p_holm"] < cfg.alpha]
        out.append(f"**{g} subjects**: {len(sig)} of {len(sub)} sample pairs differ significantly "
                   f"(paired t-test, Holm-adjusted p < {cfg.alpha}; listed under 'Significantly different pairs').")
        pairs[g] = []
        for r in sig.itertuples():
            hi, lo = (r.sample_a, r.sample_b) if r.mean_diff > 0 else (r.sample_b, r.sample_a)
            # SD of the differences 0 (up to rounding of the per-subject means): t is infinite or ~1e15
            degenerate = "" if np.isfinite(r.cohen_dz) and abs(r.cohen_dz) < 1e6 else \
                " — every subject gave the same difference, so the t-test is degenerate (SD 0); treat with care"
            pairs[g].append(f"{hi} rated higher than {lo} by {abs(r.mean_diff):.2f} points "
                            f"(95 % CI {abs(r.ci_low if r.mean_diff > 0 else r.ci_high):.2f}–"
                            f"{abs(r.ci_high if r.mean_diff > 0 else r.ci_low):.2f}, n = {r.n}, "
                            f"Holm {_p(r.p_holm)})" + degenerate)
    vr = res.velocity[res.velocity["sample"] != "(all)"]
    sig_v = vr[vr["p"] < cfg.alpha]["sample"].tolist()
    out.append("Incoming velocity vs rating within each sample (Pearson, uncorrected): "
               + (f"significant for {', '.join(sig_v)}." if sig_v else "no significant correlation.")
               + " Repeated-measures correlation over all samples: "
               + (f"r = {res.velocity.iloc[-1]['r_rm']:.2f}, {_p(res.velocity.iloc[-1]['p_rm'])}."
                  if np.isfinite(res.velocity.iloc[-1]["r_rm"]) else "not computable."))
    att = res.attempts
    inv = int((att["attempts"] - att["valid"]).sum())
    out.append(f"**Excluded attempts**: {inv} invalid testing attempts were left out (saturated "
               f"{int(att['saturated'].sum())}, rejected {int(att['rejected'].sum())}, overpowered "
               f"{int(att['overpowered'].sum())}, other {int(att['invalid_other'].sum())}); each was redrawn, so "
               "its sample was rated again later.")
    if len(res.exclusions):
        out.append("**Excluded subjects**: " + "; ".join(
            f"{r.subject} misses {r.missing_samples.replace(';', ', ')} and is left out of the RM-ANOVA/Friedman "
            f"tests and of the pairwise/equivalence tests with those samples" for r in res.exclusions.itertuples())
                   + ".")
    else:
        out.append("**Excluded subjects**: none; every subject rated every sample.")
    for w in res.warnings:
        out.append(f"Warning: {w}")
    out.extend(fig_notes)
    return out, pairs


def _strong(text: str) -> str:
    """Markdown ``**x**`` -> ``<strong>x</strong>`` (text already HTML-escaped)."""
    parts = text.split("**")
    return "".join(f"<strong>{p}</strong>" if i % 2 else p for i, p in enumerate(parts))


def make_figures(res: Analysis, out: Path, target_v_m_s: float | None = None) -> tuple[list[Path], list[str]]:
    """Write the four figures; returns (paths written, notes on skipped figures)."""
    from analysis import figures
    from analysis.stats import valid_testing
    from analysis.traces import typical_taps

    paths = [figures.fig_ratings(res.summary, out / "fig_4_17_ratings.png"),
             figures.fig_pvalues(res.pairwise, res.study.catalog, out / "fig_4_18_pvalues.png"),
             figures.fig_penetration(res.summary, out / "fig_4_19_penetration.png")]
    notes = []
    dirs = dict(zip(res.study.subjects["subject"], map(Path, res.study.subjects["folder"])))
    taps, v, why = typical_taps(valid_testing(res.study), dirs, res.study.catalog, target_v_m_s)
    if taps:
        paths.append(figures.fig_accelerations(taps, res.study.catalog, v, out / "fig_4_20_accelerations.png"))
        if why:
            notes.append("Figure 4.20 lacks some samples: " + "; ".join(why[:12]))
    else:
        stale = out / "fig_4_20_accelerations.png"
        if stale.exists():
            stale.unlink()
        notes.append("Figure 4.20 skipped: no usable per-attempt traces (" + "; ".join(why[:3])
                     + ("; ..." if len(why) > 3 else "") + ").")
    return paths, notes


TABLE_TITLES = (
    ("Sample summary (sample_summary.csv)", "summary"),
    ("Repeated-measures ANOVA and Friedman test (anova.csv)", "anova"),
    ("Equivalence to the reference, paired TOST (equivalence.csv)", "equivalence"),
    ("Paired t-tests for every pair of samples (pairwise_ttests.csv)", "pairwise"),
    ("Incoming velocity vs rating (velocity_rating.csv)", "velocity"),
    ("Testing attempts per subject (attempts.csv)", "attempts"),
    ("Subjects excluded from some tests (exclusions.csv)", "exclusions"),
)


def write_report(res: Analysis, out_dir, figures: bool = True, target_v_m_s: float | None = None) -> dict:
    """Write tables, figures, ``report.md`` and a self-contained ``report.html`` into ``out_dir``.

    Returns a dict with ``tables``, ``figures`` (paths), ``notes`` and ``md``/``html`` paths.
    """
    from analysis.pipeline import write_tables
    out = Path(out_dir)
    tables = write_tables(res, out)
    fig_paths, notes = make_figures(res, out, target_v_m_s) if figures else ([], ["Figures not requested."])
    lines, pairs = summary_text(res, notes)
    cfg = res.config
    md = ["# Realism study analysis", "",
          f"Data: `{res.study.subjects['folder'].iloc[0].rsplit('/', 1)[0] if len(res.study.subjects) else ''}` · "
          f"reference `{cfg.reference}` · equivalence margin ±{cfg.margin:g} · groups `{cfg.group}` · "
          f"α = {cfg.alpha}", "", "## Summary", ""]
    md += [f"- {ln}" for ln in lines]
    md += ["", "## Significantly different pairs", ""]
    for g, items in pairs.items():
        md += [f"**{g} subjects** ({len(items)}):", ""] + [f"- {it}" for it in items] + [""]
    for p in fig_paths:
        md += [f"![{FIGURES[p.name]}]({p.name})", "", f"*{FIGURES[p.name]}*", ""]
    for title, attr in TABLE_TITLES:
        md += [f"## {title}", "", markdown_table(getattr(res, attr)) if len(getattr(res, attr)) else "(none)", ""]
    md_path = out / "report.md"
    md_path.write_text("\n".join(md) + "\n", encoding="utf-8")

    body = [f"<h1>Realism study analysis</h1><p>reference <code>{html.escape(cfg.reference)}</code> · margin "
            f"±{cfg.margin:g} · groups <code>{html.escape(cfg.group)}</code> · α = {cfg.alpha}</p><h2>Summary</h2><ul>"]
    for ln in lines:
        body.append(f"<li>{_strong(html.escape(ln))}</li>")
    body.append("</ul><h2>Significantly different pairs</h2>")
    for g, items in pairs.items():
        body.append(f"<details><summary>{html.escape(g)} subjects: {len(items)} pairs</summary><ul>"
                    + "".join(f"<li>{html.escape(it)}</li>" for it in items) + "</ul></details>")
    for p in fig_paths:
        data = base64.b64encode(p.read_bytes()).decode("ascii")
        body.append(f"<figure><img alt='{html.escape(p.name)}' src='data:image/png;base64,{data}'>"
                    f"<figcaption>{html.escape(FIGURES[p.name])}</figcaption></figure>")
    for title, attr in TABLE_TITLES:
        df = getattr(res, attr)
        body.append(f"<h2>{html.escape(title)}</h2>")
        body.append(df.to_html(index=False, float_format=lambda v: _fmt(v), na_rep="–", border=0)
                    if len(df) else "<p>(none)</p>")
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
             "table{border-collapse:collapse;font-size:12px}td,th{border:1px solid #ccc;padding:2px 6px;"
             "text-align:right}img{max-width:100%}figcaption{font-style:italic;font-size:13px}")
    html_path = out / "report.html"
    html_path.write_text("<!doctype html><html><head><meta charset='utf-8'><title>Realism study analysis</title>"
                         f"<style>{style}</style></head><body>{''.join(body)}</body></html>\n", encoding="utf-8")
    return {"tables": tables, "figures": fig_paths, "notes": notes, "md": md_path, "html": html_path}
