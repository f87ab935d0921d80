"""The study report: tables, figures, report.md and report.html (command: :mod:`analysis.cli_report`)."""

from __future__ import annotations

import base64
import html
import json
import os
import platform
import re
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from analysis import figures, ranking, report_models, workers
from analysis.failures import attempt
from analysis.load import catalog_labels
from analysis.pipeline import write_tables
from analysis.stats import valid_testing_mask
from analysis.traces import folders_with_traces, typical_taps
from plumbing.textsafe import md_escape

if TYPE_CHECKING:  # the heavy imports wait until a report is made, so --help stays fast
    import pandas as pd

    from analysis.load import Study
    from analysis.pipeline import Analysis

FIGURES = {
    "fig_4_17_ratings.png": "Figure 4.17: mean realism rating per sample with its 95 % confidence interval "
                            "(t-interval over the per-subject means) and the median (bar), sorted from most to "
                            "least realistic. Look at which intervals overlap: samples whose intervals are far "
                            "apart differ; the colours are the samples' colours in every figure.",
    "fig_4_18_pvalues.png": "Figure 4.18: paired t-tests on the per-subject mean ratings for every pair of samples. "
                            "Left: Holm-adjusted p-values (Holm correction across the pairs of each group), "
                            "coloured on a log scale that turns from orange to purple at p = α; the stars come from "
                            "the same Holm-adjusted values (* < α, ** < 0.01, *** < 0.001), so every purple cell "
                            "has a star. Right: the effect size Cohen's d_z of row minus column (red: the row's "
                            "sample rated higher). Hatched cells have no test: a sample missing, fewer than 3 subjects, or every "
                            "subject giving the same difference (SD 0, not testable). The JZS Bayes factor BF10 of each "
                            "pair (Rouder et al. 2009, r = 0.707: above 3 evidence for a difference, below 1/3 "
                            "for none) is in the figure's CSV, in pairwise_ttests.csv beside p, and in the BF10 "
                            "matrix of 'Evidence for no difference' (hover a cell).",
    "fig_4_19_penetration.png": "Figure 4.19: mean penetration depth of the taps versus mean realism rating per "
                                "sample; error bars ±1 standard deviation (taps vertically, attempts' ratings "
                                "horizontally). Look for samples that penetrate little yet rate low: stiffness "
                                "alone does not make a surface feel real.",
    "fig_4_20_accelerations.png": "Figure 4.20: typical handle acceleration per sample for the tap whose incoming "
                                  "velocity is nearest a common value, from the saved traces. Every panel has its "
                                  "own vertical scale (compare shapes and decay, read magnitudes off the axes) and "
                                  "the same time window; the dashed line marks the contact instant.",
}


# a name from the data (sample, subject) in a summary line: kept as a marked field until the line is
# written, then escaped for its format (markdown: md_escape; HTML: html.escape), so a name cannot add
# emphasis, links, table cells or tags to report.md
_NAME_OPEN, _NAME_CLOSE = "\x02", "\x03"
_NAME_RE = re.compile("\x02([^\x02\x03]*)\x03")


def _name(value) -> str:
    """Mark a name from the data inside a summary line (escaped when the line is written)."""
    return f"{_NAME_OPEN}{value}{_NAME_CLOSE}"


def _names_md(line: str) -> str:
    return _NAME_RE.sub(lambda m: md_escape(m.group(1)), line)


def _names_plain(line: str) -> str:
    return _NAME_RE.sub(lambda m: m.group(1), line)


def _html_line(line: str) -> str:
    """A summary line as HTML: escaped, ``**x**`` as bold, a name's own ``*`` never read as bold."""
    text = _NAME_RE.sub(lambda m: m.group(1).replace("*", "\x04"), line)
    return _strong(html.escape(text)).replace("\x04", "&#42;")


