"""Statistics of section 4.5.4-4.5.5 on per-subject mean realism ratings.

All tests work on the subjects x samples matrix of per-subject mean ratings
over valid testing-phase attempts (NaN where a subject has no valid attempt of
a sample). Tests that need a sample leave out the subjects missing it; the
callers report who was left out.
"""

from __future__ import annotations

import gc
import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats
from statsmodels.stats.anova import AnovaRM
from statsmodels.stats.multitest import multipletests
from statsmodels.stats.weightstats import ttost_paired

from analysis.bayes import bf10_paired
from analysis.load import Study

PAIRWISE_COLUMNS = ("group", "sample_a", "sample_b", "n", "mean_diff", "t", "df", "p", "p_holm", "bf10",
                    "ci_low", "ci_high", "cohen_dz", "wilcoxon_w", "wilcoxon_p", "wilcoxon_p_holm", "not_testable")
# a paired t-test needs at least this many subjects with both samples (n = 2 leaves one degree of freedom)
MIN_PAIRED_N = 3
EQUIVALENCE_COLUMNS = ("group", "sample", "reference", "n", "mean_diff", "margin", "p_lower", "p_upper",
                       "p_tost", "equivalent", "bf01")
ANOVA_COLUMNS = ("group", "test", "method", "n_subjects", "k_samples", "statistic", "df1", "df2", "p",
                 "epsilon_gg", "df1_gg", "df2_gg", "p_gg")
# above this many subjects AnovaRM (an OLS with one dummy column per subject) takes seconds;
# the closed form below gives the identical F for this balanced one-way design (tested)
ANOVARM_MAX_SUBJECTS = 150


@dataclass(frozen=True)
class RatingMatrix:
    """Per-subject mean ratings.

    Attributes
    ----------
    subjects : ndarray of str, shape (n_subjects,)
    samples : tuple of str, shape (k,)
        Catalog order.
    means : ndarray, shape (n_subjects, k)
        Mean rating of each subject for each sample over valid testing attempts; NaN if none.
    counts : ndarray of int, shape (n_subjects, k)
        Number of valid testing attempts behind each mean.
    experience : ndarray of str, shape (n_subjects,)
    """

    subjects: np.ndarray
    samples: tuple
    means: np.ndarray
    counts: np.ndarray
    experience: np.ndarray

    def select(self, mask: np.ndarray) -> "RatingMatrix":
        """The subjects where ``mask`` (bool, shape (n_subjects,)) is True, with their means, counts and experience."""
        return RatingMatrix(self.subjects[mask], self.samples, self.means[mask], self.counts[mask],
                            self.experience[mask])


def valid_testing_mask(trials: pd.DataFrame) -> np.ndarray:
    """Boolean mask (shape (n_rows,)) of the valid testing-phase attempts among ``trials``."""
    return (trials["phase"] == "testing").to_numpy() & trials["valid"].to_numpy()


def valid_testing(study: Study) -> pd.DataFrame:
    """Valid testing-phase attempts (rows of ``study.trials``)."""
    t = study.trials
    return t[valid_testing_mask(t)]


def codes(values, categories) -> np.ndarray:
    """Position of each value in ``categories`` (int64, -1 where absent): one integer per row.

    Parameters
    ----------
    values : pandas Series or array-like
        Names (subject, sample...); a categorical column costs only its categories.
    categories : sequence
        The order of the codes (subjects of ``study.subjects``, catalog order).

    Returns
    -------
    ndarray of int64, shape (len(values),)
    """
    return pd.Categorical(values, categories=list(categories)).codes.astype(np.int64)


