"""Issue 35: ``python -m analysis plan``: sample sizes equal statsmodels' TTestPower exactly."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pandas as pd
import pytest
from statsmodels.stats.power import TTestPower

from analysis.__main__ import main
from analysis.power import (PlanSettings, assumed_plan, dz_ci, pilot_plan, power_difference, power_tost,
                            smallest_n)

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
