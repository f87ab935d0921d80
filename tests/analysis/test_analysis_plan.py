"""Issue 35: ``python -m analysis plan``: sample sizes equal statsmodels' TTestPower exactly."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pandas as pd
import pytest
from statsmodels.stats.power import TTestPower

from analysis.__main__ import main
from analysis.power import (PlanSettings, assumed_plan, dz_ci, pilot_plan, power_curves, power_difference,
                            power_tost, smallest_n)

SM = TTestPower()


@pytest.mark.parametrize("dz,m,power", [(0.5, 1, 0.8), (0.5, 66, 0.8), (0.3, 11, 0.9), (1.2, 66, 0.8),
                                        (0.8, 5, 0.95), (2.0, 1, 0.8)])
def test_difference_n_equals_statsmodels_solve_power(dz, m, power):
    s = PlanSettings(power=power, comparisons=m)
    row = assumed_plan(dz, 1.0, s).iloc[0]
    want = SM.solve_power(effect_size=dz, nobs=None, alpha=0.05 / m, power=power, alternative="two-sided")
    assert row["n_required"] == math.ceil(want)
    assert row["alpha_each"] == 0.05 / m
    # the smallest such n: statsmodels' power reaches the target at n and not at n - 1
    n = int(row["n_required"])
    assert SM.power(effect_size=dz, nobs=n, alpha=0.05 / m, alternative="two-sided") >= power
    if n > 2:
        assert SM.power(effect_size=dz, nobs=n - 1, alpha=0.05 / m, alternative="two-sided") < power
    assert row["power_at_n"] == SM.power(effect_size=dz, nobs=n, alpha=0.05 / m, alternative="two-sided")


@pytest.mark.parametrize("delta,margin,m", [(0.0, 0.5, 1), (0.0, 0.5, 11), (0.1, 0.4, 1), (-0.2, 0.6, 3)])
def test_tost_power_equals_statsmodels_one_sided_powers(delta, margin, m):
    a = 0.05 / m
    for n in (5, 20, 60, 150):
        lower = SM.power(effect_size=delta + margin, nobs=n, alpha=a, alternative="larger")
        upper = SM.power(effect_size=delta - margin, nobs=n, alpha=a, alternative="smaller")
        assert power_tost(delta, margin, n, a) == max(0.0, lower + upper - 1.0)
    n = smallest_n(lambda k: power_tost(delta, margin, k, a), 0.8)
    assert power_tost(delta, margin, n, a) >= 0.8 > power_tost(delta, margin, n - 1, a)


def test_tost_plan_from_assumed_sd():
    row = assumed_plan(0.5, 1.0, PlanSettings(margin=0.5, equivalence_comparisons=1)).iloc[1]
    assert row["test"] == "equivalence" and row["dz"] == 0.0
    # known value: TOST, true difference 0, margin 0.5 SD, alpha 0.05, power 0.8 -> 36 pairs (the approximation
    # of Chow et al. eq. 3.1.9 that TOSTER's powerTOSTpaired uses gives 35.6 -> 36)
    assert row["n_required"] == 36


def test_power_curves_equal_the_power_of_each_n_value_for_value():
    """The curves are computed for every n at once; each value is power_difference's or power_tost's at that n,
    including the far-tail n where statsmodels' two-sided power is NaN (d_z = 0.5 at alpha 0.05/66 from n ~ 100)
    and a d_z large enough for the 8-standard-error rule."""
    plan = pd.DataFrame({"test": ["difference", "difference", "difference", "tost"],
                         "dz": [0.5, -0.3, 3.0, 0.1], "alpha_each": [0.05 / 66, 0.05, 1e-6, 0.05],
                         "sd_diff": [np.nan, np.nan, np.nan, 1.2], "margin": [np.nan, np.nan, np.nan, 0.5],
                         "sample_a": ["a", "b", "c", "d"], "sample_b": ["x", "y", "z", "w"], "n_required": [np.nan] * 4})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        curves = power_curves(plan, n_max=200)
        fallbacks = 0
        for (k, n, pw) in curves[["row", "n", "power"]].itertuples(index=False):
            r = plan.iloc[k]
            n = int(n)
            if r.test == "difference":
                want = power_difference(r.dz, n, r.alpha_each)
                fallbacks += bool(np.isnan(SM.power(effect_size=abs(r.dz), nobs=n, alpha=r.alpha_each,
                                                    alternative="two-sided")))
            else:
                want = power_tost(r.dz, r.margin / r.sd_diff, n, r.alpha_each)
            assert pw == want or (np.isnan(pw) and np.isnan(want)), (k, n, pw, want)
    assert set(curves["row"]) == {0, 1, 2, 3} and fallbacks > 0


def test_power_difference_has_no_nan_where_scipy_gives_nan():
    # scipy's noncentral t returns NaN for this far tail; statsmodels' two-sided power is NaN there
    assert np.isnan(SM.power(effect_size=0.5, nobs=104, alpha=0.05 / 66, alternative="two-sided"))
    p = power_difference(0.5, 104, 0.05 / 66)
    near = SM.power(effect_size=0.5, nobs=104, alpha=0.05 / 132, alternative="larger")
    assert p == near and power_difference(0.5, 102, 0.05 / 66) < p < power_difference(0.5, 106, 0.05 / 66)


def test_dz_ci_covers_by_noncentral_t_inversion():
    lo, hi = dz_ci(0.8, 20)
    from scipy import stats
    t = 0.8 * math.sqrt(20)
    assert stats.nct.sf(t, 19, lo * math.sqrt(20)) == pytest.approx(0.025, abs=1e-8)
    assert stats.nct.sf(t, 19, hi * math.sqrt(20)) == pytest.approx(0.975, abs=1e-8)
    assert lo < 0.8 < hi


def test_pilot_plan_uses_observed_effects(analysed):
    s = PlanSettings()
    plan = pilot_plan(analysed.matrix, "wood_on_foam", s)
    diff = plan[plan["test"] == "difference"]
    eq = plan[plan["test"] == "equivalence"]
    assert len(diff) == 66 and len(eq) == 11
    pw = analysed.pairwise[analysed.pairwise["group"] == "all"].reset_index(drop=True)
    np.testing.assert_allclose(diff["dz"].to_numpy(), pw["cohen_dz"].to_numpy(), rtol=1e-12)
    exact = 0
    a = 0.05 / 66
    for r in diff.dropna(subset=["n_required"]).itertuples():
        n = int(r.n_required)
        assert r.dz_ci_low < r.dz < r.dz_ci_high
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            want = math.ceil(SM.solve_power(effect_size=abs(r.dz), nobs=None, alpha=a, power=0.8))
            sm_at = [SM.power(effect_size=abs(r.dz), nobs=k, alpha=a) for k in (want - 1, want)]
        if np.all(np.isfinite(sm_at)) and sm_at[1] >= 0.8:
            assert n == want
            exact += 1
        else:
            # statsmodels' two-sided power is NaN near the answer (scipy's far tail; e.g. d_z 4.0: NaN at n = 4, 5),
            # and its solve_power then returns a wrong n (3.5 where n = 5 has power 0.56): the smallest n by
            # statsmodels' one-sided power at alpha/2 (what power_difference falls back to) is reported
            near = [SM.power(effect_size=abs(r.dz), nobs=k, alpha=a / 2, alternative="larger") for k in (n - 1, n)]
            assert near[1] >= 0.8 > near[0]
    assert exact >= 30      # 37 of the 66 pairs of this pilot; the others are the NaN case above
    # a difference at least as large as the margin cannot be shown equivalent: no n, a reason
    far = eq[eq["mean_diff"].abs() >= 0.5]
    assert len(far) and far["n_required"].isna().all() and far["note"].str.contains("not inside the margin").all()


def test_plan_command_writes_csv_figure_and_one_line_per_comparison(tmp_path, capsys, study_dir):
    out = tmp_path / "plan"
    assert main(["plan", "--dz", "0.5", "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "difference: d_z = 0.50 -> 77 subjects for power 0.8 at α = 0.000758 (Holm over 66)"
    assert lines[1].startswith("equivalence (±0.5, SD of differences 1)") and len(lines) == 3
    plan = pd.read_csv(out / "plan.csv")
    assert list(plan["n_required"]) == [77, 64]
    curves = pd.read_csv(out / "fig_power_curves.plot.csv")
    assert (out / "fig_power_curves.png").stat().st_size > 10_000
    at = curves[(curves["test"] == "difference")]
    # the curve crosses the target where plan.csv says
    assert at[at["n"] >= 77]["power"].min() >= 0.8 and at[at["n"] < 77]["power"].max() < 0.8
    # refuses to overwrite without --force; one clear error line, exit 2
    assert main(["plan", "--dz", "0.5", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "--force" in err and "Traceback" not in err
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["plan", "--pilot", str(study_dir), "--out", str(out), "--force"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert sum(ln.startswith("difference ") for ln in printed) == 66
    assert sum(ln.startswith("equivalence ") for ln in printed) == 11


@pytest.mark.parametrize("argv,needle", [
    (["plan", "--out", "X"], "give either --dz"),
    (["plan", "--dz", "0", "--out", "X"], "--dz must not be 0"),
    (["plan", "--dz", "nan", "--out", "X"], "--dz must be a finite number"),
    (["plan", "--dz", "inf", "--out", "X"], "--dz must be a finite number"),
    (["plan", "--dz", "0.5", "--power", "1.5", "--out", "X"], "--power and --alpha must be below 1"),
    (["plan", "--dz", "0.5", "--comparisons", "0", "--out", "X"], "--comparisons must be a whole number >= 1"),
    (["plan", "--dz", "0.5", "--sd-diff", "-1", "--out", "X"], "--sd-diff must be > 0"),
    (["plan", "--pilot", "no_such_folder", "--out", "X"], "no_such_folder does not exist"),
])
def test_plan_bad_input_one_line(argv, needle, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and needle in err[0]


def test_dz_ci_of_a_three_subject_pilot_widens_its_bracket():
    """With df = 2 the upper end of a large d_z's interval lies beyond t + (10 + |t|), the first bracket."""
    from scipy import stats
    lo, hi = dz_ci(-9.24, 3)
    t = -9.24 * math.sqrt(3)
    assert stats.nct.sf(t, 2, lo * math.sqrt(3)) == pytest.approx(0.025, abs=1e-8)
    assert stats.nct.sf(t, 2, hi * math.sqrt(3)) == pytest.approx(0.975, abs=1e-8)
    assert lo < -9.24 < hi < 0


