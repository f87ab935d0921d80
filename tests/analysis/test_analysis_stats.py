"""Statistics against independent computations (scipy, statsmodels, hand formulas) on generated data."""

from __future__ import annotations

import json
import warnings
from itertools import combinations
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from statsmodels.regression.linear_model import OLS
from statsmodels.stats.anova import AnovaRM
from statsmodels.stats.multitest import multipletests
from statsmodels.stats.weightstats import ttost_paired

from analysis import stats as astats
from analysis.load import AnalysisWarning
from analysis.pipeline import AnalysisConfig, analyse
from analysis.synthetic import write_synthetic_study


def _independent_means(root: Path) -> tuple[pd.DataFrame, list[str], dict]:
    """Per-subject means straight from the CSV files with pandas (no analysis code involved)."""
    frames, experience, catalog = [], {}, None
    for sess in sorted(root.glob("*/session.json")):
        info = json.loads(sess.read_text())
        experience[info["subject"]] = info["experience"]
        catalog = catalog or [c["name"] for c in info["catalog"]]
        frames.append(pd.read_csv(sess.parent / "trials.csv", dtype={"valid": str, "phase": str}))
    t = pd.concat(frames)
    t = t[(t["phase"] == "testing") & (t["valid"] == "true")]
    means = t.groupby(["subject", "sample"])["rating"].mean().unstack()
    return means, catalog, experience


def _expected_pairwise(means: pd.DataFrame, catalog: list[str], group: str) -> pd.DataFrame:
    rows = []
    for a, b in combinations(catalog, 2):
        pair = means[[a, b]].dropna()
        res = stats.ttest_rel(pair[a], pair[b])
        ci = res.confidence_interval()
        d = pair[a] - pair[b]
        rows.append({"group": group, "sample_a": a, "sample_b": b, "n": len(pair), "mean_diff": d.mean(),
                     "t": res.statistic, "df": res.df, "p": res.pvalue, "ci_low": ci.low, "ci_high": ci.high,
                     "cohen_dz": d.mean() / d.std(ddof=1)})
    out = pd.DataFrame(rows)
    out["p_holm"] = multipletests(out["p"], method="holm")[1]
    return out


def test_pairwise_equals_scipy_and_statsmodels_holm(study_dir, analysed):
    means, catalog, experience = _independent_means(study_dir)
    table = analysed.pairwise
    assert list(table.columns) == ["group", "sample_a", "sample_b", "n", "mean_diff", "t", "df", "p", "p_holm",
                                   "bf10", "ci_low", "ci_high", "cohen_dz", "wilcoxon_w", "wilcoxon_p", "wilcoxon_p_holm",
                                   "not_testable"]
    for group, sel in (("all", means), ("experienced", means[[experience[s] != "none" for s in means.index]])):
        got = table[table["group"] == group].reset_index(drop=True)
        want = _expected_pairwise(sel, catalog, group)
        assert len(got) == len(catalog) * (len(catalog) - 1) // 2
        assert list(got["sample_a"]) == list(want["sample_a"]) and list(got["sample_b"]) == list(want["sample_b"])
        assert (got["n"].to_numpy() == want["n"].to_numpy()).all()
        for col in ("mean_diff", "t", "df", "p", "p_holm", "ci_low", "ci_high", "cohen_dz"):
            np.testing.assert_allclose(got[col].to_numpy(float), want[col].to_numpy(float), rtol=1e-9, atol=1e-12,
                                       err_msg=f"{group} {col}")
    # the subject missing foam leaves its pairs with one subject fewer
    all_rows = table[table["group"] == "all"]
    assert set(all_rows[(all_rows["sample_a"] == "foam") | (all_rows["sample_b"] == "foam")]["n"]) == {19}
    assert all_rows["n"].max() == 20
    # the generated profile makes wood clearly better than foam, so the test must find it
    wf = all_rows[(all_rows["sample_a"] == "wood") & (all_rows["sample_b"] == "foam")].iloc[0]
    assert wf["p_holm"] < 1e-6 and wf["mean_diff"] > 2


