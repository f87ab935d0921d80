"""Simulated null studies for the mixed model's false-positive rate (shared by tests/analysis/test_analysis_lmm.py
and the benchmark ``null_models``).

A null study: ``n_subjects`` subjects rate 12 samples 3 times each on the 1-7 scale, every sample with the same
true mean. As in :func:`analysis.synthetic.write_synthetic_study` a rating is
``clip(rint(mu + b_subject + e), 1, 7)`` with a subject bias SD of 0.4 and an attempt noise SD by experience
(1.2 for novices, 0.5 otherwise, cycling 7:7:2), plus here each subject's own view of each sample,
``c_(subject, sample) ~ N(0, cell_sd^2)``: real raters disagree about samples, and a model blind to it
counts every attempt as an independent look at a sample effect. The attempts' mean incoming velocity
is drawn as the generator's taps (N(0.10, 0.04^2) m/s per tap, 3-8 taps) and has no effect.

Built in memory (no files), in the models' own data format (:func:`analysis.models.attempt_data`), and
fitted by the report's own functions (:func:`analysis.models.mixed_model` and :func:`mixed_tables`).
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
from scipy import stats

from analysis import models
from analysis.lmm import fit_lmm
from analysis.synthetic import DEFAULT_SAMPLES, EXPERIENCE_CYCLE, NOISE_SD, SUBJECT_BIAS_SD

SAMPLES = [s.name for s in DEFAULT_SAMPLES]
REFERENCE = SAMPLES.index("wood_on_foam")
MEAN_RATING = float(np.mean([s.mean_rating for s in DEFAULT_SAMPLES]))
CELL_SD = 0.5          # rating points: each subject's own view of a sample
ALPHA = 0.05


def null_study(seed: int, n_subjects: int = 6, cell_sd: float = CELL_SD, repetitions: int = 3) -> pd.DataFrame:
    """One null study's valid attempts: ``rating, sample, subject, velocity_m_s, grip_N`` (module docstring)."""
    rng = np.random.default_rng(seed)
    k = len(SAMPLES)
    rows = []
    for i in range(n_subjects):
        noise = NOISE_SD[EXPERIENCE_CYCLE[i % len(EXPERIENCE_CYCLE)]]
        bias = rng.normal(0.0, SUBJECT_BIAS_SD)
        view = rng.normal(0.0, cell_sd, k) if cell_sd > 0 else np.zeros(k)
        order = rng.permutation(np.repeat(np.arange(k), repetitions))
        taps = rng.integers(3, 9, order.size)
        v = np.array([np.clip(rng.normal(0.10, 0.04, n), 0.02, None).mean() for n in taps])
        y = np.clip(np.rint(MEAN_RATING + bias + view[order] + rng.normal(0.0, noise, order.size)), 1, 7)
        rows.append(pd.DataFrame({"rating": y, "sample": order, "subject": i, "velocity_m_s": v, "grip_N": np.nan}))
    return pd.concat(rows, ignore_index=True)


def contrast_pvalues(data: pd.DataFrame, covariates=("velocity_m_s",)) -> tuple[np.ndarray, np.ndarray, dict]:
    """The report's mixed model on ``data``: (p of the 66 contrasts, their Holm p, the model's info).

    NaN p-values where the model was not fitted (counted as no rejection by the callers, and counted).
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res, info, _ = models.mixed_model(data, SAMPLES, REFERENCE, list(covariates))
        if res is None:
            n = len(SAMPLES) * (len(SAMPLES) - 1) // 2
            return np.full(n, np.nan), np.full(n, np.nan), info
        _, _, contrasts = models.mixed_tables(res, info, SAMPLES, REFERENCE, data, None)
    return contrasts["p"].to_numpy(), contrasts["p_holm"].to_numpy(), info


def wald_pvalues(data: pd.DataFrame) -> np.ndarray:
    """The earlier model on ``data``: random intercept only, Wald z (as statsmodels' MixedLM reports it)."""
    k = len(SAMPLES)
    X, _, _ = models.design(data, SAMPLES, REFERENCE, [])
    fit = fit_lmm(data["rating"].to_numpy(float), X, data["subject"].to_numpy(), None, None)
    L = models._sample_contrast_matrix(k, REFERENCE, 0)
    ia, ib = np.triu_indices(k, 1)
    D = L[ia] - L[ib]
    z = (D @ fit.beta) / np.sqrt(np.einsum("ij,jk,ik->i", D, fit.cov_beta, D))
    return 2 * stats.norm.sf(np.abs(z))


def false_positive_rates(n_studies: int, n_subjects: int = 6, cell_sd: float = CELL_SD, seed0: int = 0,
                         covariates=("velocity_m_s",), wald: bool = False) -> dict:
    """The mixed model's false-positive rates over ``n_studies`` null studies at alpha = 0.05.

    Returns
    -------
    dict
        ``per_contrast``: share of all contrasts (66 per study) with p < alpha (the rate a single contrast's test
        has; contrasts of one study are correlated, so its interval is over studies: ``per_contrast_ci``, the
        95 % t interval of the per-study shares); ``first``: (rejections, studies) of one pre-chosen contrast
        (the first pair), independent across studies, with its Clopper-Pearson 95 % interval ``first_ci``;
        ``familywise``: share of studies with any Holm p < alpha; ``not_fitted``: studies the model could not
        fit; ``structures``: the structures fitted, counted; ``wald_per_contrast`` (with ``wald``): the same
        share for the earlier random-intercept model with Wald z.
    """
    shares, first, any_holm, not_fitted, wald_shares, structures = [], 0, 0, 0, [], {}
    for s in range(n_studies):
        data = null_study(seed0 + s, n_subjects, cell_sd)
        p, p_holm, info = contrast_pvalues(data, covariates)
        structures[info.get("structure", "none")] = structures.get(info.get("structure", "none"), 0) + 1
        if np.all(np.isnan(p)):
            not_fitted += 1
        shares.append(float(np.mean(p < ALPHA)))
        first += bool(p[0] < ALPHA)
        any_holm += bool(np.any(p_holm < ALPHA))
        if wald:
            wald_shares.append(float(np.mean(wald_pvalues(data) < ALPHA)))
    shares = np.array(shares)
    half = stats.t.ppf(0.975, n_studies - 1) * shares.std(ddof=1) / np.sqrt(n_studies)
    ci = stats.binomtest(first, n_studies).proportion_ci(0.95, method="exact")
    out = {"studies": n_studies, "subjects": n_subjects, "cell_sd": cell_sd, "per_contrast": float(shares.mean()),
           "per_contrast_ci": (float(shares.mean() - half), float(shares.mean() + half)),
           "first": (first, n_studies), "first_ci": (float(ci.low), float(ci.high)),
           "familywise": any_holm / n_studies, "not_fitted": not_fitted, "structures": structures}
    if wald:
        out["wald_per_contrast"] = float(np.mean(wald_shares))
    return out
