"""The report on data that break one model or test: every part fails alone, says why, and the rest is written.

Each data set is a synthetic study (:func:`analysis.synthetic.write_synthetic_study`) edited the way real data
break things: a covariate that never changes, a covariate fixed per sample, one subject, two or three subjects,
ratings all equal, missing cells, a sample rated by one subject, a sample always rated at the top of the scale.
Small catalogs (4 samples) keep each report to a few seconds.
"""

from __future__ import annotations

import contextlib
import io
import re
import warnings

import numpy as np
import pandas as pd
import pytest
from statsmodels.miscmodels.ordinal_model import OrderedModel

from analysis import figures, models, stats
from analysis.__main__ import main
from analysis.load import load_study
from analysis.synthetic import DEFAULT_SAMPLES, write_synthetic_study

FOUR = DEFAULT_SAMPLES[:4]          # wood, wood_on_foam, foam, very_firm
REF = "wood_on_foam"


def _rewrite(data, fn):
    for f in sorted(data.glob("*/trials.csv")):
        t = pd.read_csv(f, dtype=str, keep_default_na=False)
        fn(t).to_csv(f, index=False)


def _velocity(values):
    """An edit setting every attempt's incoming velocity (mean and per tap) from ``values(sample)`` (a string)."""
    def edit(t):
        n = t["n_taps"].astype(int)
        v = [values(s) for s in t["sample"]]
        t["incoming_velocity_mean_m_s"] = v
        t["incoming_velocities_m_s"] = [";".join([x] * k) for x, k in zip(v, n)]
        return t
    return edit


def _ratings(fn):
    def edit(t):
        rated = t["rating"] != ""
        t.loc[rated, "rating"] = [fn(s, r) for s, r in zip(t.loc[rated, "sample"], t.loc[rated, "rating"])]
        return t
    return edit


def constant_covariate(root):
    """The reported case: 93 subjects, 4 conditions, 5 ratings' cells missing, the velocity constant (0.1 m/s)."""
    missing = {"S010": ["foam"], "S020": ["wood"], "S030": ["foam"], "S040": ["very_firm"], "S050": ["wood"]}
    write_synthetic_study(root, 93, samples=FOUR, seed=4, missing=missing)
    _rewrite(root, _velocity(lambda s: "0.1"))


def velocity_per_sample(root):
    write_synthetic_study(root, 8, samples=FOUR, seed=9)
    _rewrite(root, _velocity(lambda s: {"wood": "0.05", "wood_on_foam": "0.07", "foam": "0.09",
                                        "very_firm": "0.11"}[s]))


def one_subject(root):
    write_synthetic_study(root, 1, samples=FOUR, seed=1)


def two_subjects(root):
    write_synthetic_study(root, 2, samples=FOUR, seed=8)


def three_subjects(root):
    write_synthetic_study(root, 3, samples=FOUR, seed=0)


def all_equal(root):
    write_synthetic_study(root, 6, samples=FOUR, seed=2)
    _rewrite(root, _ratings(lambda s, r: "4"))


def missing_cells(root):
    write_synthetic_study(root, 10, samples=FOUR, seed=6,
                          missing={"S001": ["foam", "wood"], "S002": ["very_firm"], "S003": ["wood"]})


def one_rater(root):
    write_synthetic_study(root, 8, samples=FOUR, seed=5, missing={f"S{i:03d}": ["foam"] for i in range(2, 9)})


def top_of_scale(root):
    """wood always rated 7: its log-odds are unbounded in the ordinal model (complete separation)."""
    write_synthetic_study(root, 8, samples=FOUR, seed=11)
    _rewrite(root, _ratings(lambda s, r: "7" if s == "wood" else min(r, "6")))


