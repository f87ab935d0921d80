"""``analysis psychometric``'s outputs: every flag in fit.json, fits.csv, the console and the figure; log10 sessions
reported in physical units with intervals; sessions that are different measurements refused (naming them and
the field) or fitted apart with --separately; --compare, --bayesian, --threshold-at and dprime.csv."""

import csv
import json
import math

import numpy as np
import pytest

from analysis.__main__ import main
from psychophysics import fitting as pm
from psychophysics.psychometric import psi

LEVELS = np.linspace(1.0, 4.0, 7)


def _rows_from_counts(condition, k, n=40, subject="A", levels=LEVELS):
    rows = []
    for x, kk in zip(levels, k):
        rows += [[subject, condition, x, 1]] * int(kk) + [[subject, condition, x, 0]] * int(n - kk)
    return rows


def _write(path, rows, header=("subject", "condition", "intensity", "correct")):
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return path


def _read_csv(path):
    with path.open() as fh:
        return list(csv.DictReader(fh))


#: a condition per flag: counts of correct answers out of 40 at the 7 levels (2AFC)
FLAGGED = {
    "lapse_at_bound": [20, 22, 26, 30, 32, 32, 32],
    "slope_at_bound": [20, 20, 20, 40, 40, 40, 40],
    "threshold_interval_open": [40] * 7,
    "threshold_outside_range": [38, 39, 40, 40, 40, 40, 40],
    "few_levels_on_slope": [20, 20, 21, 39, 40, 40, 40],
    "poor_fit": [20, 38, 22, 38, 24, 39, 40],
    "one_response": [0] * 7,
}