def test_three_subject_pilot_plans_every_row_and_says_why_where_it_cannot(tmp_path, capsys):
    """The README's flow on 3 synthetic subjects: one pair's differences are equal up to rounding (SD ~1e-16), which
    made the d_z interval's solver meet a NaN and the whole plan stop; now that row says why and the rest is planned."""
    from analysis.synthetic import write_synthetic_study
    data = tmp_path / "D3"
    write_synthetic_study(data, 3, seed=0)
    out = tmp_path / "plan"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["plan", "--pilot", str(data), "--margin", "0.5", "--out", str(out)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert sum(ln.startswith(("difference ", "equivalence ")) for ln in printed) == 66 + 11
    plan = pd.read_csv(out / "plan.csv", keep_default_na=False, na_values=[""])
    assert (out / "fig_power_curves.png").stat().st_size > 10_000
    diff = plan[plan["test"] == "difference"]
    same = diff[(diff["sample_a"] == "foam") & (diff["sample_b"] == "soft")].iloc[0]
    assert np.isnan(same["dz"]) and np.isnan(same["n_required"])
    assert same["note"].startswith("every one of the 3 subjects gave the same difference (+0.333 rating points, SD 0)")
    # every other pair has its d_z, an interval around it and (but for d_z = 0) a sample size
    rest = diff.drop(same.name)
    assert rest["dz"].notna().all() and (rest["dz_ci_low"] <= rest["dz"]).all() and (rest["dz"] <= rest["dz_ci_high"]).all()
    assert rest["n_required"].notna().sum() >= 60
    big = rest.loc[rest["dz"].abs().idxmax()]
    assert abs(big["dz"]) > 9 and big["n_required"] == 4
    # the statsmodels cross-check of one planned n: power at n reaches 0.8, at n - 1 it does not
    r = rest[rest["n_required"].between(10, 200)].iloc[0]
    a = 0.05 / 66
    assert power_difference(r["dz"], int(r["n_required"]), a) >= 0.8 > power_difference(r["dz"], int(r["n_required"]) - 1, a)
    assert SM.power(effect_size=abs(r["dz"]), nobs=int(r["n_required"]), alpha=a) >= 0.8


def test_a_plan_row_that_cannot_be_computed_fails_alone(monkeypatch, analysed):
    """A library failure in one pair's interval leaves that row without it (said in its note), not the plan."""
    import analysis.power as power
    real = power.dz_ci
    calls = []

    def flaky(dz, n, level=0.95):
        calls.append(dz)
        if len(calls) == 2:
            raise ValueError("The function value at x=1.698e+16 is NaN; solver cannot continue.")
        return real(dz, n, level)

    monkeypatch.setattr(power, "dz_ci", flaky)
    plan = pilot_plan(analysed.matrix, "wood_on_foam", PlanSettings())
    assert len(plan) == 66 + 11
    second = plan.iloc[1]
    assert np.isnan(second["dz_ci_low"]) and np.isfinite(second["n_required"])
    assert second["note"].startswith("95 % CI of d_z not computed: the numerical solver met a value it cannot evaluate")
    assert plan.iloc[[0] + list(range(2, 66))]["dz_ci_low"].notna().all()


def test_plan_help_shows_percent_signs_as_written(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["plan", "--help"])
    assert stop.value.code == 0
    text = capsys.readouterr().out
    assert "95 % CI" in " ".join(text.split()) and "%%" not in text