CASES = {
    "constant_covariate": (constant_covariate, ["incoming velocity not in the models: it does not vary (every "
                                                "attempt 0.1)"], True, True),
    "velocity_per_sample": (velocity_per_sample, ["incoming velocity not in the models: it is a combination of "
                                                  "the samples"], True, True),
    "one_subject": (one_subject, ["models not fitted: they need 2 or more subjects with valid ratings, found 1"],
                    False, False),
    "two_subjects": (two_subjects, ["Caution: 2 subject(s)"], None, None),
    "three_subjects": (three_subjects, ["Caution: 3 subject(s)"], True, None),
    "all_equal": (all_equal, ["mixed model not fitted: every attempt has the same rating (4)",
                              "ordinal model not fitted: ratings take 1 value(s); it needs 3 or more"], False, False),
    "missing_cells": (missing_cells, ["miss sample(s) and are excluded"], True, True),
    "one_rater": (one_rater, ["S002 (foam)"], True, True),
    "top_of_scale": (top_of_scale, ["ordinal model not fitted: the ratings of wood (every rating 7) are all at one "
                                    "end of the scale used"], True, False),
}


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    """Every case's report, written once: ``{case: (out folder, exit code, stdout)}``."""
    got = {}
    for name, (build, *_rest) in CASES.items():
        root = tmp_path_factory.mktemp(name)
        build(root / "data")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            buf = io.StringIO()
            with contextlib.redirect_stdout(buf):
                rc = main(["report", str(root / "data"), "--out", str(root / "out")])
        got[name] = (root / "out", rc, buf.getvalue())
    return got


@pytest.mark.parametrize("case", list(CASES))
def test_report_is_written_and_each_failed_part_says_why(case, reports):
    out, rc, printed = reports[case]
    _, needles, mixed_fitted, ordinal_fitted = CASES[case]
    assert rc == 0, printed
    md = (out / "report.md").read_text()
    html = (out / "report.html").read_text()
    for needle in needles:
        assert needle in md, (case, needle)
    for section in ("## Summary", "## Models", "## Evidence for no difference", "## Provenance"):
        assert section in md and section[3:] in html
    # the t-tests, whatever the models did: a row per pair (4 samples: 6 pairs)
    pw = pd.read_csv(out / "pairwise_ttests.csv")
    assert len(pw[pw["group"] == "all"]) == 6
    fixed = pd.read_csv(out / "models_fixed_effects.csv")
    if mixed_fitted is not None:
        assert (fixed["model"] == "mixed").any() == mixed_fitted, case
    if ordinal_fitted is not None:
        assert (fixed["model"] == "ordinal").any() == ordinal_fitted, case
    # the printed count of figures is the PNGs written (the models' figure included)
    n = int(re.search(r"wrote \d+ tables, (\d+) figures", printed).group(1))
    assert n == len(list(out.glob("*.png"))) >= 3


def test_constant_covariate_models_equal_statsmodels_without_it(reports):
    """The reported case: the ordinal model without the constant velocity is statsmodels' own fit of sample alone;
    its cut points increase and are its thresholds' cumulative form."""
    out, _, _ = reports["constant_covariate"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        study = load_study(out.parent / "data")      # the study the report analysed (its tables are not needed)
    data, samples, _ = models.attempt_data(study)
    ref = samples.index(REF)
    X, names, _ = models.design(data, samples, ref, [])
    y = data["rating"].to_numpy().astype(int)
    levels = sorted(set(y))
    own = OrderedModel(pd.Series(pd.Categorical(y, categories=levels, ordered=True)),
                       pd.DataFrame(X[:, 1:], columns=names[1:]), distr="logit")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = own.fit(method="bfgs", disp=False, maxiter=2000)
    fixed = pd.read_csv(out / "models_fixed_effects.csv").set_index(["model", "term"])
    for s in samples:
        if s != REF:
            assert fixed.loc[("ordinal", f"sample[{s}]"), "estimate"] == pytest.approx(fit.params[f"sample[{s}]"],
                                                                                       abs=2e-4)
    cuts = fixed.loc["ordinal"].filter(like="cut ", axis=0)["estimate"].to_numpy()
    np.testing.assert_allclose(cuts, own.transform_threshold_params(np.asarray(fit.params))[1:-1], atol=2e-4)
    assert np.all(np.diff(cuts) > 0) and len(cuts) == len(levels) - 1
    # and statsmodels itself stops on the column the data gave (what the report met before)
    v = data["velocity_m_s"].to_numpy()
    col = (v - v.mean()) / v.std() if v.std() > 0 else np.ones_like(v)
    with pytest.raises(ValueError, match="There should not be a constant in the model"):
        OrderedModel(pd.Series(pd.Categorical(y, categories=levels, ordered=True)),
                     pd.DataFrame(np.column_stack([X[:, 1:], col])), distr="logit")


def test_a_library_failure_in_one_model_leaves_the_other(monkeypatch, reports, tmp_path):
    """statsmodels' OrderedModel raising (its message on a constant column) is the ordinal model's note; the mixed
    model, the t-tests and the figures are still reported."""
    out, _, _ = reports["missing_cells"]

    def broken(*args, **kwargs):
        raise ValueError("There should not be a constant in the model")

    monkeypatch.setattr(models.OrderedLogit, "fit", broken)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["report", str(out.parent / "data"), "--out", str(tmp_path / "r")]) == 0
    md = (tmp_path / "r" / "report.md").read_text()
    assert ("ordinal model not fitted: a column of the model is constant or a combination of the others (e.g. a "
            "covariate that never changes) (There should not be a constant in the model)") in md
    fixed = pd.read_csv(tmp_path / "r" / "models_fixed_effects.csv")
    assert (fixed["model"] == "mixed").sum() == 4 + 1 and not (fixed["model"] == "ordinal").any()
    assert len(pd.read_csv(tmp_path / "r" / "pairwise_ttests.csv")) > 0
    assert {"fig_4_17_ratings.png", "fig_4_18_pvalues.png", "fig_4_19_penetration.png"} <= \
        {p.name for p in (tmp_path / "r").glob("*.png")}