def rating_matrix(study: Study) -> RatingMatrix:
    """Per-subject mean rating per sample (section 4.5.4: "average user ratings for each sample")."""
    t = study.trials
    sel = valid_testing_mask(t)
    subjects = study.subjects["subject"].to_numpy(dtype=object)
    s_code = codes(t["subject"], subjects)[sel]
    k_code = codes(t["sample"], study.catalog)[sel]
    n, k = len(subjects), len(study.catalog)
    flat = s_code * k + k_code
    sums = np.bincount(flat, weights=t["rating"].to_numpy()[sel], minlength=n * k).reshape(n, k)
    counts = np.bincount(flat, minlength=n * k).reshape(n, k)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    return RatingMatrix(subjects, tuple(study.catalog), means, counts,
                        study.subjects["experience"].to_numpy(dtype=object))


def groups(matrix: RatingMatrix, which: str = "both") -> dict:
    """Subject groups of section 4.5.5: ``all`` and ``experienced`` (experience other than none).

    ``which``: ``both`` | ``all`` | ``experienced``.
    """
    out = {}
    if which in ("both", "all"):
        out["all"] = matrix
    if which in ("both", "experienced"):
        out["experienced"] = matrix.select(matrix.experience != "none")
    if not out:
        raise ValueError(f"--group must be all, experienced or both, not {which!r}")
    return out


def missing_samples(matrix: RatingMatrix) -> dict:
    """``{subject: [samples without a valid testing attempt]}`` for subjects missing any."""
    miss = np.isnan(matrix.means)
    return {str(s): [matrix.samples[j] for j in np.flatnonzero(row)]
            for s, row in zip(matrix.subjects, miss) if row.any()}


def sample_summary(study: Study, matrix: RatingMatrix) -> pd.DataFrame:
    """Table of ``sample_summary.csv`` (Fig. 4.17, 4.19 data).

    Rating columns are over per-subject means (``ci95_*``: 95 % t-interval of their mean);
    penetration and velocity are pooled over the individual taps (lists of the valid testing attempts), in m and m/s.
    """
    t = study.trials
    sel = valid_testing_mask(t)
    k = len(matrix.samples)
    all_codes = codes(t["sample"], matrix.samples)
    code = all_codes[sel]

    def taps_of(column):
        values, row = study.taps[column]
        keep = sel[row]
        return values[keep], all_codes[row[keep]]

    pen, pen_code = taps_of("penetration_depths_m")
    vel, vel_code = taps_of("incoming_velocities_m_s")

    def pooled(values, codes):
        n = np.bincount(codes, minlength=k)
        s1 = np.bincount(codes, weights=values, minlength=k)
        s2 = np.bincount(codes, weights=values * values, minlength=k)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = s1 / n
            var = (s2 - n * mean * mean) / (n - 1)
        return n, mean, np.sqrt(np.clip(var, 0.0, None))

    n_pen, pen_mean, pen_sd = pooled(pen, pen_code)
    n_vel, vel_mean, vel_sd = pooled(vel, vel_code)
    m = matrix.means
    n_sub = np.sum(~np.isnan(m), axis=0)
    ratings = t["rating"].to_numpy()[sel]
    n_att, r_mean, r_sd = pooled(ratings, code)
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        sd = np.nanstd(m, axis=0, ddof=1) if m.shape[0] > 1 else np.full(k, np.nan)
        sem = sd / np.sqrt(n_sub)
        mean = np.nanmean(m, axis=0)
        half = stats.t.ppf(0.975, n_sub - 1) * sem      # 95 % CI of the mean (t distribution)
        median = np.nanmedian(m, axis=0)
    return pd.DataFrame({
        "sample": list(matrix.samples),
        "kind": [study.kinds.get(s, "") for s in matrix.samples],
        "n_subjects": n_sub,
        "n_attempts": n_att,
        "mean_rating": mean,
        "median_rating": median,
        "sem_rating": sem,
        "ci95_low_rating": mean - half,
        "ci95_high_rating": mean + half,
        "sd_rating_attempts": r_sd,
        "n_taps": n_pen,
        "penetration_mean_m": pen_mean,
        "penetration_sd_m": pen_sd,
        "incoming_velocity_mean_m_s": vel_mean,
        "incoming_velocity_sd_m_s": vel_sd,
    })