def test_every_flag_reaches_fit_json_fits_csv_the_console_and_the_figure(tmp_path, capsys):
    rows = []
    for name, k in FLAGGED.items():
        rows += _rows_from_counts(name, k)
    src = _write(tmp_path / "flags.csv", rows)
    out = tmp_path / "fits"
    assert main(["psychometric", str(src), "--alternatives", "2", "--bootstrap", "200", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    doc = json.loads((out / "fit.json").read_text())
    groups = {g["condition"]: g for g in doc["groups"] if g["subject"] == "(pooled)"}
    table = {r["condition"]: r for r in _read_csv(out / "fits.csv")}
    plot = _read_csv(out / "fig_psychometric.plot.csv")
    for name in FLAGGED:
        assert name in {f["name"] for f in groups[name]["flags"]}, (name, groups[name]["flags"])
        assert name in table[name]["flags"].split(";")
        assert f"condition {name}: {name}:" in err
        drawn = {r["flags"] for r in plot if r["condition"] == name}
        assert drawn and all(name in d.split(", ") for d in drawn)
    # and the figure's legend names them
    from analysis.psychophysics import load_trials, fit_groups, FitOptions
    from analysis.psychometric_figures import build_curves, axis_words
    trials = load_trials(src)
    fits = fit_groups(trials, 2, options=FitOptions(alternatives=2, bootstrap=0))
    fig, _ = build_curves(trials, fits, axis_words({}, 2))
    legend = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    for name in FLAGGED:
        assert any(t.startswith(name.replace("_", " ")) and f"flags: " in t and name in t for t in legend), legend


def test_the_guess_at_bound_flag_of_a_yes_no_fit_reaches_the_table(tmp_path, capsys):
    src = _write(tmp_path / "yn.csv", _rows_from_counts("c", [24, 25, 24, 26, 30, 36, 39]))
    out = tmp_path / "fits"
    assert main(["psychometric", str(src), "--alternatives", "1", "--bootstrap", "0", "--no-figures",
                 "--out", str(out)]) == 0
    row = _read_csv(out / "fits.csv")[0]
    assert row["lower_asymptote"] == "free" and "guess_at_bound" in row["flags"]
    assert "guess_at_bound" in capsys.readouterr().err


def _session(folder, subject, experiment, rows, header=("trial", "staircase", "intensity", "intensity_physical",
                                                        "correct", "is_catch")):
    d = folder / subject
    d.mkdir(parents=True)
    (d / "session.json").write_text(json.dumps({"subject": subject, "experiment": experiment}))
    _write(d / "trials.csv", rows, header)
    return d


def _log10_discrimination(seed, reference=500.0, pse=520.0, slope_log10=18.0, sample="firm", n=30):
    """A 'which was harder?' session on a log10 stiffness axis (constant stimuli) with catch trials."""
    rng = np.random.default_rng(seed)
    physical = reference * 10 ** np.linspace(-0.15, 0.15, 7)
    rows, t = [], 0
    for x in physical:
        for _ in range(n):
            t += 1
            p = psi(math.log10(x), math.log10(pse), slope_log10, 0.02, 0.02)
            rows.append([t, "", math.log10(x), x, int(rng.random() < p), 0])
    for _ in range(5):
        t += 1
        rows.append([t, "", "", 0.0, int(rng.random() < 0.1), 1])        # catch trials: no log10 intensity
    experiment = {"kind": "discrimination", "alternatives": 2, "guess_rate": 0.0, "intensity_scale": "log10",
                  "intensity_unit": "N/m", "reference": reference, "method": "constant",
                  "config": {"vary": "stiffness_N_m", "sample": sample}}
    return experiment, rows


def test_a_log10_session_reports_physical_units_with_intervals(tmp_path, capsys):
    data = tmp_path / "DATA"
    exp, rows = _log10_discrimination(1)
    _session(data, "S01", exp, rows)
    out = tmp_path / "fits"
    assert main(["psychometric", str(data), "--bootstrap", "300", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    doc = json.loads((out / "fit.json").read_text())
    # fit.json: PSE, JND and Weber fraction in N/m with intervals (the JND's and Weber's came without before)
    assert doc["pse_physical"] == pytest.approx(10 ** doc["threshold"])
    lo, hi = doc["threshold_ci_physical"]
    assert lo == pytest.approx(10 ** doc["threshold_ci"][0]) and lo < doc["pse_physical"] < hi
    for key in ("jnd", "weber"):
        a, b = doc[f"{key}_ci_physical"]
        assert a is not None and a < doc[f"{key}_physical"] < b
    assert doc["weber_physical"] == pytest.approx(doc["jnd_physical"] / 500.0)
    assert doc["pse_physical"] == pytest.approx(520.0, rel=0.05)
    # the console says N/m, the physical values and their intervals
    assert f"PSE {doc['pse_physical']:.4g} N/m [{lo:.4g}, {hi:.4g}]" in printed
    assert "JND " in printed and "Weber fraction" in printed
    row = _read_csv(out / "fits.csv")[0]
    assert float(row["jnd_physical_ci_low"]) < float(row["jnd_physical"]) < float(row["jnd_physical_ci_high"])
    assert float(row["pse_physical"]) == pytest.approx(doc["pse_physical"])
    # the figure in N/m on a log axis: the points at the physical levels
    plot = [r for r in _read_csv(out / "fig_psychometric.plot.csv") if r["kind"] == "point"]
    assert sorted(float(r["intensity"]) for r in plot) == pytest.approx(sorted({x[3] for x in rows if x[5] == 0}))
    # the catch trials (empty intensity) were read and left out of the fit
    assert doc["n_trials"] == 7 * 30


def test_sessions_that_are_different_measurements_are_refused_or_fitted_apart(tmp_path, capsys):
    """One subject at reference 500 N/m on a log10 axis, one at 250 N/m on a linear axis, one on another sample:
    pooling them would convert every threshold with the first session's scale (a 259 N/m threshold was reported
    as 6e258 N/m). Refused, naming the sessions and the field; --separately fits each measurement on its own."""
    data = tmp_path / "DATA"
    exp1, rows1 = _log10_discrimination(2, reference=500.0, pse=510.0)
    _session(data, "S01", exp1, rows1)
    exp2, rows2 = _log10_discrimination(3, reference=250.0, pse=259.0)
    exp2 = dict(exp2, intensity_scale="linear")
    rows2 = [[r[0], r[1], r[3], r[3], r[4], r[5]] for r in rows2]     # linear: intensity = the physical value
    _session(data, "S02", exp2, rows2)
    out = tmp_path / "fits"
    assert main(["psychometric", str(data), "--bootstrap", "0", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "error:" in err and str(data / "S02" / "session.json") in err and str(data / "S01" / "session.json") in err
    assert "experiment.intensity_scale 'linear' differs from 'log10'" in err and "--separately" in err
    assert not (out / "fit.json").exists()
    assert main(["psychometric", str(data), "--bootstrap", "0", "--separately", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    doc = json.loads((out / "fit.json").read_text())
    m1, m2 = doc["measurements"]
    assert m1["sessions"] == [str(data / "S01" / "session.json")] and m2["intensity_scale"] == "linear"
    assert m1["pse_physical"] == pytest.approx(510.0, rel=0.05)
    assert m2["pse"] == pytest.approx(259.0, rel=0.05) and "pse_physical" not in m2
    table = _read_csv(out / "fits.csv")
    assert {r["measurement"] for r in table} == {"1", "2"}
    assert (out / "fig_psychometric_m1.png").exists() and (out / "fig_psychometric_m2.png").exists()
    assert "measurement 1 (1 session(s))" in printed and "measurement 2" in printed
    # another sample, same scale and reference: refused too, naming experiment.config.sample
    data3 = tmp_path / "D3"
    _session(data3, "S01", exp1, rows1)
    _session(data3, "S02", dict(exp1, config={"vary": "stiffness_N_m", "sample": "soft"}), rows1)
    assert main(["psychometric", str(data3), "--bootstrap", "0", "--out", str(tmp_path / "f3")]) == 2
    assert "experiment.config.sample 'soft' differs from 'firm'" in capsys.readouterr().err


def _two_conditions(tmp_path, seed=4):
    rng = np.random.default_rng(seed)
    rows = []
    for cond, thr in (("hfam_firm", 2.0), ("pulse_firm", 3.0)):
        for x in LEVELS:
            for _ in range(40):
                rows.append(["A", cond, x, int(rng.random() < psi(x, thr, 2.5, 0.5, 0.02))])
    return _write(tmp_path / "two.csv", rows)


def test_compare_fits_conditions_with_a_shared_slope_and_tests_their_thresholds(tmp_path, capsys):
    src = _two_conditions(tmp_path)
    out = tmp_path / "fits"
    assert main(["psychometric", str(src), "--alternatives", "2", "--bootstrap", "100", "--compare", "--no-figures",
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    (c,) = json.loads((out / "fit.json").read_text())["comparisons"]
    shared = c["shared_slope_and_lapse"]
    assert shared["conditions"] == ["hfam_firm", "pulse_firm"] and shared["slopes"][0] == shared["slopes"][1]
    assert shared["thresholds"][0] == pytest.approx(2.0, rel=0.1) and shared["thresholds"][1] == pytest.approx(3.0, rel=0.1)
    assert c["thresholds_differ"]["df"] == 1 and c["thresholds_differ"]["p_bootstrap"] < 0.05
    assert c["slopes_differ"]["df"] == 1 and c["slopes_differ"]["p_bootstrap"] > 0.01
    assert "thresholds differ? LR" in printed


def test_bayesian_fit_threshold_at_and_dprime(tmp_path, capsys):
    src = _two_conditions(tmp_path)
    out = tmp_path / "fits"
    assert main(["psychometric", str(src), "--alternatives", "2", "--bayesian", "--threshold-at", "0.75,0.9",
                 "--no-figures", "--out", str(out)]) == 0
    doc = json.loads((out / "fit.json").read_text())
    assert doc["fit_method"] == "Bayesian (maximum a posteriori)" and 0 <= doc["eta"] < 1 and doc["eta_ci"][1] > doc["eta_ci"][0]
    assert [t["pc"] for t in doc["thresholds_at"]] == [0.75, 0.9]
    row = _read_csv(out / "fits.csv")[0]
    assert float(row["threshold_at_0.75_ci_low"]) < float(row["threshold_at_0.75"]) < float(row["threshold_at_0.9"])
    assert "threshold at 0.75:" in capsys.readouterr().out
    # yes/no with catch trials: d' and criterion per level against the catch trials' false alarms
    rng = np.random.default_rng(8)
    rows = [["A", "c", x, int(rng.random() < psi(x, 2.5, 2.0, 0.1, 0.02)), 0] for x in LEVELS for _ in range(30)]
    rows += [["A", "c", 0.0, int(rng.random() < 0.1), 1] for _ in range(40)]
    yn = _write(tmp_path / "yn.csv", rows, ("subject", "condition", "intensity", "correct", "is_catch"))
    assert main(["psychometric", str(yn), "--alternatives", "1", "--bootstrap", "0", "--no-figures",
                 "--out", str(tmp_path / "yn")]) == 0
    table = _read_csv(tmp_path / "yn" / "dprime.csv")
    assert len(table) == 7 and all(int(r["n_catch"]) == 40 for r in table)
    d = [float(r["dprime"]) for r in table]
    assert d[0] < 0.5 < 2.0 < d[-1]
    from scipy.stats import norm
    r = table[-1]
    h = (int(r["hits"]) + 0.5) / (int(r["n_signal"]) + 1)
    f = (int(r["false_alarms"]) + 0.5) / 41
    assert float(r["dprime"]) == pytest.approx(norm.ppf(h) - norm.ppf(f))


def test_changed_definitions_reach_the_table(tmp_path):
    """n-AFC with a reference: JND = threshold - reference, Weber = JND / reference (the docs' one definition);
    no PSE."""
    src = _two_conditions(tmp_path)
    out = tmp_path / "fits"
    assert main(["psychometric", str(src), "--alternatives", "2", "--reference", "1.5", "--bootstrap", "0",
                 "--no-figures", "--out", str(out)]) == 0
    row = _read_csv(out / "fits.csv")[0]
    assert float(row["jnd"]) == pytest.approx(float(row["threshold"]) - 1.5)
    assert float(row["weber"]) == pytest.approx(float(row["jnd"]) / 1.5)
    assert row["pse"] == ""
    f = pm.fit_counts(LEVELS, np.full(7, 40.0), np.full(7, 30.0), 2, bootstrap=0)[0]
    assert math.isnan(f.pse)


# -- the psychometric figure's rules: checked on the plotted data and with the text-overlap check --------------

def _figure(src, alternatives, experiment=None, bootstrap=0):
    import figstyle
    from analysis.psychometric_figures import axis_words, build_curves
    from analysis.psychophysics import FitOptions, fit_groups, load_trials
    trials = load_trials(src)
    fits = fit_groups(trials, alternatives, options=FitOptions(alternatives=alternatives, bootstrap=bootstrap))
    fig, (header, rows) = build_curves(trials, fits, axis_words(experiment or {}, alternatives))
    return figstyle, fig, [dict(zip(header, r)) for r in rows]


def _close(fig):
    import matplotlib.pyplot as plt
    plt.close(fig)


def test_a_2afc_figure_shows_chance_to_1_with_points_below_chance_as_arrows_sized_by_their_trials(tmp_path):
    """2AFC: the y axis runs from below chance to 1; a level answered 30 % correct (below chance, it vanished
    from the old axis) is drawn as a downward arrow at the bottom edge; every point's area is proportional to
    its trial count; the threshold is drawn with its interval."""
    k = [12, 22, 26, 30, 36, 39, 40]
    n = [40, 40, 40, 40, 40, 40, 20]
    rows = []
    for x, kk, nn in zip(LEVELS, k, n):
        kk = min(kk, nn)
        rows += [["A", "c", x, 1]] * kk + [["A", "c", x, 0]] * (nn - kk)
    figstyle, fig, plotted = _figure(_write(tmp_path / "a.csv", rows), 2)
    try:
        ax = fig.axes[0]
        y0, y1 = ax.get_ylim()
        assert 0.40 < y0 < 0.5 and y1 >= 1.0
        points = [r for r in plotted if r["kind"] == "point"]
        low = next(r for r in points if r["intensity"] == pytest.approx(LEVELS[0]))
        assert low["proportion"] == pytest.approx(0.3) and low["clipped"] == 1 and y0 < low["y_drawn"] < 0.5
        drawn = [c for c in ax.collections if len(c.get_offsets())
                 and np.allclose(c.get_offsets(), [[LEVELS[0], low["y_drawn"]]])]
        assert len(drawn) == 1 and drawn[0].get_sizes()[0] == pytest.approx(low["marker_area"])
        assert sum(r["clipped"] for r in points) == 1
        areas = {r["n_trials"]: r["marker_area"] for r in points}
        assert areas[20] == pytest.approx(areas[40] / 2)
        (thr,) = [r for r in plotted if r["kind"] == "threshold"]
        assert thr["ci_low"] < thr["threshold"] < thr["ci_high"]
        assert ax.get_ylabel() == "proportion correct (1)"
        assert figstyle.text_problems(fig, tight=True) == [] and figstyle.legend_overlaps(fig) == []
    finally:
        _close(fig)


def test_all_wrong_yes_no_data_are_visible_on_a_0_to_1_axis(tmp_path):
    figstyle, fig, plotted = _figure(_write(tmp_path / "w.csv", _rows_from_counts("c", [0] * 7)), 1)
    try:
        y0, y1 = fig.axes[0].get_ylim()
        points = [r for r in plotted if r["kind"] == "point"]
        assert y0 < 0.0 and y1 >= 1.0 and len(points) == 7
        assert all(r["proportion"] == 0.0 and r["clipped"] == 0 and y0 < r["y_drawn"] for r in points)
        assert all("one_response" in r["flags"] for r in points)
    finally:
        _close(fig)


def test_several_subjects_get_small_panels_beside_the_pooled_fit(tmp_path):
    rng = np.random.default_rng(5)
    rows = []
    for s, thr in (("S1", 2.0), ("S2", 2.6), ("S3", 3.0)):
        for x in LEVELS:
            rows += [[s, "c", x, int(rng.random() < psi(x, thr, 3.0, 0.5, 0.02))] for _ in range(30)]
    figstyle, fig, plotted = _figure(_write(tmp_path / "s.csv", rows), 2)
    try:
        assert len(fig.axes) == 4 and [a.get_title(loc="left") for a in fig.axes[1:]] == ["S1", "S2", "S3"]
        panels = {r["panel"] for r in plotted}
        assert panels == {"(pooled)", "S1", "S2", "S3"}
        thr = {r["panel"]: r["threshold"] for r in plotted if r["kind"] == "threshold"}
        assert thr["S1"] < thr["S2"] < thr["S3"]
        assert figstyle.text_problems(fig, tight=True) == []
    finally:
        _close(fig)


def test_axis_words_come_from_the_task_and_log_ticks_are_plain_numbers(tmp_path):
    from analysis.psychometric_figures import axis_words, log_ticks
    harder = axis_words({"kind": "discrimination", "intensity_unit": "N/m", "config": {"vary": "stiffness_N_m"}}, 1)
    assert harder.y_label == "proportion 'comparison harder' (1)" and harder.x_label == "comparison stiffness (N/m)"
    detect = axis_words({"kind": "detection", "intensity_unit": "N*s/m", "config": {"vary": "amplitude_Ns_m"}}, 1)
    assert detect.y_label == "proportion 'yes' (1)" and detect.x_label == "transient amplitude (N·s/m)"
    assert axis_words({"kind": "detection"}, 2).y_label == "proportion correct (1)"
    ticks = log_ticks(3.0, 40.0)      # plain 1, 1.5, 2, 3, 5, 7 x 10^k, at most 5, spanning the range
    assert 2 <= len(ticks) <= 5 and ticks == sorted(set(ticks)) and ticks[0] == 3.0 and ticks[-1] >= 20.0
    assert all(round(t / 10 ** math.floor(math.log10(t)), 6) in (1, 1.5, 2, 3, 5, 7) for t in ticks)
    # a log10 session's figure: physical units on a log axis, tick labels readable (no "3x10^0 4x10^0")
    data = tmp_path / "DATA"
    exp, rows = _log10_discrimination(6)
    _session(data, "S01", exp, rows)
    figstyle, fig, _ = _figure(data, 1, experiment=exp)
    try:
        ax = fig.axes[0]
        assert ax.get_xscale() == "log" and ax.get_xlabel() == "comparison stiffness (N/m)"
        labels = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
        assert labels and all("10^" not in s and "times" not in s and "×" not in s for s in labels)
        assert figstyle.text_problems(fig, tight=True) == []
    finally:
        _close(fig)