def test_tost_equals_statsmodels_ttost_paired(study_dir, analysed):
    means, catalog, experience = _independent_means(study_dir)
    eq = analysed.equivalence
    assert list(eq.columns) == ["group", "sample", "reference", "n", "mean_diff", "margin", "p_lower", "p_upper",
                                "p_tost", "equivalent", "bf01"]
    got = eq[eq["group"] == "all"].set_index("sample")
    assert list(got.index) == [s for s in catalog if s != "wood_on_foam"]
    for sample in got.index:
        pair = means[[sample, "wood_on_foam"]].dropna()
        p, lower, upper = ttost_paired(pair[sample].to_numpy(), pair["wood_on_foam"].to_numpy(), -0.5, 0.5)
        row = got.loc[sample]
        assert row["n"] == len(pair)
        np.testing.assert_allclose([row["p_tost"], row["p_lower"], row["p_upper"]], [p, lower[1], upper[1]],
                                   rtol=1e-12)
        assert row["equivalent"] == (p < 0.05)
        assert row["margin"] == 0.5
    # real wood is rated far above wood on foam in the generated data: never equivalent
    assert not got.loc["wood", "equivalent"] and got.loc["wood", "p_tost"] > 0.5


def test_tost_margin_and_reference_options(complete_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # the options of the t-tests and TOST; the models read neither (not fitted: ~1 s of CPU less)
        res = analyse(complete_dir, AnalysisConfig(reference="wood", margin=3.0, group="experienced", models=False))
    assert set(res.equivalence["group"]) == {"experienced"} and set(res.pairwise["group"]) == {"experienced"}
    assert set(res.equivalence["reference"]) == {"wood"} and (res.equivalence["margin"] == 3.0).all()
    with pytest.raises(ValueError, match="reference 'marble'"):
        analyse(complete_dir, AnalysisConfig(reference="marble"))
    with pytest.raises(ValueError, match="margin"):
        AnalysisConfig(margin=0.0)


def _hand_rm_anova(y: np.ndarray) -> tuple[float, float, float]:
    """F of a one-way RM-ANOVA written out cell by cell (sums of squares with explicit loops)."""
    n, k = y.shape
    grand = sum(y[i, j] for i in range(n) for j in range(k)) / (n * k)
    col = [sum(y[i, j] for i in range(n)) / n for j in range(k)]
    row = [sum(y[i, j] for j in range(k)) / k for i in range(n)]
    ss_treat = n * sum((c - grand) ** 2 for c in col)
    ss_resid = sum((y[i, j] - row[i] - col[j] + grand) ** 2 for i in range(n) for j in range(k))
    df1, df2 = k - 1, (n - 1) * (k - 1)
    return (ss_treat / df1) / (ss_resid / df2), df1, df2


def test_anova_matches_hand_computation_and_anovarm(study_dir, analysed):
    means, catalog, experience = _independent_means(study_dir)
    complete = means[catalog].dropna()
    assert len(complete) == 19                       # S005 misses samples
    f_hand, df1, df2 = _hand_rm_anova(complete.to_numpy())
    row = analysed.anova[(analysed.anova["group"] == "all") & (analysed.anova["test"] == "rm_anova")].iloc[0]
    assert row["method"] == "statsmodels AnovaRM"
    np.testing.assert_allclose(row["statistic"], f_hand, rtol=1e-9)
    assert (row["df1"], row["df2"], row["n_subjects"]) == (df1, df2, 19)
    np.testing.assert_allclose(row["p"], stats.f.sf(f_hand, df1, df2), rtol=1e-9)
    # Greenhouse-Geisser from the eigenvalues of the covariance of orthonormal contrasts
    k = len(catalog)
    contrasts = np.linalg.qr(np.vstack([np.ones(k), np.eye(k)[:-1]]).T)[0][:, 1:]
    lam = np.linalg.eigvalsh(contrasts.T @ np.cov(complete.to_numpy(), rowvar=False) @ contrasts)
    eps = lam.sum() ** 2 / ((k - 1) * (lam ** 2).sum())
    np.testing.assert_allclose(row["epsilon_gg"], eps, rtol=1e-9)
    assert 1 / (k - 1) <= eps <= 1
    np.testing.assert_allclose(row["p_gg"], stats.f.sf(f_hand, eps * df1, eps * df2), rtol=1e-9)
    assert row["p_gg"] >= row["p"]
    fr = analysed.anova[(analysed.anova["group"] == "all") & (analysed.anova["test"] == "friedman")].iloc[0]
    want = stats.friedmanchisquare(*complete.to_numpy().T)
    np.testing.assert_allclose([fr["statistic"], fr["p"]], [want.statistic, want.pvalue], rtol=1e-12)


def test_closed_form_equals_anovarm_for_large_groups():
    rng = np.random.default_rng(5)
    y = rng.normal(size=(30, 5)) + np.array([0.0, 0.3, 0.1, 0.5, 0.2]) + rng.normal(size=(30, 1))
    long = pd.DataFrame({"s": np.repeat(np.arange(30), 5), "c": np.tile(np.arange(5), 30), "r": y.reshape(-1)})
    table = AnovaRM(long, "r", "s", within=["c"]).fit().anova_table
    f, df1, df2 = astats.rm_anova_closed_form(y)
    np.testing.assert_allclose(f, table["F Value"].iloc[0], rtol=1e-9)
    assert (df1, df2) == (table["Num DF"].iloc[0], table["Den DF"].iloc[0])
    np.testing.assert_allclose(f, _hand_rm_anova(y)[0], rtol=1e-9)


def test_exclusion_warnings_list_subjects(study_dir):
    with pytest.warns(AnalysisWarning) as record:
        res = analyse(study_dir)
    texts = [str(w.message) for w in record if issubclass(w.category, AnalysisWarning)]
    excl = [t for t in texts if "miss sample" in t]
    assert len(excl) == 1 and "S005 (foam, pulse_soft)" in excl[0]
    assert any("S006" in t and "not finished" in t for t in texts)
    assert list(res.exclusions["subject"]) == ["S005"]
    assert res.exclusions.iloc[0]["missing_samples"] == "foam;pulse_soft"
    assert texts == list(res.warnings)


def test_sample_summary_matches_pandas(study_dir, analysed):
    means, catalog, _ = _independent_means(study_dir)
    s = analysed.summary.set_index("sample")
    assert list(s.index) == catalog
    np.testing.assert_allclose(s.loc[catalog, "mean_rating"], means[catalog].mean(), rtol=1e-12)
    np.testing.assert_allclose(s.loc[catalog, "median_rating"], means[catalog].median(), rtol=1e-12)
    np.testing.assert_allclose(s.loc[catalog, "sem_rating"], means[catalog].sem(), rtol=1e-12)
    assert s.loc["foam", "n_subjects"] == 19 and s.loc["wood", "n_subjects"] == 20
    # penetration pooled over the individual taps of valid testing attempts
    frames = [pd.read_csv(p, dtype=str, keep_default_na=False) for p in sorted(study_dir.glob("*/trials.csv"))]
    t = pd.concat(frames)
    t = t[(t["phase"] == "testing") & (t["valid"] == "true") & (t["sample"] == "foam")]
    taps = np.array([float(x) for lst in t["penetration_depths_m"] for x in lst.split(";") if x])
    np.testing.assert_allclose(s.loc["foam", "penetration_mean_m"], taps.mean(), rtol=1e-9)
    np.testing.assert_allclose(s.loc["foam", "penetration_sd_m"], taps.std(ddof=1), rtol=1e-6)
    assert s.loc["foam", "penetration_mean_m"] > 5 * s.loc["wood", "penetration_mean_m"]


def test_repeated_measures_correlation_equals_ols_with_subject_dummies(study_dir, analysed):
    frames = [pd.read_csv(p, dtype={"valid": str}) for p in sorted(study_dir.glob("*/trials.csv"))]
    t = pd.concat(frames)
    t = t[(t["phase"] == "testing") & (t["valid"] == "true") & (t["sample"] == "hfam_firm")]
    dummies = pd.get_dummies(t["subject"]).to_numpy(float)
    fit = OLS(t["rating"].to_numpy(), np.column_stack([t["incoming_velocity_mean_m_s"].to_numpy(), dummies])).fit()
    row = analysed.velocity.set_index("sample").loc["hfam_firm"]
    assert row["df_rm"] == fit.df_resid
    np.testing.assert_allclose(row["p_rm"], fit.pvalues[0], rtol=1e-8)
    assert np.sign(row["r_rm"]) == np.sign(fit.params[0])
    r, p = stats.pearsonr(t["incoming_velocity_mean_m_s"], t["rating"])
    np.testing.assert_allclose([row["r"], row["p"]], [r, p], rtol=1e-8)


def test_small_groups_and_degenerate_pairs_are_reported(tmp_path):
    from analysis.report import summary_text
    # 3 subjects, all 'none': the experienced group is empty; no rating noise -> equal differences
    write_synthetic_study(tmp_path, 3, seed=1, experience=["none"] * 3, p_invalid=0.0)
    with pytest.warns(AnalysisWarning, match="group 'experienced' has 0 subject"):
        res = analyse(tmp_path)
    exp = res.pairwise[res.pairwise["group"] == "experienced"]
    assert len(exp) == 66 and exp["p"].isna().all() and exp["p_holm"].isna().all()
    assert res.anova[res.anova["group"] == "experienced"]["statistic"].isna().all()
    lines, pairs = summary_text(res, [])
    assert any("experienced**: not enough complete subjects" in ln for ln in lines)
    assert set(pairs) == {"all", "experienced"} and pairs["experienced"] == []


def test_pairs_with_sd_0_or_fewer_than_3_subjects_are_not_testable():
    """SD 0 of the differences (scipy: t = inf or ~1e15, p = 0) and n < 3 are reported as not testable: no t, p
    or d_z, never among the significant pairs (Holm over the testable ones only), hatched in Figure 4.18."""
    from analysis.stats import RatingMatrix, pairwise_ttests
    means = np.array([[5.0, 3.0, 4.0, 6.0], [6.0, 4.0, 4.5, np.nan], [4.0, 2.0, 6.0, np.nan],
                      [5.5, 3.5, 3.0, 2.0]])
    rm = RatingMatrix(np.array(["S1", "S2", "S3", "S4"]), ("a", "b", "c", "d"), means,
                      np.where(np.isnan(means), 0, 3), np.array(["none"] * 4))
    pw = pairwise_ttests(rm, "all").set_index(["sample_a", "sample_b"])
    ab = pw.loc[("a", "b")]                                  # b = a - 2 for every subject: SD 0
    assert ab["not_testable"].endswith("(SD 0)") and np.isnan(ab["t"]) and np.isnan(ab["p"])
    assert np.isnan(ab["p_holm"]) and np.isnan(ab["cohen_dz"]) and ab["mean_diff"] == 2.0
    ad = pw.loc[("a", "d")]                                  # d rated by 2 subjects only
    assert ad["n"] == 2 and "fewer than 3" in ad["not_testable"] and np.isnan(ad["p"])
    ac = pw.loc[("a", "c")]
    assert ac["not_testable"] == "" and np.isfinite(ac["p"])
    ref = stats.ttest_rel(means[:, 0], means[:, 2])
    np.testing.assert_allclose([ac["t"], ac["p"]], [ref.statistic, ref.pvalue], rtol=1e-10)
    # Holm over the testable pairs only (statsmodels)
    testable = pw[pw["not_testable"] == ""]
    np.testing.assert_allclose(testable["p_holm"], multipletests(testable["p"], method="holm")[1], rtol=1e-12)
    # Figure 4.18 hatches the not-testable cells (no colour, no star)
    import matplotlib.pyplot as plt

    from analysis import figures as F
    fig, data = F.build_pvalues(pw.reset_index(), ["a", "b", "c", "d"])
    try:
        cell = data[(data["sample_row"] == "a") & (data["sample_col"] == "b")].iloc[0]
        assert np.isnan(cell["p_holm"]) and not (isinstance(cell["stars"], str) and cell["stars"].strip("*") == ""
                                                 and cell["stars"])
        hatched = {(round(p.get_x() + 0.5), round(p.get_y() + 0.5)) for p in fig.axes[0].patches if p.get_hatch()}
        assert (1, 0) in hatched and (3, 0) in hatched and (2, 0) not in hatched   # (col, row): a-b, a-d; a-c tested
    finally:
        plt.close(fig)