def test_a_test_and_a_figure_that_fail_are_said_in_their_places(monkeypatch, reports, tmp_path):
    out, _, _ = reports["missing_cells"]

    def broken(*args, **kwargs):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setattr(stats, "omnibus", broken)
    monkeypatch.setattr(figures, "fig_pvalues", broken)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["report", str(out.parent / "data"), "--out", str(tmp_path / "r")]) == 0
    md = (tmp_path / "r" / "report.md").read_text()
    assert ("RM-ANOVA and Friedman test (all subjects) not computed: the model's equations have no unique "
            "solution") in md
    assert "Figure 4.18 not drawn: the model's equations have no unique solution" in md
    names = {p.name for p in (tmp_path / "r").glob("*")}
    assert "fig_4_18_pvalues.png" not in names and {"fig_4_17_ratings.png", "fig_4_19_penetration.png"} <= names
    # the other tests are still there, with their numbers
    pw = pd.read_csv(tmp_path / "r" / "pairwise_ttests.csv")
    assert pw["p"].notna().sum() >= 6
    assert len(pd.read_csv(tmp_path / "r" / "equivalence.csv")) >= 3


@pytest.mark.parametrize("case", list(CASES))
def test_plan_from_each_adversarial_pilot_is_written(case, reports, tmp_path, capsys):
    """``plan --pilot`` completes on every data set: the rows that cannot be planned say why."""
    out, _, _ = reports[case]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["plan", "--pilot", str(out.parent / "data"), "--margin", "0.5", "--out", str(tmp_path / "p")]) == 0
    plan = pd.read_csv(tmp_path / "p" / "plan.csv", keep_default_na=False, na_values=[""])
    assert len(plan) == 6 + 3 and (tmp_path / "p" / "fig_power_curves.png").exists()
    # a row has a sample size or a reason, never neither
    assert (plan["n_required"].notna() | (plan["note"].fillna("") != "")).all()
    printed = capsys.readouterr().out
    assert sum(ln.startswith(("difference ", "equivalence ")) for ln in printed.splitlines()) == 9
    if case == "one_subject":
        assert plan["n_required"].isna().all() and "1 subject(s); a pilot needs 2 or more" in printed
        assert plan["note"].str.contains("1 subject(s) rated both samples: a pilot pair needs 2 or more for an SD", regex=False).all()
    if case == "all_equal":
        assert plan[plan["test"] == "difference"]["note"].str.startswith("every one of the 6 subjects gave the same "
                                                                        "difference (+0 rating points, SD 0)").all()