def _fmt(v) -> str:
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
    head = "| " + " | ".join(md_escape(c) for c in df.columns) + " |"
    sep = "|" + "|".join("---" for _ in df.columns) + "|"
    body = ["| " + " | ".join(md_escape(_fmt(v)) for v in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join([head, sep, *body])


def _p(p: float) -> str:
    return "p < 0.001" if p < 1e-3 else f"p = {p:.3f}"


def summary_text(res: Analysis, fig_notes: list[str]) -> tuple[list[str], dict]:
    """Plain-language findings: omnibus, equivalence, significant pairs, velocity, exclusions.

    Returns the summary lines (markdown emphasis with ``**``) and, per group, one line per
    significantly different pair. Each finding is its own part: a table that could not be computed
    (``res.failures``) is said in its place, and a line that cannot be written says why (the others are
    still written; analysis.failures).
    """
    cfg, out, pairs = res.config, [], {}

    def block(attr, what, fn):
        for reason in res.failures.get(attr, ()):
            out.append(f"**{what}**: {reason}.")
        problems = []
        attempt("its summary", problems, fn, failed="not written")
        out.extend(f"**{what}**: {p}." for p in problems)

    def subjects():
        subj = res.study.subjects
        exp_counts = subj["experience"].value_counts()
        experience_words = {"none": "never used a haptic device", "few": "used one a few times",
                            "regular": "use one regularly"}
        out.append(f"{len(subj)} subjects ({', '.join(f'{n} {experience_words.get(e, e)}' for e, n in exp_counts.items())}); "
                   f"{len(res.study.catalog)} samples; {int(res.matrix.counts.sum())} valid testing attempts analysed.")

    def omnibus():
        for g, sub in res.anova.groupby("group", sort=False):
            a, f = sub[sub["test"] == "rm_anova"], sub[sub["test"] == "friedman"]
            if not len(a) or not np.isfinite(a.iloc[0]["statistic"]):
                out.append(f"**{g}**: not enough complete subjects for the omnibus tests (every sample rated by 2 or "
                           "more subjects, and ratings that vary)." if not len(a) or a.iloc[0]["n_subjects"] < 2 else
                           f"**{g}**: the omnibus tests give no result: the ratings do not vary between or within "
                           "the samples beyond a constant.")
                continue
            a, f = a.iloc[0], f.iloc[0]
            verdict = "differ significantly" if a["p_gg"] < cfg.alpha else "do not differ significantly"
            out.append(f"**{g} subjects** (n = {a['n_subjects']}): ratings {verdict} between samples "
                       f"(repeated-measures ANOVA F({a['df1']:.0f}, {a['df2']:.0f}) = {a['statistic']:.2f}, "
                       f"Greenhouse–Geisser ε = {a['epsilon_gg']:.2f}, corrected {_p(a['p_gg'])}; "
                       f"Friedman χ²({f['df1']:.0f}) = {f['statistic']:.1f}, {_p(f['p'])}).")

    def equivalence():
        for g, sub in res.equivalence.groupby("group", sort=False):
            eq = sub[sub["equivalent"].astype(bool)]["sample"].tolist()
            out.append(f"**{g} subjects**: equivalent to {_name(cfg.reference)} within ±{cfg.margin:g} rating points "
                       f"(paired TOST, p < {cfg.alpha}): {', '.join(map(_name, eq)) if eq else 'none'}. Samples not "
                       "shown equivalent are not thereby shown different; that may just be too few subjects.")

    def pairwise():
        for g, sub in res.pairwise.groupby("group", sort=False):
            sig = sub[sub["p_holm"] < cfg.alpha]
            untestable = sub[sub["not_testable"].astype(bool)] if "not_testable" in sub else sub.iloc[:0]
            out.append(f"**{g} subjects**: {len(sig)} of {len(sub) - len(untestable)} testable sample pairs differ "
                       f"significantly (paired t-test, Holm-adjusted p < {cfg.alpha}; listed under 'Significantly "
                       "different pairs')."
                       + (f" {len(untestable)} pair(s) not testable (fewer than 3 subjects rated both, or every "
                          "subject gave the same difference, SD 0): never counted as significant; hatched in "
                          "Figure 4.18." if len(untestable) else ""))
            pairs[g] = []
            for r in sig.itertuples():
                hi, lo = (_name(r.sample_a), _name(r.sample_b)) if r.mean_diff > 0 else (_name(r.sample_b),
                                                                                       _name(r.sample_a))
                pairs[g].append(f"{hi} rated higher than {lo} by {abs(r.mean_diff):.2f} points "
                                f"(95 % CI {abs(r.ci_low if r.mean_diff > 0 else r.ci_high):.2f}–"
                                f"{abs(r.ci_high if r.mean_diff > 0 else r.ci_low):.2f}, n = {r.n}, "
                                f"Holm {_p(r.p_holm)})")

    def velocity():
        vr = res.velocity[res.velocity["sample"] != "(all)"]
        sig_v = vr[vr["p"] < cfg.alpha]["sample"].tolist()
        whole = res.velocity[res.velocity["sample"] == "(all)"]
        rm = whole.iloc[0] if len(whole) else None
        out.append("Incoming velocity vs rating within each sample (Pearson, uncorrected): "
                   + (f"significant for {', '.join(map(_name, sig_v))}." if sig_v else "no significant correlation.")
                   + " Repeated-measures correlation over all samples: "
                   + (f"r = {rm['r_rm']:.2f}, {_p(rm['p_rm'])}." if rm is not None and np.isfinite(rm["r_rm"])
                      else "not computable (no velocity that varies within a subject's samples)."))

    def attempts():
        att = res.attempts
        inv = int((att["attempts"] - att["valid"]).sum())
        out.append(f"**Excluded attempts**: {inv} invalid testing attempts were left out (saturated "
                   f"{int(att['saturated'].sum())}, rejected {int(att['rejected'].sum())}, overpowered "
                   f"{int(att['overpowered'].sum())}, other {int(att['invalid_other'].sum())}); each was redrawn, so "
                   "its sample was rated again later.")

    def exclusions():
        if len(res.exclusions):
            out.append("**Excluded subjects**: " + "; ".join(
                f"{_name(r.subject)} misses {', '.join(map(_name, r.missing_samples.split(';')))} and is left out of "
                "the RM-ANOVA/Friedman "
                f"tests and of the pairwise/equivalence tests with those samples" for r in res.exclusions.itertuples())
                       + ".")
        else:
            out.append("**Excluded subjects**: none; every subject rated every sample.")

    block("subjects", "Subjects", subjects)
    block("anova", "RM-ANOVA and Friedman test", omnibus)
    block("equivalence", "Equivalence tests", equivalence)
    block("pairwise", "Paired t-tests", pairwise)
    block("velocity", "Velocity-rating correlations", velocity)
    block("attempts", "Attempt counts", attempts)
    block("exclusions", "Exclusions", exclusions)
    for reason in res.failures.get("summary", ()):
        out.append(f"**Sample summary**: {reason} (Figures 4.17 and 4.19 need it).")
    for w in res.warnings:
        out.append(f"Warning: {w}")
    out.extend(fig_notes)
    return out, pairs


def _strong(text: str) -> str:
    """Markdown ``**x**`` -> ``<strong>x</strong>`` (text already HTML-escaped)."""
    parts = text.split("**")
    return "".join(f"<strong>{p}</strong>" if i % 2 else p for i, p in enumerate(parts))


def make_figures(res: Analysis, out: Path, target_v_m_s: float | None = None,
                 pool=None, accelerations=None) -> tuple[list[Path], list[str]]:
    """Write the four figures (PNG, SVG and CSV each); returns (PNG paths written, notes on skipped figures).

    ``pool``: an executor with a second process (:func:`analysis.cli_report.figure_process`) that draws
    Figures 4.20 and 4.19 while this process draws 4.18 and 4.17 (each figure costs the same at any
    number of subjects, ~0.2-1 s of matplotlib; the two halves take about as long); None draws all four
    here, in turn. A figure whose process died is drawn here. ``accelerations``: Figure 4.20 as begun
    by :func:`start_accelerations` (with ``pool``, once the study was loaded), else begun here.
    """
    alpha = res.config.alpha
    labels = catalog_labels(res.study)   # the catalog's own labels ("HFAM, my library, firm"), not "hfam mine"
    ratings = (figures.fig_ratings, res.summary, out / "fig_4_17_ratings.png", labels)
    pvalues = (figures.fig_pvalues, res.pairwise, res.study.catalog, out / "fig_4_18_pvalues.png", alpha, labels)
    penetration = (figures.fig_penetration, res.summary, out / "fig_4_19_penetration.png", labels)
    notes: list[str] = []
    if pool is None:
        acc, acc_notes = attempt_figure(out / "fig_4_20_accelerations.png", notes, start_accelerations,
                                         res.study, out, target_v_m_s) or (None, [])
        jobs = [(None, ratings), (None, pvalues), (None, penetration)] + ([acc] if acc else [])
    else:
        acc, acc_notes = accelerations if accelerations is not None else \
            (attempt_figure(out / "fig_4_20_accelerations.png", notes, start_accelerations, res.study, out,
                             target_v_m_s, pool) or (None, []))
        there = workers.submit(pool, *penetration)          # queued behind Figure 4.20
        jobs = [(None, ratings), (None, pvalues), (there, penetration)] + ([acc] if acc else [])
    written = []
    for future, job in jobs:
        # each figure fails alone: its note says why, the others and the tables are still written
        png = next(a for a in job if isinstance(a, Path) and a.suffix == ".png")
        got = attempt_figure(png, notes, _finish, future, job)
        if got is not None:
            written.append(got["png"])
    return written, acc_notes + notes


def _figure_name(png: Path) -> str:
    """"Figure 4.17" for ``fig_4_17_ratings.png``; the caption's first words otherwise."""
    return FIGURES.get(Path(png).name, Path(png).stem).split(":")[0]


def attempt_figure(png: Path, notes: list, fn, *args):
    """``fn(*args)``, or None with "<figure> not drawn: <reason>" in ``notes`` and its partly written files removed."""
    problems: list[str] = []
    got = attempt(_figure_name(png), problems, fn, *args, failed="not drawn")
    if problems:
        notes.extend(p + "." for p in problems)
        for ext in (".png", ".svg", ".plot.csv", ".csv"):
            stale = Path(png).with_suffix(ext)
            if stale.exists():
                stale.unlink()
    return got


def _finish(future, job: tuple) -> dict:
    """The paths a figure job returns: ``future``'s result, or ``job`` run here without a future or when
    the process drawing it died."""
    got = workers.result(future)
    if got is None:
        fn, *args = job
        got = fn(*args)
    return got


def list_traces(folders: list, pool):
    """The subject folders that hold traces (:func:`analysis.traces.folders_with_traces`), listed in
    ``pool``'s process (idle while the study loads): a future for :func:`start_accelerations`, or None
    without a pool."""
    return workers.submit(pool, folders_with_traces, folders)


def start_accelerations(study: Study, out: Path, target_v_m_s: float | None = None,
                        pool=None, traced=None) -> tuple[tuple | None, list[str]]:
    """Begin Figure 4.20: the typical taps are read from the traces here and the figure is submitted to
    ``pool`` (without one, :func:`make_figures` draws it here). ``traced``: the future of
    :func:`list_traces` for the study's folders, or None (they are listed here).

    Returns
    -------
    pending : (future or None, job) or None
        The drawing and the job that draws it (:func:`_finish` gives its paths); None when no trace
        gives a tap (stale files of an earlier report removed).
    notes : list of str
        Why the figure lacks samples or was skipped.
    """
    notes = []
    dirs = dict(zip(study.subjects["subject"], study.subjects["folder"]))     # folder paths as str
    t = study.trials
    sel = valid_testing_mask(t)
    values, row = study.taps["incoming_velocities_m_s"]
    keep = sel[row]
    # the velocities parsed at loading, re-indexed to the valid testing rows (no second parse), and of
    # those rows only the columns that locate a trace (not the lists as text)
    velocities = (values[keep], (np.cumsum(sel) - 1)[row[keep]])
    rows = t.loc[sel, ["subject", "phase", "trial", "attempt", "sample"]]
    if traced is not None:
        traced = _finish(traced, (folders_with_traces, list(dirs.values())))
    taps, v, why = typical_taps(rows, dirs, study.catalog, target_v_m_s, velocities=velocities, traced=traced)
    if not taps:
        for ext in ("png", "svg", "csv"):
            stale = out / f"fig_4_20_accelerations.{ext}"
            if stale.exists():
                stale.unlink()
        notes.append("Figure 4.20 skipped: no usable per-attempt traces (" + "; ".join(why[:3])
                     + ("; ..." if len(why) > 3 else "") + ").")
        return None, notes
    if why:
        notes.append("Figure 4.20 lacks some samples: " + "; ".join(why[:12]))
    job = (figures.fig_accelerations, taps, study.catalog, v, out / "fig_4_20_accelerations.png", catalog_labels(study))
    return (workers.submit(pool, *job), job), notes


def provenance(res: Analysis, out: Path) -> list[tuple[str, str]]:
    """(label, value) rows of the report's provenance: versions, seeds, folders, settings."""
    subj = res.study.subjects
    versions = []
    for dist in ("hfam-haptics", "numpy", "scipy", "pandas", "statsmodels", "matplotlib"):
        try:
            versions.append(f"{dist} {metadata.version(dist)}")
        except metadata.PackageNotFoundError:
            versions.append(f"{dist} (not installed)")
    # the parents as strings first (one Path per distinct parent, not per subject)
    folders = sorted({str(Path(d)) for d in {os.path.dirname(f) for f in subj["folder"]}}) if len(subj) else []
    seeds = [str(s) for s in subj.get("seed", []) if s is not None]
    seed_text = (", ".join(seeds) if len(seeds) <= 12 else f"{', '.join(seeds[:6])}, … {', '.join(seeds[-3:])}"
                 f" ({len(seeds)} sessions)") if seeds else "none recorded"
    soft = sorted({str(v) for v in subj.get("software_version", []) if v is not None})
    devices = sorted({str(v) for v in subj.get("device", []) if v is not None})
    timing = [f"{s}: {t}" for s, t in zip(subj.get("subject", []), subj.get("servo_timing", []))]
    timing_text = "; ".join(timing) if len(timing) <= 12 else (
        f"{sum(t.split(': ', 1)[1].startswith('met') for t in timing)} of {len(timing)} sessions met them; "
        + "; ".join(t for t in timing if ": NOT met" in t)[:2000])
    cfg = res.config
    return [
        ("data folder", ", ".join(folders)),
        ("report folder", str(out.resolve())),
        ("subjects", f"{len(subj)} ({subj['subject'].iloc[0]} … {subj['subject'].iloc[-1]})" if len(subj) else "0"),
        ("session seeds", seed_text),
        ("study software", ", ".join(soft) or "not recorded"),
        ("devices", ", ".join(devices) or "not recorded"),
        # whether each session's servo met p99 <= 20 us, p99.9 <= 50 us, no period > 1 ms (+ link)
        ("servo timing", timing_text or "not recorded"),
        ("analysis settings", f"reference {cfg.reference}, margin ±{cfg.margin:g}, groups {cfg.group}, "
                              f"α = {cfg.alpha}, Holm correction across the pairs of each group"),
        ("software", f"Python {platform.python_version()}, " + ", ".join(versions)),
    ]


REPORT_CSS = """
*,*::before,*::after{box-sizing:border-box}
html{-webkit-text-size-adjust:100%}
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;line-height:1.45;color:#222;margin:0 auto;
     padding:1rem;max-width:72rem;overflow-wrap:anywhere}
h1{font-size:1.6rem}h2{font-size:1.2rem;margin-top:2rem}
code{overflow-wrap:anywhere}
.table-wrap{max-width:100%;overflow-x:auto;-webkit-overflow-scrolling:touch;border:1px solid #ddd;margin:.5rem 0}
table{border-collapse:collapse;font-size:.8rem;font-variant-numeric:tabular-nums}
td,th{border-bottom:1px solid #e4e4e4;padding:.2rem .5rem;text-align:right;white-space:nowrap}
th{background:#f3f3f3;position:sticky;top:0}
td:first-child,th:first-child{text-align:left}
table.prov td{white-space:normal;text-align:left;overflow-wrap:anywhere}
figure{margin:1.5rem 0}figure img{display:block;max-width:100%;height:auto}
figcaption{font-size:.9rem;color:#333;margin-top:.4rem}
details{margin:.5rem 0}
@media print{
  body{max-width:none;padding:0;font-size:10pt;color:#000}
  .table-wrap{overflow:visible;border:0}
  table{font-size:7pt}td,th{white-space:normal;padding:1pt 3pt}
  th{position:static}
  figure,table,tr{break-inside:avoid}
  h2{break-after:avoid}
  details>*{display:block}
  a{color:#000;text-decoration:none}
}
"""


# tables longer than this show their first rows in report.md/.html (the CSV has them all): a
# per-subject table of 10,000 subjects would make the report megabytes long and slow to write
REPORT_MAX_ROWS = 200


def _shown(df, csv_name: str):
    """``(rows shown, note)``: the first :data:`REPORT_MAX_ROWS` rows and a note naming the CSV."""
    if len(df) <= REPORT_MAX_ROWS:
        return df, ""
    return df.head(REPORT_MAX_ROWS), f"First {REPORT_MAX_ROWS} of {len(df)} rows; all of them are in {csv_name}."


def _table_html(df, csv_name: str = "") -> str:
    if not len(df):
        return "<p>(none)</p>"
    df, note = _shown(df, csv_name)
    return ("<div class='table-wrap'>" + df.to_html(index=False, float_format=lambda v: _fmt(v), na_rep="–",
                                                     border=0) + "</div>" + (f"<p>{html.escape(note)}</p>" if note
                                                                             else ""))


def report_html(res: Analysis, lines: list[str], pairs: dict, fig_paths: list[Path],
                prov: list[tuple[str, str]], sections: list | None = None) -> str:
    """The self-contained ``report.html``: summary, pairs, the models' sections (``sections``:
    :func:`analysis.report_models.sections`, "Models" and "Evidence for no difference"), captioned figures
    (embedded PNG), tables, provenance; responsive (tables scroll inside their box, never the page) with a
    print stylesheet."""
    cfg = res.config
    body = [f"<h1>Realism study analysis</h1><p>reference <code>{html.escape(cfg.reference)}</code> · margin "
            f"±{cfg.margin:g} · groups <code>{html.escape(cfg.group)}</code> · α = {cfg.alpha}</p><h2>Summary</h2><ul>"]
    for ln in lines:
        body.append(f"<li>{_html_line(ln)}</li>")
    body.append("</ul><h2>Significantly different pairs</h2>")
    for g, items in pairs.items():
        body.append(f"<details><summary>{html.escape(g)} subjects: {len(items)} pairs</summary><ul>"
                    + "".join(f"<li>{_html_line(it)}</li>" for it in items) + "</ul></details>")
    for sec in sections or ():
        body.append(_section_html(sec))
    if fig_paths:
        body.append("<h2>Figures</h2>")
    for p in fig_paths:
        data = base64.b64encode(p.read_bytes()).decode("ascii")
        body.append(f"<figure><img alt='{html.escape(FIGURES[p.name].split(':')[0])}' "
                    f"src='data:image/png;base64,{data}'><figcaption>{html.escape(FIGURES[p.name])} "
                    f"Data: <code>{html.escape(p.with_suffix('.csv').name)}</code>, vector: "
                    f"<code>{html.escape(p.with_suffix('.svg').name)}</code>.</figcaption></figure>")
    for title, attr in TABLE_TITLES:
        body.append(f"<h2>{html.escape(title)}</h2>")
        body.append(_table_html(getattr(res, attr), _csv_name(title)))
    body.append("<h2>Provenance</h2><div class='table-wrap'><table class='prov'><tbody>"
                + "".join(f"<tr><th scope='row'>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in prov)
                + "</tbody></table></div>")
    return ("<!doctype html><html lang='en'><head><meta charset='utf-8'>"
            "<meta name='viewport' content='width=device-width, initial-scale=1'>"
            f"<title>Realism study analysis</title><style>{REPORT_CSS}</style></head><body>{''.join(body)}"
            "</body></html>\n")


def _section_html(sec) -> str:
    """One :class:`analysis.report_models.Section` as HTML: its lines, figures (embedded PNG), tables, extra HTML."""
    parts = [f"<h2>{html.escape(sec.title)}</h2><ul>"] + [f"<li>{_html_line(ln)}</li>" for ln in sec.lines]
    parts.append("</ul>")
    for path, caption in sec.figures:
        data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
        parts.append(f"<figure><img alt='{html.escape(caption.split(':')[0])}' src='data:image/png;base64,{data}'>"
                     f"<figcaption>{html.escape(caption)} Data: <code>{html.escape(Path(path).with_suffix('.plot.csv').name)}"
                     "</code>.</figcaption></figure>")
    parts.append(sec.html_extra)
    for title, df in sec.tables:
        parts.append(f"<h3>{html.escape(title)}</h3>" + _table_html(df, _csv_name(title)))
    return "".join(parts)


def _section_md(sec) -> list[str]:
    """One :class:`analysis.report_models.Section` as markdown lines (figures linked, tables in full up to the cap)."""
    md = [f"## {sec.title}", ""] + [f"- {_names_md(ln)}" for ln in sec.lines] + [""]
    for path, caption in sec.figures:
        md += [f"![{caption.split(':')[0]}]({Path(path).name})", "", f"*{caption}*", ""]
    for title, df in sec.tables:
        shown, note = _shown(df, _csv_name(title))
        md += [f"### {title}", "", markdown_table(shown) if len(df) else "(none)", ""] + ([note, ""] if note else [])
    return md


def _csv_name(title: str) -> str:
    return title.rsplit("(", 1)[-1].rstrip(")") if title.endswith(")") else "the CSV"


TABLE_TITLES = (
    ("Sample summary (sample_summary.csv)", "summary"),
    ("Repeated-measures ANOVA and Friedman test (anova.csv)", "anova"),
    ("Equivalence to the reference, paired TOST (equivalence.csv)", "equivalence"),
    ("Paired t-tests for every pair of samples (pairwise_ttests.csv)", "pairwise"),
    ("Incoming velocity vs rating (velocity_rating.csv)", "velocity"),
    ("Testing attempts per subject (attempts.csv)", "attempts"),
    ("Subjects excluded from some tests (exclusions.csv)", "exclusions"),
)


def write_report(res: Analysis, out_dir, figures: bool = True, target_v_m_s: float | None = None,
                 pool=None, accelerations=None, final_dir=None) -> dict:
    """Write tables, figures, ``report.md`` and a self-contained ``report.html`` into ``out_dir``.

    ``pool``, ``accelerations``: see :func:`make_figures`. ``final_dir``: the folder the report will be
    found in, named in its provenance (``out_dir`` is then the staging folder swapped in as it later). Returns a dict
    with ``tables``, ``figures`` (the PNG of every figure written, the sections' figures included), ``notes`` and
    ``md``/``html`` paths.
    """
    out = Path(out_dir)
    tables = write_tables(res, out)
    fig_paths, notes = make_figures(res, out, target_v_m_s, pool, accelerations) if figures else \
        ([], ["Figures not requested."])
    lines, pairs = summary_text(res, notes)
    # Figure 4.17's ordering and section 4.5.4's saturations, as yes/no lines and ranking.json
    marked = ranking.figure_4_17_checks(res.summary, res.study.trials, _name)
    lines += ranking.ranking_lines(marked, _name)
    # ranking.json: the same checks, computed once, their texts with the names unmarked
    checks = {k: {**v, "text": _names_plain(v["text"])} if isinstance(v, dict) and "text" in v else v
              for k, v in marked.items()}
    (out / "ranking.json").write_text(json.dumps(checks, indent=1, default=str) + "\n", encoding="utf-8")
    sections = report_models.sections(res, out, draw=figures)
    cfg = res.config
    md = ["# Realism study analysis", "",
          f"Data: `{res.study.subjects['folder'].iloc[0].rsplit('/', 1)[0] if len(res.study.subjects) else ''}` · "
          f"reference `{cfg.reference}` · equivalence margin ±{cfg.margin:g} · groups `{cfg.group}` · "
          f"α = {cfg.alpha}", "", "## Summary", ""]
    md += [f"- {_names_md(ln)}" for ln in lines]
    md += ["", "## Significantly different pairs", ""]
    for g, items in pairs.items():
        md += [f"**{md_escape(g)} subjects** ({len(items)}):", ""] + [f"- {_names_md(it)}" for it in items] + [""]
    for sec in sections:
        md += _section_md(sec)
    for p in fig_paths:
        md += [f"![{FIGURES[p.name].split(':')[0]}]({p.name})", "", f"*{FIGURES[p.name]}*", ""]
    for title, attr in TABLE_TITLES:
        df = getattr(res, attr)
        shown, note = _shown(df, _csv_name(title))
        md += [f"## {title}", "", markdown_table(shown) if len(df) else "(none)", ""] + ([note, ""] if note else [])
    md_path = out / "report.md"
    prov = provenance(res, Path(final_dir) if final_dir is not None else out)
    md += ["## Provenance", "", "| item | value |", "|---|---|"] + [f"| {md_escape(k)} | {md_escape(v)} |"
                                                                    for k, v in prov] + [""]
    md_path.write_text("\n".join(md) + "\n", encoding="utf-8")
    html_path = out / "report.html"
    html_path.write_text(report_html(res, lines, pairs, fig_paths, prov, sections), encoding="utf-8")
    # in the report's order: the sections' figures come before Figures 4.17-4.20
    every_figure = [Path(png) for sec in sections for png, _ in sec.figures] + list(fig_paths)
    return {"tables": tables, "figures": every_figure, "notes": notes, "md": md_path, "html": html_path}