def _pair_indices(k: int) -> tuple[np.ndarray, np.ndarray]:
    i, j = np.triu_indices(k, 1)
    return i, j


def _holm(p: np.ndarray) -> np.ndarray:
    """Holm-adjusted p-values (statsmodels ``multipletests``); NaN p-values stay NaN and do not count."""
    out = np.full_like(p, np.nan, dtype=float)
    ok = np.isfinite(p)
    if ok.any():
        # statsmodels' Holm branch calls gc.collect(), which walks the whole heap (0.1-0.5 s with
        # pandas/scipy loaded); freezing the existing objects makes that collection trivial
        gc.freeze()
        try:
            out[ok] = multipletests(p[ok], method="holm")[1]
        finally:
            gc.unfreeze()
    return out


def pairwise_ttests(matrix: RatingMatrix, group: str) -> pd.DataFrame:
    """Paired t-tests (section 4.5.5) on per-subject means for every pair of samples, catalog order.

    For each pair (a, b) the subjects with both means are used; ``mean_diff`` = mean(a - b),
    ``t``, ``p`` (two-sided) and the 95 % CI from :func:`scipy.stats.ttest_rel`, ``p_holm`` Holm
    across the pairs of the group (statsmodels ``multipletests``), ``cohen_dz`` = mean/SD of the
    differences (eq. of Cohen's d_z).

    A pair is not testable (``not_testable`` names why; ``t``, ``p``, ``p_holm``, CI and ``cohen_dz`` NaN, so
    it is never counted among the significant pairs and Figure 4.18 hatches its cell) when fewer than
    :data:`MIN_PAIRED_N` subjects rated both, or when every subject gave the same difference (SD 0 up to
    the rounding of the per-subject means: scipy then returns t = +-inf or ~1e15 and p = 0).
    """
    m = matrix.means
    ia, ib = _pair_indices(m.shape[1])
    a, b = m[:, ia], m[:, ib]
    ok = ~(np.isnan(a) | np.isnan(b))
    n = ok.sum(axis=0)
    t = np.full(ia.size, np.nan)
    p, lo, hi, md, dz, w, pw = t.copy(), t.copy(), t.copy(), t.copy(), t.copy(), t.copy(), t.copy()
    # one vectorised ttest_rel per distinct subject set (usually a single call for all pairs); the
    # sets are told apart by their bit-packed masks as byte strings: linear in the number of subjects
    # (np.unique(ok.T, axis=0) sorts rows of n booleans, worse than linear)
    packed = np.ascontiguousarray(np.packbits(ok, axis=0).T)
    keys = packed.view(np.dtype((np.void, max(packed.shape[1], 1)))).reshape(-1) if packed.size else \
        np.zeros(ia.size, dtype="V1")
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    inverse = np.asarray(inverse).reshape(-1)
    for g, col0 in enumerate(first):
        rows = ok[:, col0]
        cols = np.flatnonzero(inverse == g)
        if rows.sum() < 2:
            continue
        aa, bb = a[rows][:, cols], b[rows][:, cols]
        with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            res = stats.ttest_rel(aa, bb, axis=0)
            ci = res.confidence_interval(0.95)
            d = aa - bb
            md[cols] = d.mean(axis=0)
            dz[cols] = md[cols] / d.std(axis=0, ddof=1)
        t[cols], p[cols], lo[cols], hi[cols] = res.statistic, res.pvalue, ci.low, ci.high
        w[cols], pw[cols] = _wilcoxon(d)
    why = _not_testable(a, b, ok, n)
    bad = why != ""
    t[bad] = p[bad] = lo[bad] = hi[bad] = dz[bad] = w[bad] = pw[bad] = np.nan
    samples = np.array(matrix.samples, dtype=object)
    return pd.DataFrame({
        "group": group, "sample_a": samples[ia], "sample_b": samples[ib], "n": n, "mean_diff": md,
        "t": t, "df": n - 1, "p": p, "p_holm": _holm(p), "bf10": bf10_paired(t, n), "ci_low": lo, "ci_high": hi,
        "cohen_dz": dz, "wilcoxon_w": w, "wilcoxon_p": pw, "wilcoxon_p_holm": _holm(pw),
        "not_testable": why,
    }, columns=list(PAIRWISE_COLUMNS))


