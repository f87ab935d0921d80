"""The method of adjustment's and magnitude estimation's analysis: a small honest recovery on simulated sessions
(the 100-participant study is ``python -m benchmarks scaling``), the statistics cross-checked against
statsmodels and scipy, order effects, the commands' output and their refusals."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
import statsmodels.api as sm
from scipy import stats

import figstyle
from analysis import adjustment, magnitude
from analysis.__main__ import main as analysis_main
from analysis.scaling_figures import (build_adjustment_pooled, build_adjustment_subjects, build_magnitude_exponents,
                                      build_magnitude_loglog)
from analysis.scaling_load import order_effects
from study.__main__ import main as study_main

QUICK = "tap_window_s = 0.6\nhoming_after_s = 0.3\nhoming_before_max_s = 0.1\n"
ADJUST = QUICK + '[experiment]\nkind = "adjustment"\nsample = "firm"\nreferences = [500.0, 900.0]\n' \
                 "trials_per_reference = 3\n"
MAGNITUDE = QUICK + '[experiment]\nkind = "magnitude"\nsamples = ["firm"]\n' \
                    'levels = [250.0, 500.0, 1000.0, 2000.0]\nrepetitions = 3\n'
BIAS, EXPONENT = 0.15, 1.2


@pytest.fixture(scope="module")
def studies(tmp_path_factory):
    """Three simulated participants' adjustment sessions (two references, four trials each) and magnitude
    sessions (four levels, three times each), biased by 15 % and with exponent 1.2."""
    root = tmp_path_factory.mktemp("scaling")
    (root / "a.toml").write_text(ADJUST)
    (root / "m.toml").write_text(MAGNITUDE)
    (root / "p.toml").write_text(f"adjust_bias_frac = {BIAS}\nstevens_exponent = {EXPONENT}\np_reject = 0\n")
    for proto, data in (("a.toml", "ADJ"), ("m.toml", "MAG")):
        for k in range(3):
            assert study_main(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject",
                               f"S{k}", "--seed", str(20 + k), "--out", str(root / data), "--protocol",
                               str(root / proto), "--participant-config", str(root / "p.toml")]) == 0
    return root


def test_adjustment_recovers_the_constant_error_and_its_numbers_are_the_textbooks(studies):
    res = adjustment.analyse(studies / "ADJ")
    s, p = res["subjects"], res["pooled"]
    assert len(s) == 6 and set(p["condition"]) == {"500", "900"}
    # pooled over 3 participants x 4 settings: the 15 % over-adjustment within the noise (the benchmark's 100
    # participants put it within 1 %)
    assert np.all(np.abs(p["pse_rel"] / (1 + BIAS) - 1) < 0.12), p
    trials = res["trials"]
    for _, r in s.iterrows():    # PSE and its interval: scipy's t interval of the log settings, exponentiated
        ln = np.log(trials[(trials["subject"] == r["subject"]) & (trials["condition"] == r["condition"])]["final_value"])
        lo, hi = stats.t.interval(0.95, len(ln) - 1, loc=ln.mean(), scale=stats.sem(ln))
        assert (r["pse"], r["pse_low"], r["pse_high"]) == pytest.approx((math.exp(ln.mean()), math.exp(lo), math.exp(hi)))
        assert r["weber"] == pytest.approx(math.expm1(0.6744897501960817 * ln.std(ddof=1)))
        assert r["ce"] == pytest.approx(r["pse"] - r["reference"])
    # the block position varies (each subject's own order): its ANOVA row is there
    assert res["order"] is not None and "C(position)" in set(res["order"]["term"])


def test_magnitude_exponents_equal_statsmodels_ols_and_recover_the_law(studies):
    res = magnitude.analyse(studies / "MAG")
    t = res["trials"]
    for _, r in res["subjects"].iterrows():
        d = t[t["subject"] == r["subject"]]
        ols = sm.OLS(d["ln_number"].to_numpy(), sm.add_constant(d["ln_level"].to_numpy())).fit()
        lo, hi = ols.conf_int(0.05)[1]
        assert (r["exponent"], r["exponent_low"], r["exponent_high"]) == pytest.approx((ols.params[1], lo, hi), rel=1e-9)
    p = res["pooled"].iloc[0]
    assert abs(p["exponent"] - EXPONENT) < 0.15 and p["exponent_low"] < p["exponent"] < p["exponent_high"]
    # normalisation leaves every subject's geometric mean at the grand one and the exponents unchanged
    gm = t.groupby("subject")["ln_norm"].mean()
    assert np.allclose(gm, t["ln_number"].mean())


def test_a_planted_position_effect_is_found():
    rng = np.random.default_rng(1)
    rows = []
    for s in range(12):
        order = ["a", "b"] if s % 2 else ["b", "a"]
        for pos, cond in enumerate(order, start=1):
            for _ in range(6):
                rows.append({"subject": f"S{s}", "condition": cond, "position": pos,
                             "ln_ratio": 0.1 * (pos == 2) + 0.02 * (cond == "a") + rng.normal(0, 0.05)})
    table = order_effects(pd.DataFrame(rows), "ln_ratio")
    pos = table[table["term"] == "C(position)"].iloc[0]
    assert pos["PR(>F)"] < 1e-6
    assert order_effects(pd.DataFrame(rows).assign(position=1), "ln_ratio") is None


def test_the_figures_keep_the_style(studies):
    a, m = adjustment.analyse(studies / "ADJ"), magnitude.analyse(studies / "MAG")
    built = [build_adjustment_subjects(a["trials"], a["subjects"], "comparison stiffness (N/m)")[0],
             build_adjustment_pooled(a["subjects"], a["pooled"])[0],
             build_magnitude_loglog(m["trials"], m["pooled"], "stimulus stiffness (N/m)")[0],
             build_magnitude_exponents(m["subjects"], m["pooled"])[0]]
    for fig in built:
        assert figstyle.unlabelled_axes(fig) == [] and figstyle.legend_overlaps(fig) == []
        assert figstyle.text_problems(fig, tight=True) == [], figstyle.text_problems(fig, tight=True)  # saved tight
    ax = built[2].axes[0]
    assert ax.get_xscale() == "log" and ax.get_yscale() == "log"


def test_the_commands_write_a_whole_folder_or_nothing(studies, tmp_path, capsys):
    out = tmp_path / "A"
    assert analysis_main(["adjustment", str(studies / "ADJ"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "500: PSE" in printed and "constant error" in printed
    line = printed.split("500: PSE ", 1)[1]
    pse = float(line.split(" ", 1)[0])
    low, high = (float(v) for v in line.split("[", 1)[1].split("]", 1)[0].split(","))
    assert low < pse < high and 500 < pse < 700                     # the pooled interval over three subjects
    names = {p.name for p in out.iterdir()}
    assert {"subjects.csv", "pooled.csv", "trials.csv", "order_effects.csv", "summary.json",
            "fig_adjustment_subjects.png", "fig_adjustment_pooled.svg"} <= names
    assert json.loads((out / "summary.json").read_text())["unit"] == "N/m"
    assert analysis_main(["magnitude", str(studies / "MAG"), "--out", str(tmp_path / "M"), "--no-figures"]) == 0
    assert "exponent" in capsys.readouterr().out
    # refusals: one error line, nothing written
    assert analysis_main(["magnitude", str(studies / "ADJ"), "--out", str(tmp_path / "X")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "no magnitude session with trials in it (other kinds: S0, S1, S2)" in err
    assert not (tmp_path / "X").exists() and not list(tmp_path.glob(".X*"))
    assert analysis_main(["adjustment", str(studies / "ADJ"), "--out", str(out)]) == 2
    assert "error:" in capsys.readouterr().err
    assert analysis_main(["adjustment", str(tmp_path / "nowhere"), "--out", str(tmp_path / "Y")]) == 2
    assert "not a folder" in capsys.readouterr().err
    damaged = tmp_path / "D" / "S0"
    damaged.mkdir(parents=True)
    for f in ("session.json", "trials.csv"):
        (damaged / f).write_bytes((studies / "ADJ" / "S0" / f).read_bytes())
    text = (damaged / "trials.csv").read_text().splitlines()
    text[2] = text[2].replace(",above,", ",sideways,").replace(",below,", ",sideways,")
    (damaged / "trials.csv").write_text("\n".join(text) + "\n")
    assert analysis_main(["adjustment", str(tmp_path / "D"), "--out", str(tmp_path / "Z")]) == 2
    err = capsys.readouterr().err
    assert f"{damaged / 'trials.csv'} line 3" in err and "start_side='sideways'" in err and err.count("\n") == 1
    # one subject: the pooled values without an interval (not "[nan, nan]")
    one = tmp_path / "ONE" / "S0"
    one.mkdir(parents=True)
    for f in ("session.json", "trials.csv"):
        (one / f).write_bytes((studies / "ADJ" / "S0" / f).read_bytes())
    assert analysis_main(["adjustment", str(tmp_path / "ONE"), "--out", str(tmp_path / "O"), "--no-figures"]) == 0
    printed = capsys.readouterr().out
    assert printed.count("(no interval: one subject) over 1 subject(s)") == 2 and "nan" not in printed
