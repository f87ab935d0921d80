"""The mixed model's own REML fit and Satterthwaite degrees of freedom (analysis.lmm).

Cross-checks: a balanced split-plot design, where the REML variances are the ANOVA mean-square estimates and
the df are known exactly ((n - 1)(k - 1) for a within-subject contrast; the Welch-Satterthwaite combination
of two mean squares for a sample's mean); statsmodels' OLS on the cell means (the same t tests); statsmodels'
MixedLM (the same REML log-likelihood, fixed effects and, on a balanced design, standard errors). The
false-positive rate over simulated null studies (tests/support/null_studies.py; 500 studies in the benchmark
``null_models``).
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest
import statsmodels.formula.api as smf
from statsmodels.regression.mixed_linear_model import MixedLM, MixedLMParams, VCSpec

from analysis.lmm import NestedLMM, NotFitted, fit_lmm, satterthwaite_df

from tests.support.null_studies import false_positive_rates


def _quiet(fn, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(*args, **kwargs)


def _split_plot(n=6, k=4, r=3, seed=1, unbalanced=False, slope=False):
    rng = np.random.default_rng(seed)
    subj = np.repeat(np.arange(n), k * r)
    samp = np.tile(np.repeat(np.arange(k), r), n)
    v = rng.normal(0.0, 1.0, subj.size)
    y = (4 + rng.normal(0, 0.6, n)[subj] + rng.normal(0, 0.5, (n, k))[subj, samp] + rng.normal(0, 1.0, subj.size)
         + 0.3 * samp + (rng.normal(0.5, 0.4, n)[subj] * v if slope else 0.0))
    keep = rng.random(y.size) > 0.12 if unbalanced else np.ones(y.size, bool)
    subj, samp, v, y = subj[keep], samp[keep], v[keep], y[keep]
    X = np.column_stack([np.ones(y.size)] + [(samp == j).astype(float) for j in range(1, k)]
                        + ([v] if slope else []))
    return y, X, subj, samp, v


def _statsmodels_model(y, X, subj, cell, Z):
    groups = np.unique(subj)
    mats = [[(cell[subj == g][:, None] == np.unique(cell[subj == g])[None, :]).astype(float) for g in groups]]
    names = [[[str(c) for c in range(m.shape[1])] for m in mats[0]]]
    model = MixedLM(y, X, groups=subj, exog_re=Z, exog_vc=VCSpec(["cell"], names, mats))
    model.reml, model.cov_pen, model.fe_pen = True, None, None        # what its fit() sets before evaluating
    return model


def test_balanced_split_plot_gives_the_anova_estimates_and_exact_df():
    n, k, r = 6, 4, 3
    y, X, subj, samp, _ = _split_plot(n, k, r)
    fit = fit_lmm(y, X, subj, subj * k + samp)
    assert fit.converged and fit.varpar_names == ("G[0,0]", "cell", "residual")
    cm = np.array([[y[(subj == i) & (samp == j)].mean() for j in range(k)] for i in range(n)])
    gm = cm.mean()
    ms_s = k * r * np.sum((cm.mean(1) - gm) ** 2) / (n - 1)
    ms_sa = r * np.sum((cm - cm.mean(1)[:, None] - cm.mean(0)[None, :] + gm) ** 2) / ((n - 1) * (k - 1))
    ms_e = np.sum((y - cm[subj, samp]) ** 2) / (n * k * (r - 1))
    # REML = the ANOVA (mean-square) estimates where they are positive
    assert fit.resid_var == pytest.approx(ms_e, rel=1e-6)
    assert fit.cell_var == pytest.approx((ms_sa - ms_e) / r, rel=1e-5)
    assert fit.G[0, 0] == pytest.approx((ms_s - ms_sa) / (k * r), rel=1e-5)
    L = np.zeros((3, k))
    L[0, 1] = 1.0                   # sample 1 - sample 0
    L[1, [1, 2]] = 1.0, -1.0        # sample 1 - sample 2
    L[2, 0] = 1.0                   # the mean of sample 0
    df = satterthwaite_df(fit, L)
    # a within-subject contrast: the subject x sample mean square's (n - 1)(k - 1) = 15 df, exactly
    np.testing.assert_allclose(df[:2], (n - 1) * (k - 1), rtol=1e-6)
    # a sample's mean: var = (MS_S + (k - 1) MS_SA) / (k r n), Welch-Satterthwaite over the two mean squares
    v = ms_s + (k - 1) * ms_sa
    assert df[2] == pytest.approx(v ** 2 / (ms_s ** 2 / (n - 1) + ((k - 1) * ms_sa) ** 2 / ((n - 1) * (k - 1))),
                                  rel=1e-5)
    assert np.sqrt(L[0] @ fit.cov_beta @ L[0]) == pytest.approx(np.sqrt(2 * ms_sa / (n * r)), rel=1e-6)
    assert np.sqrt(L[2] @ fit.cov_beta @ L[2]) == pytest.approx(np.sqrt(v / (k * r * n)), rel=1e-6)
    # the same t tests from statsmodels' OLS on the cell means (subject + sample, the split plot's error term)
    cells = pd.DataFrame({"y": cm.ravel(), "subject": np.repeat(np.arange(n), k), "sample": np.tile(np.arange(k), n)})
    ols = smf.ols("y ~ C(subject) + C(sample)", cells).fit()
    want = ols.t_test("C(sample)[T.1] - C(sample)[T.2] = 0")
    t_ours = (L[1] @ fit.beta) / np.sqrt(L[1] @ fit.cov_beta @ L[1])
    assert t_ours == pytest.approx(float(np.squeeze(want.tvalue)), rel=1e-6) and ols.df_resid == (n - 1) * (k - 1)
    # and statsmodels' MixedLM of the same terms: its fit, its standard errors (on a balanced design they equal
    # (X'V^-1X)^-1, the convention used here and by lme4/lmerTest)
    model = _statsmodels_model(y, X, subj, subj * k + samp, np.ones((y.size, 1)))
    found = _quiet(model.fit, reml=True, method="powell")
    # (its Powell search stops short of the maximum, by 1e-5 here: the ANOVA estimates above are the exact
    # reference); started at our estimates its lbfgs stays there, and its standard errors are ours
    assert found.llf - 1e-9 <= fit.loglik <= found.llf + 1e-4
    start = MixedLMParams.from_components(fe_params=fit.beta, cov_re=fit.G / fit.resid_var,
                                          vcomp=np.array([fit.cell_var / fit.resid_var]))
    sm = _quiet(model.fit, reml=True, method="lbfgs", start_params=start)
    assert sm.llf == pytest.approx(fit.loglik, abs=1e-8)
    np.testing.assert_allclose(np.sqrt(np.diag(fit.cov_beta)), np.asarray(sm.bse_fe), rtol=1e-4)
    np.testing.assert_allclose(fit.beta, np.asarray(sm.fe_params), atol=1e-6)


def test_unbalanced_data_with_a_slope_have_statsmodels_likelihood():
    y, X, subj, samp, v = _split_plot(n=8, k=4, r=3, seed=3, unbalanced=True, slope=True)
    Z = np.column_stack([np.ones(y.size), v])
    cell = subj * 4 + samp
    fit = fit_lmm(y, X, subj, cell, Z)
    assert fit.converged and len(fit.varpar_names) == 5
    model = _statsmodels_model(y, X, subj, cell, Z)
    par = MixedLMParams.from_components(cov_re=fit.G / fit.resid_var, vcomp=np.array([fit.cell_var / fit.resid_var]))
    # the same function: statsmodels' REML log-likelihood at our estimates is ours
    assert model.loglike(par) == pytest.approx(fit.loglik, abs=1e-8)
    np.testing.assert_allclose(model.get_fe_params(par.cov_re, par.vcomp)[0], fit.beta, atol=1e-10)
    # and no optimiser of statsmodels finds a higher maximum
    best = max(_quiet(model.fit, reml=True, method=m).llf for m in ("lbfgs", "powell"))
    assert fit.loglik >= best - 1e-6
    # every df between 1 and the residual df; a within-subject contrast far below the residual df
    df = satterthwaite_df(fit, np.eye(X.shape[1]))
    assert np.all((df >= 1) & (df <= y.size - X.shape[1]))
    assert df[1] < 0.5 * (y.size - X.shape[1])


def test_random_intercept_only_equals_statsmodels_mixedlm():
    y, X, subj, _, _ = _split_plot(n=7, k=3, r=4, seed=5, unbalanced=True)
    fit = fit_lmm(y, X, subj)
    sm = _quiet(MixedLM(y, X, groups=subj).fit, reml=True, method="powell")
    assert fit.loglik == pytest.approx(sm.llf, abs=1e-6)
    np.testing.assert_allclose(fit.beta, np.asarray(sm.fe_params), atol=1e-5)
    assert fit.G[0, 0] == pytest.approx(float(np.asarray(sm.cov_re)[0, 0]), rel=1e-3)


def test_a_variance_at_zero_is_held_there_and_bad_designs_say_why():
    rng = np.random.default_rng(2)
    subj = np.repeat(np.arange(8), 12)
    samp = np.tile(np.repeat(np.arange(4), 3), 8)
    y = 3 + samp + rng.normal(0, 1, subj.size)               # no subject or cell variance at all
    X = np.column_stack([np.ones(y.size)] + [(samp == j).astype(float) for j in range(1, 4)])
    fit = fit_lmm(y, X, subj, subj * 4 + samp)
    held = [name for name in ("G[0,0]", "cell") if name not in fit.varpar_names]
    assert held and all(v == 0 or v < 1e-6 * fit.resid_var
                        for v in ([fit.G[0, 0]] if "G[0,0]" in held else []) + ([fit.cell_var] if "cell" in held else []))
    assert np.all(np.isfinite(satterthwaite_df(fit, np.eye(4))))
    with pytest.raises(NotFitted, match="not estimable"):
        fit_lmm(y, np.column_stack([X, X[:, 1]]), subj)
    with pytest.raises(NotFitted, match="no residual degrees of freedom"):
        fit_lmm(y[:3], X[:3], subj[:3])
    # the profiled deviance is the absolute one at the profiled residual variance
    m = NestedLMM(y, X, subj, subj * 4 + samp)
    assert m.deviance(fit.G, fit.cell_var, fit.resid_var) == pytest.approx(-2 * fit.loglik, abs=1e-8)


def test_contrasts_false_positive_rate_is_near_alpha_where_the_earlier_model_was_not():
    """50 null studies of 6 subjects whose views of the samples differ (SD 1 rating point): the contrasts' false-
    positive rate at alpha = 0.05 is 3-7 % (the benchmark null_models: 500 studies), the earlier random-intercept
    model's Wald z on the same studies above 10 %."""
    r = false_positive_rates(50, n_subjects=6, cell_sd=1.0, seed0=0, covariates=(), wald=True)
    assert r["not_fitted"] == 0
    assert 0.03 <= r["per_contrast"] <= 0.07, r
    lo, hi = r["per_contrast_ci"]
    assert lo <= 0.05 <= hi, r
    # one pre-chosen contrast per study: independent studies, an exact binomial interval
    lo, hi = r["first_ci"]
    assert lo <= 0.05 <= hi, r
    assert r["familywise"] <= 0.10
    assert r["wald_per_contrast"] > 0.10, r