#: scipy's ``wilcoxon(method="auto")`` takes the p of a sign-flip permutation test when the differences have
#: ties or zeros and there are at most this many (2^13 sign patterns fit its default 9999 resamples: exact)
_PERMUTATION_MAX_N = 13


def _wilcoxon(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Wilcoxon signed-rank statistic and two-sided p of each column of differences ``d`` (n, m).

    Columns whose differences are all zero have no test (NaN): scipy would divide by zero.

    The values are scipy's ``stats.wilcoxon(d, axis=0, zero_method="wilcox")`` (method ``"auto"``). Where
    that takes its exact permutation test (ties or zeros, at most :data:`_PERMUTATION_MAX_N` subjects) the
    same test is run here through ``stats.permutation_test`` with a statistic vectorised over the 2^n sign
    patterns and all pairs (:func:`_signed_rank_sum`): scipy's own call evaluates it once per pattern and
    pair in Python (~55 s for the 66 pairs of 12 subjects, against ~0.1 s here). The sums of mid-ranks are
    exact in floating point, so the p-values are scipy's to the last bit.
    """
    w, p = np.full(d.shape[1], np.nan), np.full(d.shape[1], np.nan)
    some = np.any(d != 0, axis=0)
    if some.any():
        x = d[:, some]
        with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
            warnings.simplefilter("ignore", UserWarning)     # "exact p not available with ties": it says so itself
            warnings.simplefilter("ignore", RuntimeWarning)
            if _permutation_p_in_scipy(x):
                # the statistic min(R+, R-) does not depend on how p is found
                w[some] = stats.wilcoxon(x, axis=0, zero_method="wilcox", method="asymptotic").statistic
                p[some] = stats.permutation_test((x,), _signed_rank_sum, permutation_type="samples", vectorized=True,
                                                 n_resamples=9999, alternative="two-sided", axis=0).pvalue
            else:
                res = stats.wilcoxon(x, axis=0, zero_method="wilcox")
                w[some], p[some] = res.statistic, res.pvalue
    return w, p


def _permutation_p_in_scipy(x: np.ndarray) -> bool:
    """Whether ``stats.wilcoxon(x, axis=0, method="auto")`` takes its p from a permutation test: ties in
    any column's absolute differences, or any zero, with at most :data:`_PERMUTATION_MAX_N` rows (its rule,
    decided once for the whole array)."""
    if x.shape[0] > _PERMUTATION_MAX_N:
        return False
    a = np.sort(np.abs(x), axis=0)
    return bool(np.any(x == 0) or np.any(a[1:] == a[:-1]))


def _signed_rank_sum(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """R+ of the Wilcoxon signed-rank test along ``axis``: the sum of the mid-ranks of ``|x|`` over the
    positive ``x``, zeros dropped before ranking (``zero_method="wilcox"``); scipy's statistic of its
    permutation test, for any leading shape."""
    x = np.moveaxis(x, axis, -1)
    ranks = stats.rankdata(np.where(x == 0, np.nan, np.abs(x)), axis=-1, nan_policy="omit")
    return np.sum(np.where(x > 0, ranks, 0.0), axis=-1)


def _not_testable(a: np.ndarray, b: np.ndarray, ok: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Why each pair's paired t-test cannot be made ("" if it can): too few subjects, or differences all equal.

    ``a``, ``b``: (subjects, pairs) per-subject means; ``ok``: both present; ``n``: ``ok.sum(axis=0)``.
    "All equal" allows the rounding of means of a few ratings: SD <= 1e-9 x (1 + |mean difference|).
    """
    d = np.where(ok, a - b, np.nan)
    with warnings.catch_warnings(), np.errstate(invalid="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        sd = np.nanstd(d, axis=0, ddof=1) if d.size else np.full(n.shape, np.nan)
        mean = np.nanmean(d, axis=0) if d.size else np.full(n.shape, np.nan)
    why = np.full(n.shape, "", dtype=object)
    flat = (n >= MIN_PAIRED_N) & ~(sd > 1e-9 * (1.0 + np.abs(mean)))
    why[flat] = "not testable: every subject gave the same difference (SD 0)"
    why[n < MIN_PAIRED_N] = f"not testable: fewer than {MIN_PAIRED_N} subjects rated both"
    return why


def greenhouse_geisser_epsilon(y: np.ndarray) -> float:
    """Greenhouse-Geisser epsilon of a complete subjects x conditions matrix ``y`` (n, k).

    epsilon = tr(S)^2 / ((k - 1) tr(S S)) with S the double-centred covariance matrix of the
    conditions (Box 1954; Greenhouse & Geisser 1959); 1/(k-1) <= epsilon <= 1.
    """
    k = y.shape[1]
    cov = np.cov(y, rowvar=False)
    c = np.eye(k) - 1.0 / k
    s = c @ cov @ c
    denom = (k - 1) * np.sum(s * s)
    return float(np.trace(s) ** 2 / denom) if denom > 0 else float("nan")


def rm_anova_closed_form(y: np.ndarray) -> tuple[float, float, float]:
    """One-way repeated-measures ANOVA F of a complete (n, k) matrix.

    F = [SS_cond/(k-1)] / [SS_err/((k-1)(n-1))], SS_err = SS_total - SS_subj - SS_cond.
    Returns (F, df1, df2).
    """
    n, k = y.shape
    grand = y.mean()
    ss_cond = n * np.sum((y.mean(axis=0) - grand) ** 2)
    ss_subj = k * np.sum((y.mean(axis=1) - grand) ** 2)
    ss_err = np.sum((y - grand) ** 2) - ss_subj - ss_cond
    df1, df2 = k - 1, (k - 1) * (n - 1)
    return float((ss_cond / df1) / (ss_err / df2)) if ss_err > 0 else float("nan"), float(df1), float(df2)


def omnibus(matrix: RatingMatrix, group: str) -> pd.DataFrame:
    """Repeated-measures ANOVA over samples (with Greenhouse-Geisser correction) and Friedman test.

    Uses the subjects with a mean for every sample (balanced data). AnovaRM from statsmodels for
    up to :data:`ANOVARM_MAX_SUBJECTS` subjects, above that the identical closed form.
    """
    complete = ~np.isnan(matrix.means).any(axis=1)
    y = matrix.means[complete]
    n, k = y.shape
    rows = []
    base = {"group": group, "n_subjects": n, "k_samples": k}
    if n < 2 or k < 2:
        nan = float("nan")
        for test in ("rm_anova", "friedman"):
            rows.append(base | {"test": test, "method": "not enough complete subjects", "statistic": nan,
                                "df1": nan, "df2": nan, "p": nan, "epsilon_gg": nan, "df1_gg": nan,
                                "df2_gg": nan, "p_gg": nan})
        return pd.DataFrame(rows, columns=list(ANOVA_COLUMNS))
    if n <= ANOVARM_MAX_SUBJECTS:
        long = pd.DataFrame({"subject": np.repeat(np.arange(n), k), "sample": np.tile(np.arange(k), n),
                             "rating": y.reshape(-1)})
        table = AnovaRM(long, "rating", "subject", within=["sample"]).fit().anova_table
        f_val, df1, df2 = (float(table.iloc[0][c]) for c in ("F Value", "Num DF", "Den DF"))
        method = "statsmodels AnovaRM"
    else:
        f_val, df1, df2 = rm_anova_closed_form(y)
        method = "closed form (equals AnovaRM for this balanced design)"
    p = float(stats.f.sf(f_val, df1, df2))
    eps = greenhouse_geisser_epsilon(y)
    df1g, df2g = eps * df1, eps * df2
    rows.append(base | {"test": "rm_anova", "method": method, "statistic": f_val, "df1": df1, "df2": df2, "p": p,
                        "epsilon_gg": eps, "df1_gg": df1g, "df2_gg": df2g,
                        "p_gg": float(stats.f.sf(f_val, df1g, df2g))})
    fr = stats.friedmanchisquare(*y.T)
    rows.append(base | {"test": "friedman", "method": "scipy friedmanchisquare", "statistic": float(fr.statistic),
                        "df1": float(k - 1), "df2": float("nan"), "p": float(fr.pvalue), "epsilon_gg": float("nan"),
                        "df1_gg": float("nan"), "df2_gg": float("nan"), "p_gg": float("nan")})
    return pd.DataFrame(rows, columns=list(ANOVA_COLUMNS))


def equivalence(matrix: RatingMatrix, group: str, reference: str, margin: float,
                alpha: float = 0.05) -> pd.DataFrame:
    """Paired TOST of every sample against ``reference`` with equivalence bounds +-``margin`` rating points.

    ``mean_diff`` = mean(sample - reference); ``p_lower`` tests H0: diff <= -margin, ``p_upper``
    H0: diff >= +margin (statsmodels ``ttost_paired``); ``p_tost`` = max of the two;
    ``equivalent`` = p_tost < alpha. ``bf01`` = 1 / BF10 of the paired t-test of the same differences
    (JZS prior, Rouder et al. 2009, r = 0.707): the evidence for no difference at all (> 3: moderate,
    > 10: strong), the Bayesian companion of the TOST's bounded question.
    """
    if reference not in matrix.samples:
        raise ValueError(f"--reference {reference!r} is not a sample of the catalog ({', '.join(matrix.samples)})")
    if not margin > 0:
        raise ValueError(f"--margin must be > 0 rating points, got {margin}")
    r = matrix.samples.index(reference)
    ref = matrix.means[:, r]
    rows = []
    for j, name in enumerate(matrix.samples):
        if j == r:
            continue
        x = matrix.means[:, j]
        ok = ~(np.isnan(x) | np.isnan(ref))
        n = int(ok.sum())
        row = {"group": group, "sample": name, "reference": reference, "n": n, "margin": margin}
        if n < 2:
            rows.append(row | {"mean_diff": float(np.mean(x[ok] - ref[ok])) if n else np.nan, "p_lower": np.nan,
                               "p_upper": np.nan, "p_tost": np.nan, "equivalent": False, "bf01": np.nan})
            continue
        with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            p_tost, lower, upper = ttost_paired(x[ok], ref[ok], -margin, margin)
            t_diff = stats.ttest_rel(x[ok], ref[ok]).statistic
        rows.append(row | {"mean_diff": float(np.mean(x[ok] - ref[ok])), "p_lower": float(lower[1]),
                           "p_upper": float(upper[1]), "p_tost": float(p_tost),
                           "equivalent": bool(p_tost < alpha), "bf01": float(1.0 / bf10_paired(t_diff, n)[0])})
    return pd.DataFrame(rows, columns=list(EQUIVALENCE_COLUMNS))


def _pearson(x: np.ndarray, y: np.ndarray, dof: int) -> tuple[float, float]:
    """Correlation of centred vectors and its two-sided p with ``dof`` degrees of freedom."""
    sxx, syy = float(np.dot(x, x)), float(np.dot(y, y))
    if sxx <= 0 or syy <= 0 or dof < 1:
        return float("nan"), float("nan")
    r = float(np.dot(x, y) / np.sqrt(sxx * syy))
    r = max(-1.0, min(1.0, r))
    if abs(r) == 1.0:
        return r, 0.0
    t = r * np.sqrt(dof / (1 - r * r))
    return r, float(2 * stats.t.sf(abs(t), dof))


def _center(values: np.ndarray, codes: np.ndarray) -> np.ndarray:
    n = np.bincount(codes)
    means = np.bincount(codes, weights=values) / np.maximum(n, 1)
    return values - means[codes]


def velocity_rating(study: Study) -> pd.DataFrame:
    """Incoming velocity vs rating (section 4.5.4).

    Per sample: Pearson correlation across valid testing attempts (``r``, ``p``, pooled over
    subjects) and the repeated-measures correlation across subjects (``r_rm``, ``p_rm``,
    ``df_rm``; Bakdash & Marusich 2017: correlation after removing each subject's mean,
    df = N - n_subjects - 1). The row ``sample = (all)`` is the rm correlation with each
    subject x sample cell centred (so sample effects do not count).
    """
    t = study.trials
    sel = valid_testing_mask(t)
    v = t["incoming_velocity_mean_m_s"].to_numpy()[sel]
    y = t["rating"].to_numpy()[sel]
    keep = np.isfinite(v) & np.isfinite(y)
    v, y = v[keep], y[keep]
    # subjects and samples as integer labels (only which rows share one matters: groups are bincounts)
    subj = codes(t["subject"], study.subjects["subject"])[sel][keep]
    samp = codes(t["sample"], study.catalog)[sel][keep]
    rows = []
    for j, name in enumerate(study.catalog):
        sel = samp == j
        n = int(sel.sum())
        r, p = _pearson(v[sel] - v[sel].mean(), y[sel] - y[sel].mean(), n - 2) if n > 2 else (np.nan, np.nan)
        s_codes = subj[sel]
        n_s = int(np.count_nonzero(np.bincount(s_codes)))
        dof = n - n_s - 1
        if n and dof >= 1:
            r_rm, p_rm = _pearson(_center(v[sel], s_codes), _center(y[sel], s_codes), dof)
        else:
            r_rm, p_rm = np.nan, np.nan
        rows.append({"sample": name, "n_attempts": n, "n_subjects": n_s, "r": r, "p": p,
                     "r_rm": r_rm, "df_rm": dof, "p_rm": p_rm})
    cells = subj * len(study.catalog) + samp
    n, g = len(v), int(np.count_nonzero(np.bincount(cells)))
    dof = n - g - 1
    r_rm, p_rm = _pearson(_center(v, cells), _center(y, cells), dof) if dof >= 1 else (np.nan, np.nan)
    r, p = _pearson(v - v.mean(), y - y.mean(), n - 2) if n > 2 else (np.nan, np.nan)
    rows.append({"sample": "(all)", "n_attempts": n, "n_subjects": int(np.count_nonzero(np.bincount(subj))),
                 "r": r, "p": p,
                 "r_rm": r_rm, "df_rm": dof, "p_rm": p_rm})
    return pd.DataFrame(rows)


def attempt_counts(study: Study) -> pd.DataFrame:
    """Testing-phase attempts per subject: valid, saturated, rejected, overpowered (what was excluded and why).

    One row per subject with testing attempts, in the order of their first testing attempt.
    """
    t = study.trials
    testing = (t["phase"] == "testing").to_numpy()
    subjects = study.subjects["subject"].to_numpy(dtype=object)
    code = codes(t["subject"], subjects)[testing]
    flags = {c: t[c].to_numpy()[testing] for c in ("valid", "saturated", "rejected", "overpowered")}
    present, first = np.unique(code, return_index=True)
    order = present[np.argsort(first, kind="stable")]        # subjects by their first testing attempt
    n = len(subjects)

    def count(mask=None):
        return np.bincount(code if mask is None else code[mask], minlength=n)[order].astype(np.int64)

    other = ~(flags["valid"] | flags["saturated"] | flags["rejected"] | flags["overpowered"])
    return pd.DataFrame({"subject": subjects[order], "attempts": count(),
                         **{c: count(flags[c]) for c in ("valid", "saturated", "rejected", "overpowered")},
                         "invalid_other": count(other)})
