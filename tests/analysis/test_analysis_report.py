"""``python -m analysis report``: tables, figures with real content, report.md and self-contained report.html."""

from __future__ import annotations

import base64
import io
import json
import re
import subprocess
import sys
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pandas as pd
import pytest

from analysis import ranking
from analysis.__main__ import main

ROOT = Path(__file__).resolve().parents[2]


def _pixels_vary(png: Path) -> float:
    img = mpimg.imread(png)
    assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 200
    return float(img[..., :3].std())


@pytest.fixture(scope="module")
def report(study_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    proc = subprocess.run([sys.executable, "-m", "analysis", "report", str(study_dir), "--out", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return out, proc


def test_tables_written_with_issue_columns(report):
    out, _ = report
    pw = pd.read_csv(out / "pairwise_ttests.csv")
    assert list(pw.columns) == ["group", "sample_a", "sample_b", "n", "mean_diff", "t", "df", "p", "p_holm",
                                "bf10", "ci_low", "ci_high", "cohen_dz", "wilcoxon_w", "wilcoxon_p", "wilcoxon_p_holm",
                                "not_testable"]
    assert len(pw) == 2 * 66 and set(pw["group"]) == {"all", "experienced"}
    eq = pd.read_csv(out / "equivalence.csv")
    assert list(eq.columns) == ["group", "sample", "reference", "n", "mean_diff", "margin", "p_lower", "p_upper",
                                "p_tost", "equivalent", "bf01"]
    an = pd.read_csv(out / "anova.csv")
    assert set(an["test"]) == {"rm_anova", "friedman"} and an["p_gg"].notna().sum() == 2
    summ = pd.read_csv(out / "sample_summary.csv")
    assert {"sample", "n_subjects", "mean_rating", "median_rating", "sem_rating", "penetration_mean_m",
            "penetration_sd_m", "incoming_velocity_mean_m_s"} <= set(summ.columns)
    assert len(pd.read_csv(out / "velocity_rating.csv")) == 13


def test_figures_have_content(report):
    out, _ = report
    for name in ("fig_4_17_ratings.png", "fig_4_18_pvalues.png", "fig_4_19_penetration.png",
                 "fig_4_20_accelerations.png"):
        assert _pixels_vary(out / name) > 0.05, name


def test_warnings_printed_and_in_report(report):
    out, proc = report
    assert "warning: 1 subject(s) miss sample(s)" in proc.stderr and "S005 (foam, pulse_soft)" in proc.stderr
    md = (out / "report.md").read_text()
    assert "S005 misses foam, pulse_soft" in md and "S006 is not finished" in md
    assert re.search(r"\*\*all subjects\*\*: \d+ of 66 testable sample pairs differ significantly", md)
    assert "## Significantly different pairs" in md and "- wood rated higher than foam by" in md
    assert "equivalent to wood_on_foam within ±0.5" in md
    assert "invalid testing attempts were left out (saturated" in md
    assert "![Figure 4.20" in md


def test_ranking_json_holds_the_checks_the_summary_states(report, analysed):
    """ranking.json: Figure 4.17's checks of the study as figure_4_17_checks computes them, plain names in their
    texts; report.md states the ranking and each check, met or not, in the same words (this study's sample names
    need no escaping)."""
    out, _ = report
    saved = json.loads((out / "ranking.json").read_text())
    want = json.loads(json.dumps(ranking.figure_4_17_checks(analysed.summary, analysed.study.trials), default=str))
    assert saved == want and not any(c in (out / "ranking.json").read_text() for c in "\x02\x03")
    md = (out / "report.md").read_text()
    lines = ranking.ranking_lines(saved)
    assert len(lines) == 5 and all(line in md for line in lines), [ln for ln in lines if ln not in md]


def test_html_is_self_contained(report):
    out, _ = report
    html = (out / "report.html").read_text()
    srcs = re.findall(r"src='([^']*)'", html)
    # Figures 4.17-4.20 and the ordinal model's P(rating) (issue 35)
    assert len(srcs) == 5 and all(s.startswith("data:image/png;base64,") for s in srcs)
    png = base64.b64decode(srcs[0].split(",", 1)[1])
    img = mpimg.imread(io.BytesIO(png), format="png")
    assert img[..., :3].std() > 0.05
    assert "href=" not in html and "<table" in html and "S005" in html


def test_figures_of_the_drawing_process_equal_those_drawn_here(report, analysed_report):
    """The command draws Figures 4.19-4.20 in its second process: byte for byte what write_report draws in one
    (``analysed_report``: write_report of the same study in the test process, tests/analysis/conftest.py)."""
    out, _ = report
    here = analysed_report["html"].parent
    for stem in ("fig_4_17_ratings", "fig_4_18_pvalues", "fig_4_19_penetration", "fig_4_20_accelerations"):
        for ext in ("png", "svg", "plot.csv"):
            assert (out / f"{stem}.{ext}").read_bytes() == (here / f"{stem}.{ext}").read_bytes(), (stem, ext)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the drawing process is forked on Linux only")
def test_figure_process_is_a_second_process_only_when_forking_is_safe():
    import threading

    from analysis.cli_report import figure_process
    # a new interpreter runs one thread when it starts the command (one BLAS thread, as main() sets it): the
    # pool's process is another process
    code = ("import os\nos.environ.setdefault('OPENBLAS_NUM_THREADS', '1')\n"
            "from analysis.cli_report import figure_process\n"
            "with figure_process() as pool:\n"
            "    print(pool is not None and pool.submit(os.getpid).result() != os.getpid())\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and proc.stdout.strip() == "True", proc.stderr
    # with another thread running (a caller's process) nothing is forked: the figures are drawn here
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        with figure_process() as pool:
            assert pool is None
    finally:
        stop.set()
        other.join()


def test_figures_drawn_here_when_the_drawing_process_died(analysed, tmp_path):
    import multiprocessing
    import os
    import signal
    from concurrent.futures import ProcessPoolExecutor

    from analysis.report import make_figures
    pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"))
    try:
        os.kill(pool.submit(os.getpid).result(), signal.SIGKILL)
        pngs, _ = make_figures(analysed, tmp_path, pool=pool)
    finally:
        pool.shutdown()
    assert [p.name for p in pngs] == ["fig_4_17_ratings.png", "fig_4_18_pvalues.png", "fig_4_19_penetration.png",
                                      "fig_4_20_accelerations.png"]
    for png in pngs:
        assert _pixels_vary(png) > 0.05, png.name


def test_figure_4_20_skipped_with_note_without_traces(complete_dir, tmp_path, capsys):
    # the models are not what this test is about (nothing below reads them): --no-models, ~0.6 s of CPU less
    assert main(["report", str(complete_dir), "--out", str(tmp_path), "--group", "all", "--no-models"]) == 0
    err = capsys.readouterr().err
    assert "Figure 4.20 skipped: no usable per-attempt traces" in err
    assert not (tmp_path / "fig_4_20_accelerations.png").exists()
    assert "Figure 4.20 skipped" in (tmp_path / "report.md").read_text()
    assert _pixels_vary(tmp_path / "fig_4_17_ratings.png") > 0.05


def test_cli_errors_exit_2(tmp_path, capsys):
    data = tmp_path / "data"      # the report goes beside the study, never into it
    data.mkdir()
    assert main(["report", str(data), "--out", str(tmp_path / "r")]) == 2
    assert "error:" in capsys.readouterr().err
    (data / "S1").mkdir()
    (data / "S1" / "session.json").write_text("{\n  \"subject\": \"S1\",\n  oops\n}\n")
    (data / "S1" / "trials.csv").write_text(",".join(["subject"]) + "\n")
    assert main(["report", str(data), "--out", str(tmp_path / "r")]) == 2
    assert "session.json:3: not valid JSON" in capsys.readouterr().err


def test_missing_data_folder_is_reported_before_any_figure_work(tmp_path):
    # a wrong path is an error at once: no drawing process, no matplotlib, no report folder
    code = ("import sys; from analysis.__main__ import main; "
            f"rc = main(['report', {str(tmp_path / 'missing')!r}, '--out', {str(tmp_path / 'r')!r}]); "
            "print(rc, 'matplotlib' in sys.modules, 'pandas' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.stdout.split() == ["2", "False", "False"], proc.stdout + proc.stderr
    assert f"error: data folder {tmp_path / 'missing'} does not exist" in proc.stderr
    assert not (tmp_path / "r").exists()


def test_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["report", "--help"])
    out = capsys.readouterr().out
    assert exc.value.code == 0 and "--reference" in out and "--margin" in out and "--group" in out


def test_accelerations_picked_near_common_velocity(analysed):
    from analysis.stats import valid_testing
    from analysis.traces import typical_taps
    dirs = dict(zip(analysed.study.subjects["subject"], map(Path, analysed.study.subjects["folder"])))
    taps, v, notes = typical_taps(valid_testing(analysed.study), dirs, analysed.study.catalog, 0.11)
    assert v == 0.11 and set(taps) == set(analysed.study.catalog)
    for tap in taps.values():
        assert abs(tap.v_in_m_s - 0.11) < 0.03
        pre = tap.accel_m_s2[tap.t_s < 0]
        post = tap.accel_m_s2[(tap.t_s > 0) & (tap.t_s < 0.03)]
        assert np.abs(post).max() > 5 * np.abs(pre).max()   # impact found where the ringing starts
    assert taps["wood"].accel_m_s2.max() > 3 * taps["foam"].accel_m_s2.max()


def test_analysis_imports_no_other_package():
    code = ("import sys, analysis.report, analysis.cli_report, analysis.pipeline, analysis.traces, analysis.figures, analysis.synthetic\n"
            "bad = [m for m in ('devices', 'renderer', 'stimuli', 'study') if m in sys.modules]\n"
            "assert not bad, bad\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr


def test_out_must_not_be_data(complete_dir, capsys):
    assert main(["report", str(complete_dir), "--out", str(complete_dir)]) == 2
    err = capsys.readouterr().err
    assert f"--out {complete_dir} is the study folder" in err and "not even with --force" in err


def test_trace_reader_is_tolerant(tmp_path):
    from analysis.synthetic import DEFAULT_SAMPLES, synthetic_trace
    from analysis.traces import read_trace_taps
    tr = synthetic_trace(DEFAULT_SAMPLES[0], 0.12, fs_hz=10000.0)
    np.savez(tmp_path / "study.npz", **tr)
    (tap,) = read_trace_taps(tmp_path / "study.npz", "S1", "wood")
    assert tap.v_in_m_s == pytest.approx(0.12) and tap.t_s[0] == pytest.approx(-0.01)
    assert len(tap.t_s) == 1100 and np.argmax(np.abs(tap.accel_m_s2)) > 100
    # no event arrays, other spellings: impacts from the position's downward crossing of 0, velocity from CSV
    np.savez(tmp_path / "pos.npz", time_s=tr["t_s"], acceleration_m_s2=tr["accel_m_s2"], position_m=tr["position_m"])
    (tap2,) = read_trace_taps(tmp_path / "pos.npz", "S1", "wood", velocities_m_s=[0.12])
    assert tap2.v_in_m_s == 0.12
    assert abs(np.argmax(np.abs(tap2.accel_m_s2)) - np.argmax(np.abs(tap.accel_m_s2))) <= 1
    (tap3,) = read_trace_taps(tmp_path / "pos.npz", "S1", "wood")          # speed estimated from position
    assert tap3.v_in_m_s == pytest.approx(0.12, rel=0.05)
    np.savez(tmp_path / "none.npz", t_s=tr["t_s"], force_N=tr["force_prop_N"])
    assert read_trace_taps(tmp_path / "none.npz", "S1", "wood") == []


def test_synthetic_command_then_report(tmp_path, capsys):
    data = tmp_path / "data"
    assert main(["synthetic", str(data), "--subjects", "4", "--seed", "3", "--traces", "1"]) == 0
    assert sorted(p.name for p in data.iterdir()) == ["S001", "S002", "S003", "S004"]
    assert any((data / "S001" / "traces").iterdir()) and not any((data / "S002" / "traces").iterdir())
    assert main(["synthetic", str(data)]) == 2                      # never writes into existing data
    assert "not empty" in capsys.readouterr().err
    assert main(["report", str(data), "--out", str(tmp_path / "rep"), "--no-figures"]) == 0
    assert (tmp_path / "rep" / "pairwise_ttests.csv").stat().st_size > 1000


def test_report_html_renders_in_chromium(report):
    """The self-contained report opens in Debian's headless Chromium with every figure decoded."""
    from playwright.sync_api import sync_playwright

    from tests.support.needs import chromium
    out, _ = report
    exe = chromium()
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, args=[
            "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
            "--disable-sync", "--no-first-run"])
        try:
            page = browser.new_page()
            requests = []
            page.on("request", lambda r: requests.append(r.url))
            page.goto((out / "report.html").as_uri())
            widths = page.eval_on_selector_all("img", "imgs => imgs.map(i => i.complete ? i.naturalWidth : -1)")
            headings = page.eval_on_selector_all("h2", "hs => hs.map(h => h.textContent)")
        finally:
            browser.close()
    assert len(widths) == 5 and min(widths) > 300          # 4.17-4.20 and the ordinal model's (issue 35)
    assert "Models" in headings and "Evidence for no difference" in headings
    assert "Summary" in headings and any("pairwise_ttests.csv" in h for h in headings)
    assert [u for u in requests if not u.startswith(("file:", "data:"))] == []   # nothing fetched from outside


def test_pvalue_matrix_marks_untested_pairs_apart_from_p_one(tmp_path):
    from analysis.figures import build_pvalues, fig_pvalues

    def masked_and_hatched(p_ac):
        pairwise = pd.DataFrame({"group": "all", "sample_a": ["a", "a", "b"], "sample_b": ["b", "c", "c"],
                                 "p": [1.0, p_ac, 0.5], "p_holm": [1.0, p_ac, 1.0], "n": 8,
                                 "cohen_dz": [0.0, 0.1, 0.2]})
        fig, _ = build_pvalues(pairwise, ["a", "b", "c"])
        ax = fig.axes[0]
        masked = int(np.ma.getmaskarray(ax.images[0].get_array()).sum())
        hatched = sum(1 for patch in ax.patches if patch.get_hatch())
        import matplotlib.pyplot as plt
        plt.close(fig)
        return masked, hatched

    assert masked_and_hatched(1.0) == (3, 3)        # only the diagonal lacks a p-value
    assert masked_and_hatched(np.nan) == (5, 5)     # the a-c pair excluded: 2 more cells, never drawn as p = 1
    paths = fig_pvalues(pd.DataFrame({"group": "all", "sample_a": ["a"], "sample_b": ["b"], "p": [0.01],
                                      "p_holm": [0.01], "n": 8, "cohen_dz": [1.0]}), ["a", "b"], tmp_path / "p.png")
    assert sorted(paths) == ["csv", "png", "svg"] and all(p.exists() for p in paths.values())


def test_truncated_traces_are_skipped_with_a_note_naming_them(tmp_path, capsys):
    """Audit analysis_truncated_traces.txt: a truncated trace .npz raised BadZipFile out of Figure 4.20 and
    aborted the whole report; now it is an unreadable trace like any other (named in the note), report written."""
    data = tmp_path / "data"
    assert main(["synthetic", str(data), "--subjects", "4", "--seed", "3", "--traces", "1"]) == 0
    traces = sorted((data / "S001" / "traces").glob("*.npz"))
    assert traces
    for path in traces:                                   # cut off the zip's central directory
        raw = path.read_bytes()
        path.write_bytes(raw[:len(raw) * 2 // 3])
    capsys.readouterr()
    # Figure 4.20 reads the traces; the models do not (nothing below reads them): --no-models
    assert main(["report", str(data), "--out", str(tmp_path / "rep"), "--no-models"]) == 0
    err = capsys.readouterr().err
    assert "Traceback" not in err and "Figure 4.20 skipped" in err
    assert re.search(re.escape(str(data / "S001" / "traces")) + r"/testing_t\d+_a\d+\.npz: unreadable trace "
                     r"\(BadZipFile: ", err), err
    assert (tmp_path / "rep" / "report.html").is_file()


def test_report_figures_use_the_catalog_labels(tmp_path):
    """A sample's label in session.json's catalog ("HFAM, my library, firm") is what the report's figures show,
    not the sample name made readable ("hfam mine")."""
    import json as _json

    from analysis.load import catalog_labels
    from analysis.pipeline import analyse
    from analysis.report import make_figures
    from analysis.synthetic import write_synthetic_study
    data = tmp_path / "DATA"
    write_synthetic_study(data, 3, seed=2, p_invalid=0.0)
    for sess in data.glob("*/session.json"):
        s = _json.loads(sess.read_text())
        for item in s["catalog"]:
            if item["name"] == "hfam_firm":
                item["label"] = "HFAM, my library, firm"
        sess.write_text(_json.dumps(s))
    res = analyse(data)
    assert catalog_labels(res.study)["hfam_firm"] == "HFAM, my library, firm"
    # the report's figures as write_report draws them (its tables, models' section and pages are not read here)
    (tmp_path / "R").mkdir()
    make_figures(res, tmp_path / "R")
    for stem in ("fig_4_17_ratings", "fig_4_18_pvalues", "fig_4_19_penetration"):
        svg = (tmp_path / "R" / f"{stem}.svg").read_text()
        assert "HFAM, my library, firm" in svg, stem
