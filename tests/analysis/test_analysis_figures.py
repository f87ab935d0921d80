"""Figures 4.17-4.20 on the synthetic study: the colours and stars of Fig. 4.18 come from the same Holm
p-values, no legend overlaps anything, every axis label has a unit, each CSV holds what is plotted, and the
HTML report never overflows the page in headless Chromium."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

import figstyle
from analysis import figures as F
from analysis.stats import valid_testing
from analysis.traces import typical_taps

from tests.support.needs import chromium


@pytest.fixture(scope="module")
def built(analysed):
    dirs = dict(zip(analysed.study.subjects["subject"], map(Path, analysed.study.subjects["folder"])))
    taps, v, _ = typical_taps(valid_testing(analysed.study), dirs, analysed.study.catalog, 0.11)
    figs = {"4.17": F.build_ratings(analysed.summary),
            "4.18": F.build_pvalues(analysed.pairwise, analysed.study.catalog, 0.05),
            "4.19": F.build_penetration(analysed.summary),
            "4.20": F.build_accelerations(taps, analysed.study.catalog, v)}
    yield figs
    import matplotlib.pyplot as plt
    for fig, _ in figs.values():
        plt.close(fig)


@pytest.fixture(scope="module")
def written(analysed_report):
    """The report of ``analysed`` with every figure (written once per run: tests/analysis/conftest.py)."""
    return analysed_report["html"].parent, analysed_report


def _star_cells(ax) -> dict:
    """``{(row, col): stars}`` of the star marks drawn in a p-value panel of Fig. 4.18 (one collection of
    glyph paths per star count, gid ``stars_<group>_<count>``), each mark checked to be that many star glyphs."""
    from matplotlib.textpath import TextPath
    one = len(TextPath((0, 0), "*", size=5.5).vertices)
    cells = {}
    for coll in ax.collections:
        if not (coll.get_gid() or "").startswith("stars_"):
            continue
        n = int(coll.get_gid().rsplit("_", 1)[1])
        (path,) = coll.get_paths()
        assert len(path.vertices) == n * one            # the glyphs of n stars
        for x, y in coll.get_offsets():
            assert (round(y), round(x)) not in cells
            cells[(round(y), round(x))] = "*" * n
    return cells


def test_pvalue_colours_and_stars_from_the_same_holm_p(built, analysed):
    fig, data = built["4.18"]
    samples = list(analysed.study.catalog)
    k = len(samples)
    p_axes = [ax for ax in fig.axes if ax.get_title("left").endswith("Holm-adjusted p")]
    assert [ax.get_title("left").split(" ")[0] for ax in p_axes] == ["all", "experienced"]
    n_sig_total = 0
    for ax in p_axes:
        group = ax.get_title("left").split(" ")[0]
        sub = analysed.pairwise[analysed.pairwise["group"] == group]
        holm = np.full((k, k), np.nan)
        ia, ib = sub["sample_a"].map(samples.index).to_numpy(), sub["sample_b"].map(samples.index).to_numpy()
        holm[ia, ib] = holm[ib, ia] = sub["p_holm"].to_numpy()
        (im,) = ax.images
        shown = im.get_array()
        # the colour is the Holm p (not the uncorrected p), masked where there is no test
        np.testing.assert_array_equal(np.ma.getmaskarray(shown), np.isnan(holm))
        np.testing.assert_allclose(shown.filled(np.nan), np.log10(holm), rtol=0, atol=0)
        assert not np.allclose(shown.filled(np.nan)[ia, ib], np.log10(sub["p"].to_numpy()))
        drawn = _star_cells(ax)
        starred = set(drawn)
        sig = {(int(i), int(j)) for i, j in zip(*np.nonzero(holm < 0.05))}
        assert starred == sig and len(sig) > 0
        n_sig_total += len(sig)
        # every starred cell is on the significant (purple) side of the diverging scale, every other cell not
        side = im.norm(shown.filled(np.nan)) < 0.5
        for i, j in zip(*np.nonzero(~np.isnan(holm))):
            assert bool(side[i, j]) == ((int(i), int(j)) in sig), (group, samples[i], samples[j], holm[i, j])
        # the number of stars follows the same values
        for (i, j), text in drawn.items():
            assert text == F.stars(np.array([holm[i, j]]))[0]
    # some pairs are not significant, so the check above saw both sides of the scale
    assert n_sig_total < 2 * k * (k - 1)
    # the d_z panel holds the effect sizes of the same table (row minus column)
    dz_ax = [ax for ax in fig.axes if "d_z" in ax.get_title("left")][0]
    dz = dz_ax.images[0].get_array().filled(np.nan)
    row = analysed.pairwise[(analysed.pairwise["group"] == "all")].iloc[0]
    i, j = samples.index(row["sample_a"]), samples.index(row["sample_b"])
    assert dz[i, j] == pytest.approx(row["cohen_dz"]) and dz[j, i] == pytest.approx(-row["cohen_dz"])


def test_no_legend_overlaps_and_units_on_every_axis(built):
    for name, (fig, _) in built.items():
        assert figstyle.legend_overlaps(fig) == [], name
        assert figstyle.unlabelled_axes(fig) == [], name
        assert fig.legends or any(ax.get_legend() for ax in fig.axes), name


def test_overlap_check_finds_a_legend_over_data():
    """The checker itself: a legend placed over a line is reported, one outside the axes is not."""
    with figstyle.style() as plt:
        fig, ax = plt.subplots()
        ax.plot([0, 1], [0, 1], label="line")
        ax.plot([0, 1], [1, 0], label="other")
        ax.legend(loc="center")
        assert any("overlaps Line2D" in p for p in figstyle.legend_overlaps(fig))
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0))
        assert figstyle.legend_overlaps(fig) == []
        ax.set_xlabel("time")
        assert figstyle.unlabelled_axes(fig) == ["axes x: 'time'"]
        plt.close(fig)


def test_each_csv_reproduces_the_plotted_values(written, analysed):
    out, res = written
    for stem in ("fig_4_17_ratings", "fig_4_18_pvalues", "fig_4_19_penetration", "fig_4_20_accelerations"):
        for ext in ("png", "svg", "plot.csv"):
            assert (out / f"{stem}.{ext}").stat().st_size > 500, (stem, ext)
        assert (out / f"{stem}.svg").read_text()[:200].lstrip().startswith("<?xml")
    # 4.17: sorted by mean, CIs = t-intervals of the per-subject means (scipy)
    d = pd.read_csv(out / "fig_4_17_ratings.plot.csv")
    assert list(d["mean_rating"]) == sorted(d["mean_rating"], reverse=True)
    fig, data = F.build_ratings(analysed.summary)
    ax = fig.axes[0]
    means = [c.lines[0].get_xdata()[0] for c in ax.containers]
    np.testing.assert_allclose(means, d["mean_rating"], rtol=1e-8)
    lo = [c.lines[2][0].get_segments()[0][0][0] for c in ax.containers]
    np.testing.assert_allclose(lo, d["ci95_low_rating"], rtol=1e-8)
    j = analysed.matrix.samples.index(d["sample"].iloc[0])
    x = analysed.matrix.means[:, j]
    x = x[~np.isnan(x)]
    ci = stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=stats.sem(x))
    assert (d["ci95_low_rating"].iloc[0], d["ci95_high_rating"].iloc[0]) == pytest.approx(ci, rel=1e-9)
    assert [t.get_text() for t in ax.get_yticklabels()] == [figstyle.sample_style(s)["label"] for s in d["sample"]]
    # 4.18: the CSV's log10 p per cell equals the image
    d = pd.read_csv(out / "fig_4_18_pvalues.plot.csv")
    fig, _ = F.build_pvalues(analysed.pairwise, analysed.study.catalog)
    for ax in [a for a in fig.axes if a.get_title("left").endswith("Holm-adjusted p")]:
        g = ax.get_title("left").split(" ")[0]
        sub = d[d["group"] == g]
        img = ax.images[0].get_array().filled(np.nan)
        np.testing.assert_allclose(img[sub["row"], sub["col"]], sub["log10_p_holm"], rtol=1e-8, equal_nan=True)
        assert (sub["stars"].fillna("") == F.stars(sub["p_holm"].to_numpy())).all()
    # 4.19: points and error bars
    d = pd.read_csv(out / "fig_4_19_penetration.plot.csv")
    fig, _ = F.build_penetration(analysed.summary)
    pts = np.array([[c.lines[0].get_xdata()[0], c.lines[0].get_ydata()[0]] for c in fig.axes[0].containers])
    np.testing.assert_allclose(pts, d[["mean_rating", "penetration_mean_mm"]].to_numpy(), rtol=1e-8)
    np.testing.assert_allclose(d["penetration_mean_mm"], analysed.summary["penetration_mean_m"] * 1e3, rtol=1e-8)
    # 4.20: every panel's line is the CSV's rows of that sample
    d = pd.read_csv(out / "fig_4_20_accelerations.plot.csv")
    dirs = dict(zip(analysed.study.subjects["subject"], map(Path, analysed.study.subjects["folder"])))
    taps, v, _ = typical_taps(valid_testing(analysed.study), dirs, analysed.study.catalog, None)
    fig, _ = F.build_accelerations(taps, analysed.study.catalog, v)
    panels = [ax for ax in fig.axes if ax.lines]
    assert len(panels) == d["panel"].nunique() == len(taps)
    lims = []
    for p, ax in enumerate(panels):
        rows = d[d["panel"] == p]
        line = ax.lines[0]
        np.testing.assert_allclose(line.get_xdata(), rows["t_ms"], rtol=1e-6)
        np.testing.assert_allclose(line.get_ydata(), rows["accel_m_s2"], rtol=1e-6)
        assert ax.get_xlim() == F.WINDOW_MS and ax.lines[1].get_xdata()[0] == 0.0   # contact marked at t = 0
        lims.append(ax.get_ylim()[1])
        assert ax.get_ylim()[1] == pytest.approx(1.1 * np.abs(rows["accel_m_s2"]).max())
    assert max(lims) / min(lims) > 5     # per-panel scales: foam and wood differ by far more than 5x


def test_same_colour_for_a_sample_in_every_figure(built):
    wood = figstyle.color("wood")
    fig17, _ = built["4.17"]
    fig19, _ = built["4.19"]
    fig20, _ = built["4.20"]
    c17 = [c.lines[0].get_color() for c in fig17.axes[0].containers]
    assert wood in c17
    assert fig19.axes[0].containers[0].lines[0].get_color() == wood
    assert [ax for ax in fig20.axes if ax.lines][0].lines[0].get_color() == wood
    colours = [figstyle.color(s) for s in figstyle.palette()["samples"]]
    assert len(set(colours)) == len(colours)      # one colour per sample/rendering


def test_report_has_no_horizontal_overflow_in_chromium(written):
    from playwright.sync_api import sync_playwright
    out, res = written
    html = res["html"].read_text()
    assert "@media print" in html and "class='table-wrap'" in html and "Provenance" in html
    assert "session seeds" in html and "numpy " in html
    exe = chromium()
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, args=[
            "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
            "--disable-sync", "--no-first-run"])
        try:
            results = {}
            for width in (390, 1280):
                page = browser.new_page(viewport={"width": width, "height": 900})
                page.goto(res["html"].as_uri())
                results[width] = page.evaluate("""() => ({
                    doc: document.documentElement.scrollWidth, view: window.innerWidth,
                    widest: Math.max(...[...document.body.querySelectorAll('*')].map(
                        e => e.closest('.table-wrap') && e !== e.closest('.table-wrap') ? 0 :
                             e.getBoundingClientRect().right)),
                    tables: [...document.querySelectorAll('table')].map(
                        t => [t.closest('.table-wrap') ? 1 : 0, t.scrollWidth]),
                    imgs: [...document.images].map(i => i.getBoundingClientRect().width),
                    captions: document.querySelectorAll('figure figcaption').length})""")
                page.emulate_media(media="print")
                results[(width, "print")] = page.evaluate("document.documentElement.scrollWidth")
                page.close()
        finally:
            browser.close()
    for width in (390, 1280):
        r = results[width]
        assert r["doc"] <= r["view"] == width, (width, r["doc"])
        assert r["widest"] <= width + 0.5, (width, r["widest"])
        assert all(wrapped for wrapped, _ in r["tables"]) and len(r["tables"]) >= 7
        assert r["captions"] == 5 and max(r["imgs"]) <= width      # 4.17-4.20 and the ordinal model's (issue 35)
    # the pairwise table is wider than a phone: it scrolls inside its box instead of widening the page
    assert max(w for _, w in results[390]["tables"]) > 390


def test_figstyle_is_a_leaf_package():
    """figstyle imports no project package, so every package may use it without a new arrow."""
    import subprocess
    import sys
    code = ("import sys, figstyle, figstyle.gallery\n"
            "bad = [m for m in ('devices', 'renderer', 'stimuli', 'study', 'analysis') if m in sys.modules]\n"
            "assert not bad, bad\n")
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert figstyle.figsize("column")[0] == 3.5 and figstyle.figsize("slide")[0] == 10.0
    with figstyle.style("slide") as plt:
        assert plt.rcParams["font.size"] == pytest.approx(8 * figstyle.SLIDE_FONT_SCALE)


def test_figure_4_17_says_where_a_ci_runs_past_the_scale():
    """A t-interval of few subjects past 7 (or below 1) is drawn to the scale's end with an arrowhead and a
    legend entry, and flagged in the CSV, instead of being cut at the axis silently."""
    summary = pd.DataFrame({"sample": ["real_wood", "hfam_firm", "pulse_firm"], "mean_rating": [6.6, 4.0, 1.4],
                            "median_rating": [7.0, 4.0, 1.0], "ci95_low_rating": [5.9, 3.1, 0.2],
                            "ci95_high_rating": [7.6, 4.9, 2.6], "n_subjects": [3, 3, 3]})
    fig, data = F.build_ratings(summary)
    try:
        assert list(data["ci_cut_at_scale"]) == [True, False, True]
        ax = fig.axes[0]
        cut = [ln for ln in ax.lines if ln.get_marker() in (">", "<")]
        assert sorted((ln.get_marker(), tuple(ln.get_xdata())) for ln in cut) == [("<", (1.0,)), (">", (7.0,))]
        legend = [t.get_text() for t in ax.get_legend().get_texts()]
        assert "CI cut at the scale's end" in legend
        assert figstyle.text_problems(fig, tight=True) == [] and figstyle.legend_overlaps(fig) == []
    finally:
        import matplotlib.pyplot as plt
        plt.close(fig)
