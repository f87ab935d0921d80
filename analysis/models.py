"""Ratings modelled as what they are: a linear mixed model and an ordinal model of every attempt.

The paired t-tests of :mod:`analysis.stats` average each subject's attempts first. The models here use
every valid testing attempt, so unbalanced cells (redraws, missed samples) weigh as much as they hold,
and the tap-to-tap incoming velocity enters as a covariate:

* **linear mixed model** (:mod:`analysis.lmm`, REML): ``rating ~ sample + velocity (+ grip)`` with a
  random intercept per subject, a random subject x sample term (each subject's own view of each sample,
  lme4's ``(1 | subject:sample)``) and, where the data support it, a random slope of velocity;
  estimated marginal means (EMMs) per sample at the mean velocity, every pairwise contrast, with
  Satterthwaite degrees of freedom (t tests, Holm across the pairs), set beside the paired t-tests;
* **ordinal model** (statsmodels ``OrderedModel``, proportional odds, logit link): the same fixed
  effects; subjects enter through cluster-robust (sandwich) standard errors by subject, with t tests on
  subjects - 1 degrees of freedom (Cameron & Miller 2015: a sandwich from few clusters is too small and
  its z tests too liberal), so the coefficients and the predicted probability of each rating per sample
  are population-averaged (statsmodels has no random-effects ordinal model); its cut points are printed
  as cut points (increasing), with delta-method standard errors.

Every failure becomes a one-line note (:attr:`ModelResults.notes`) naming the model, never an
exception: one subject, a sample nobody rated, a covariate that does not vary, ratings that do not
vary, a fit that does not converge, or anything a library raises (:func:`analysis.failures.attempt`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats as sps
from statsmodels.tools.sm_exceptions import ConvergenceWarning

from analysis.failures import reason
from analysis.lmm import NotFitted, fit_lmm, satterthwaite_df
from analysis.ordinal import OrderedLogit
from analysis.stats import _holm, codes, valid_testing_mask

#: above this many subjects the models are skipped (said in the report): the tables of the paired tests
#: stay fast at 10,000 subjects, MixedLM's cost grows with the number of subjects and attempts
MODELS_MAX_SUBJECTS = 400
#: a random-slope variance below this share of the residual variance counts as on the boundary (zero):
#: the data do not support a random slope, and the random-intercept model is reported
SLOPE_VARIANCE_FLOOR = 1e-6
#: the random slope is kept where a likelihood-ratio test of its variance gives p below this (Matuschek, Kliegl,
#: Vasishth, Baayen & Bates 2017: random terms chosen at 0.2 keep the false-positive rate at alpha with more power
#: than keeping every term; a near-zero slope variance kept anyway made the Satterthwaite df of some null
#: studies' contrasts fall to 4, and the contrasts conservative)
SLOPE_TEST_ALPHA = 0.2
#: the per-attempt grip column (N) used when the study table has it: the study runner keeps grip in the traces
#: only and the loader reads the study's own columns, so today the report says grip is not in the models
GRIP_COLUMN = "grip_mean_N"
RATING_LEVELS = tuple(range(1, 8))
#: below this many subjects the report cautions that the models' variances rest on few subjects (the
#: Satterthwaite df keep the false-positive rate near alpha down to 3 subjects in the simulated studies of
#: docs/analysis.md, but the subjects' variances, and so every interval, are estimated from few people)
CAUTION_SUBJECTS = 10
#: a covariate whose SD is below this share of its mean magnitude does not vary (a column of 0.1 m/s written
#: as floats has an SD of ~1e-17, not 0, and scaled by it became a constant column)
CONSTANT_RELATIVE_SD = 1e-9

FIXED_COLUMNS = ("model", "term", "estimate", "se", "df", "t", "p", "ci_low", "ci_high")
EMM_COLUMNS = ("sample", "n_attempts", "emm", "se", "df", "ci_low", "ci_high")
CONTRAST_COLUMNS = ("sample_a", "sample_b", "estimate", "se", "df", "t", "p", "p_holm", "ci_low", "ci_high",
                    "ttest_mean_diff", "ttest_p_holm", "same_direction")
PROB_COLUMNS = ("sample", "rating", "p_model", "p_observed", "n_attempts")


@dataclass(frozen=True)
class ModelResults:
    """Both models' tables and what was fitted, with a one-line note for every fallback or failure.

    Attributes
    ----------
    fixed : DataFrame
        Fixed effects of both models (``FIXED_COLUMNS``: estimate, SE, df, t, p, interval): rating points
        for ``mixed`` (Satterthwaite df), log-odds of a higher rating for ``ordinal`` (t on subjects - 1 df),
        and the ordinal model's cut points (``cut a|b``, increasing).
    emm : DataFrame
        Mixed-model estimated marginal mean rating per sample at the mean velocity (``EMM_COLUMNS``).
    contrasts : DataFrame
        Mixed-model pairwise differences a - b in rating points (Satterthwaite t tests, Holm-adjusted),
        beside the paired t-tests.
    probabilities : DataFrame
        Ordinal model: probability of each rating 1-7 per sample at the mean velocity, and the observed share.
    mixed : dict
        ``fitted`` (bool), ``structure``, ``covariates``, ``n_attempts``, ``n_subjects``, ``converged``,
        ``variances``, ``df_method``.
    ordinal : dict
        ``fitted`` (bool), ``covariates``, ``n_attempts``, ``converged``, ``cov_type``, ``df``.
    notes : list of str
        Plain one-line reasons: left-out samples or covariates, fallbacks, failures, skips.
    """

    fixed: pd.DataFrame
    emm: pd.DataFrame
    contrasts: pd.DataFrame
    probabilities: pd.DataFrame
    mixed: dict = field(default_factory=dict)
    ordinal: dict = field(default_factory=dict)
    notes: tuple = ()


def _empty(columns) -> pd.DataFrame:
    return pd.DataFrame(columns=list(columns))


def attempt_data(study, max_subjects: int = MODELS_MAX_SUBJECTS) -> tuple[pd.DataFrame | None, list, list[str]]:
    """The valid testing attempts as model data: ``rating, sample (code), subject (code), velocity_m_s, grip_N``.

    Parameters
    ----------
    study : analysis.load.Study
    max_subjects : int
        Above this many subjects with valid attempts, no data (a note says the models were skipped).

    Returns
    -------
    data : DataFrame or None
        One row per valid testing attempt with a rating; None when no model can be fitted.
    samples : list of str
        Samples present, in catalog order (the codes of ``data['sample']`` index it).
    notes : list of str
        Why samples, covariates or the whole models were left out.
    """
    if len(study.subjects) > max_subjects:      # before touching the (large) trials table
        return None, [], [f"models skipped: {len(study.subjects)} subjects is above the models' limit of "
                          f"{max_subjects} (the mixed model's cost grows with subjects and attempts; the paired tests "
                          "above use every subject)"]
    t = study.trials
    sel = valid_testing_mask(t)
    rating = t["rating"].to_numpy(dtype=float)[sel]
    subject = codes(t["subject"], study.subjects["subject"])[sel]
    sample = codes(t["sample"], study.catalog)[sel]
    velocity = t["incoming_velocity_mean_m_s"].to_numpy(dtype=float)[sel]
    grip = t[GRIP_COLUMN].to_numpy(dtype=float)[sel] if GRIP_COLUMN in t.columns else np.full(rating.size, np.nan)
    ok = np.isfinite(rating) & (sample >= 0) & (subject >= 0)
    notes = []
    n_subjects = np.unique(subject[ok]).size
    if n_subjects < 2:
        return None, [], [f"models not fitted: they need 2 or more subjects with valid ratings, found {n_subjects}"]
    if n_subjects > max_subjects:
        return None, [], [f"models skipped: {n_subjects} subjects is above the models' limit of {max_subjects} "
                          "(the mixed model's cost grows with subjects and attempts; the paired tests above use "
                          "every subject)"]
    present = np.bincount(sample[ok], minlength=len(study.catalog)) > 0
    missing = [s for s, p in zip(study.catalog, present) if not p]
    if missing:
        notes.append(f"left out of the models: {', '.join(missing)} (no valid rating by any subject)")
    samples = [s for s, p in zip(study.catalog, present) if p]
    if len(samples) < 2:
        return None, [], notes + [f"models not fitted: they need 2 or more rated samples, found {len(samples)}"]
    remap = np.cumsum(present) - 1
    data = pd.DataFrame({"rating": rating[ok], "sample": remap[sample[ok]], "subject": subject[ok],
                         "velocity_m_s": velocity[ok], "grip_N": grip[ok]})
    return data, samples, notes


def _covariates(data: pd.DataFrame) -> tuple[list[str], pd.DataFrame, list[str]]:
    """Which covariates enter (velocity, grip) and the rows kept; notes say what was left out and why."""
    notes, use = [], []
    for col, label, why_absent in (("velocity_m_s", "incoming velocity", "the velocity column is empty (NaN)"),
                                   ("grip_N", "grip", "the study records no per-attempt grip (trials.csv has no "
                                                      f"{GRIP_COLUMN} column; the traces' grip_N is per tap)")):
        values = data[col].to_numpy(dtype=float)
        finite = np.isfinite(values)
        if not finite.any():
            notes.append(f"{label} not in the models: {why_absent}")
            continue
        if np.std(values[finite]) <= CONSTANT_RELATIVE_SD * max(np.mean(np.abs(values[finite])), 1e-300):
            notes.append(f"{label} not in the models: it does not vary (every attempt {values[finite][0]:.4g})")
            continue
        use.append(col)
    keep = np.all(np.isfinite(data[use].to_numpy(dtype=float)), axis=1) if use else np.ones(len(data), bool)
    if (~keep).any():
        notes.append(f"{int((~keep).sum())} attempt(s) without a value of {', '.join(use)} left out of the models")
    return use, data[keep].reset_index(drop=True), notes


def _present(data: pd.DataFrame, samples: list) -> tuple[pd.DataFrame, list, list[str]]:
    """The samples still holding attempts once rows were left out (a covariate's missing values), re-coded."""
    present = np.bincount(data["sample"].to_numpy(), minlength=len(samples)) > 0
    if present.all():
        return data, samples, []
    gone = [s for s, p in zip(samples, present) if not p]
    remap = np.cumsum(present) - 1
    data = data.assign(sample=remap[data["sample"].to_numpy()])
    return data, [s for s, p in zip(samples, present) if p], \
        [f"left out of the models: {', '.join(gone)} (no attempt with every covariate recorded)"]


def design(data: pd.DataFrame, samples: list, reference: int, covariates: list) -> tuple[np.ndarray, list, dict]:
    """Fixed-effect design: treatment coding against ``reference`` plus the centred covariates.

    Returns
    -------
    X : ndarray, shape (n_attempts, 1 + (k - 1) + len(covariates))
        Intercept (the reference sample at the covariates' means), one dummy per other sample,
        covariates centred at their means (so EMMs are at the mean velocity and grip) and divided by
        their SD (velocities of ~0.1 m/s beside 0/1 dummies left the optimisers ill-conditioned; the
        coefficients are converted back to SI units by :func:`_to_si`).
    names : list of str
        Column names.
    centres : dict
        Mean and SD of each covariate (SI units): ``{name: (mean, sd)}``.
    """
    k = len(samples)
    code = data["sample"].to_numpy()
    others = [j for j in range(k) if j != reference]
    dummies = (code[:, None] == np.array(others, dtype=int)[None, :]).astype(float)
    centres = {c: (float(data[c].mean()), float(data[c].std())) for c in covariates}
    cov = np.column_stack([(data[c].to_numpy() - centres[c][0]) / centres[c][1] for c in covariates]) if covariates else \
        np.empty((len(data), 0))
    X = np.column_stack([np.ones(len(data)), dummies, cov])
    names = ["intercept"] + [f"sample[{samples[j]}]" for j in others] + covariates
    return X, names, centres


def _estimable(data: pd.DataFrame, samples: list, reference: int, covariates: list) -> tuple[list, list[str]]:
    """The covariates that leave the design of full column rank; a note for each dropped one.

    A covariate that is a combination of the samples (each sample tapped at its own fixed velocity, say)
    makes the fixed effects non-unique: statsmodels' OrderedModel then stops with "There should not be a
    constant in the model" and the mixed model's equations are singular. Such a covariate is left out, said.
    """
    notes, use = [], list(covariates)
    for c in list(covariates):
        X, _, _ = design(data, samples, reference, use)
        if np.linalg.matrix_rank(X) == X.shape[1]:
            break
        trial = [u for u in use if u != c]
        Xt, _, _ = design(data, samples, reference, trial)
        if np.linalg.matrix_rank(Xt) == Xt.shape[1]:
            label = {"velocity_m_s": "incoming velocity", "grip_N": "grip"}.get(c, c)
            notes.append(f"{label} not in the models: it is a combination of the samples (e.g. every attempt of a "
                         "sample at the same value), so its effect cannot be told from theirs")
            use = trial
    return use, notes


def _to_si(table: pd.DataFrame, centres: dict) -> pd.DataFrame:
    """Covariate rows of a coefficient table from per-SD units back to per-SI-unit (rating or log-odds per m/s, per N)."""
    for name, (_, sd) in centres.items():
        row = table["term"] == name
        table.loc[row, ["estimate", "se", "ci_low", "ci_high"]] /= sd
    return table


def _sample_contrast_matrix(k: int, reference: int, n_cov: int) -> np.ndarray:
    """Rows L with L @ beta = EMM of each sample (covariates at their means), shape (k, 1 + k - 1 + n_cov)."""
    L = np.zeros((k, k + n_cov))
    L[:, 0] = 1.0
    others = [j for j in range(k) if j != reference]
    for col, j in enumerate(others, start=1):
        L[j, col] = 1.0
    return L


def _structure(fit, slope: bool) -> str:
    """The random-effects structure as fitted, in words (terms estimated at zero left out)."""
    parts = ["random intercept"] if fit.G[0, 0] > 0 else []
    if fit.cell_var > 0:
        parts.append("subject × sample")
    if slope:
        parts.append("velocity slope")
    return " + ".join(parts) if parts else "none (every variance at zero: least squares)"


def mixed_model(data: pd.DataFrame, samples: list, reference: int, covariates: list):
    """Fit the mixed model: random intercept, subject x sample term, and a random slope of velocity where supported.

    The slope is kept where a REML likelihood-ratio test of its variance (against the model without it) gives
    p < :data:`SLOPE_TEST_ALPHA`; it is dropped (with a note saying why) when that test does not support it,
    its fit does not converge, its variance is at zero (on the boundary: the subjects' velocity effects do
    not differ measurably), or a subject has fewer than 3 attempts. The subject x sample term needs a subject to rate some sample more than
    once (else it cannot be told from the attempts' noise). Variances estimated at zero are kept at zero
    and said (the model is then the simpler one without them).

    Returns
    -------
    result : analysis.lmm.LMMFit or None
    info : dict
        ``structure`` (words), ``converged``, ``fitted``, ``n_attempts``, ``n_subjects``, ``covariates``,
        ``centres``, ``names``, ``variances`` (subject, subject x sample, residual, velocity slope SD in
        rating/(m/s)), ``df_method``.
    notes : list of str
        Each fallback and why.
    """
    y = data["rating"].to_numpy(dtype=float)
    X, names, centres = design(data, samples, reference, covariates)
    subject = data["subject"].to_numpy()
    cell = subject.astype(np.int64) * len(samples) + data["sample"].to_numpy()
    info = {"fitted": False, "covariates": covariates, "names": names, "centres": centres,
            "n_attempts": len(data), "n_subjects": int(np.unique(subject).size), "structure": "none",
            "converged": False}
    notes = []
    instead = "; its estimates are not reported: the paired t-tests above are the result to use"
    if np.ptp(y) == 0:
        return None, info, notes + [f"mixed model not fitted: every attempt has the same rating ({y[0]:g}): there "
                                    f"is no variation to model{instead}"]
    resid = y - X @ np.linalg.lstsq(X, y, rcond=None)[0]
    if np.max(np.abs(resid)) < 1e-6 * np.ptp(y):       # ratings are whole numbers: 1e-6 is rounding, not variation
        return None, info, notes + ["mixed model not fitted: the samples (and covariates) account for every rating "
                                    "exactly (each sample always rated the same): there is no attempt-to-attempt "
                                    f"variation to model{instead}"]
    use_cell = np.bincount(np.unique(cell, return_inverse=True)[1]).max() >= 2
    if not use_cell:
        notes.append("mixed model: no subject × sample term (every subject rated each sample once: its variance "
                     "cannot be told from the attempts' noise)")
    cell_arg = cell if use_cell else None
    attempts_per_subject = np.bincount(subject)[np.unique(subject)]
    drop = "mixed model: random slope of velocity dropped"
    try:
        fit = fit_lmm(y, X, subject, cell_arg, None)
    except (NotFitted, np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
        return None, info, notes + [f"mixed model not fitted: {reason(exc)}{instead}"]
    if not fit.converged:
        return None, info, notes + [f"mixed model not fitted: its REML fit did not converge{instead}"]
    slope = False
    if "velocity_m_s" in covariates and attempts_per_subject.min() >= 3:
        v = X[:, names.index("velocity_m_s")]
        try:
            with_slope = fit_lmm(y, X, subject, cell_arg, np.column_stack([np.ones_like(v), v]))
        except (NotFitted, np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            notes.append(f"{drop}: the slope model was not fitted ({reason(exc)})")
            with_slope = None
        if with_slope is not None:
            sd_v = centres["velocity_m_s"][1]
            slope_var = float(with_slope.G[1, 1])
            # REML likelihood-ratio test of the slope's variance and covariance (same fixed effects): on the
            # boundary its null distribution is 0.5 chi2(1) + 0.5 chi2(2) (Self & Liang 1987; Stram & Lee 1994)
            lr = max(2.0 * (with_slope.loglik - fit.loglik), 0.0)
            p_slope = 0.5 * sps.chi2.sf(lr, 1) + 0.5 * sps.chi2.sf(lr, 2)
            info["slope_test"] = {"lr": lr, "p": float(p_slope)}
            if not with_slope.converged:
                notes.append(f"{drop}: its fit did not converge")
            elif slope_var <= SLOPE_VARIANCE_FLOOR * with_slope.resid_var:
                notes.append(f"{drop}: the slope's variance is at zero ({slope_var / sd_v ** 2:.2g} (rating/(m/s))^2, "
                             "on the boundary): the subjects' velocity effects do not differ measurably")
            elif p_slope >= SLOPE_TEST_ALPHA:
                notes.append(f"{drop}: the data do not support it (likelihood-ratio test of its variance, "
                             f"χ² = {lr:.2f}, p = {p_slope:.2f} ≥ {SLOPE_TEST_ALPHA:g}): the subjects' velocity "
                             "effects do not differ measurably")
            else:
                fit, slope = with_slope, True
                info["slope_sd"] = float(np.sqrt(slope_var)) / sd_v
    elif "velocity_m_s" in covariates:
        notes.append(f"{drop}: a random velocity slope needs 3 or more attempts per subject")
    if fit.G[0, 0] <= 0:
        notes.append("mixed model: the subjects' random-intercept variance is estimated at zero (on the boundary): "
                     "the subjects' mean ratings do not differ beyond what the other terms explain")
    if use_cell and fit.cell_var <= 0:
        notes.append("mixed model: the subject × sample variance is estimated at zero (on the boundary): the "
                     "subjects agree on the samples beyond their attempts' noise")
    info.update(fitted=True, converged=True, structure=_structure(fit, slope), df_method="Satterthwaite",
                variances={"subject": float(fit.G[0, 0]), "subject_x_sample": float(fit.cell_var),
                           "residual": float(fit.resid_var)})
    return fit, info, notes


def _df(fit, L: np.ndarray, notes: list, what: str) -> np.ndarray:
    """Satterthwaite df of the rows of ``L``; where unavailable, subjects - 1 (conservative) with a note."""
    df = satterthwaite_df(fit, L)
    bad = ~np.isfinite(df)
    if bad.any():
        df = np.where(bad, max(fit.n_subjects - 1, 1), df)
        notes.append(f"mixed model: Satterthwaite degrees of freedom not available for {int(bad.sum())} {what} (the "
                     "likelihood's curvature in the variances is not positive definite); they use subjects − 1 = "
                     f"{max(fit.n_subjects - 1, 1)} instead (conservative)")
    return df


def mixed_tables(res, info: dict, samples: list, reference: int, data: pd.DataFrame,
                 pairwise: pd.DataFrame | None, alpha: float = 0.05,
                 notes: list | None = None) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """Fixed effects, EMMs and Holm-adjusted pairwise contrasts of a fitted mixed model, each with its
    Satterthwaite df, t test and (1 - alpha) t interval.

    ``pairwise``: the paired t-tests of the ``all`` group (:func:`analysis.stats.pairwise_ttests`), whose
    direction each contrast is compared with (``same_direction``). ``notes``: where a fallback is said.
    """
    notes = [] if notes is None else notes
    k = len(samples)
    n_fe = len(info["names"])
    beta = np.asarray(res.beta)
    cov = np.asarray(res.cov_beta)

    def tests(L, what):
        est = L @ beta
        se = np.sqrt(np.einsum("ij,jk,ik->i", L, cov, L))
        df = _df(res, L, notes, what)
        t = est / se
        half = sps.t.ppf(1 - alpha / 2, df) * se
        return est, se, df, t, 2 * sps.t.sf(np.abs(t), df), est - half, est + half

    est, se, df, t, p, lo, hi = tests(np.eye(n_fe), "fixed effect(s)")
    fixed = pd.DataFrame({"model": "mixed", "term": info["names"], "estimate": est, "se": se, "df": df, "t": t,
                          "p": p, "ci_low": lo, "ci_high": hi})
    fixed = _to_si(fixed, info["centres"])
    L = _sample_contrast_matrix(k, reference, n_fe - k)
    emm, emm_se, emm_df, _, _, lo, hi = tests(L, "marginal mean(s)")
    n_att = np.bincount(data["sample"].to_numpy(), minlength=k)
    emm_table = pd.DataFrame({"sample": samples, "n_attempts": n_att, "emm": emm, "se": emm_se, "df": emm_df,
                              "ci_low": lo, "ci_high": hi})
    ia, ib = np.triu_indices(k, 1)
    est, c_se, c_df, t, p, lo, hi = tests(L[ia] - L[ib], "contrast(s)")
    contrasts = pd.DataFrame({"sample_a": np.array(samples, dtype=object)[ia],
                              "sample_b": np.array(samples, dtype=object)[ib], "estimate": est, "se": c_se,
                              "df": c_df, "t": t, "p": p, "p_holm": _holm(p), "ci_low": lo, "ci_high": hi})
    if pairwise is not None and len(pairwise):
        pw = pairwise.set_index(["sample_a", "sample_b"])
        keys = list(zip(contrasts["sample_a"], contrasts["sample_b"]))
        found = [key in pw.index for key in keys]
        contrasts["ttest_mean_diff"] = [float(pw.loc[key, "mean_diff"]) if f else np.nan for key, f in zip(keys, found)]
        contrasts["ttest_p_holm"] = [float(pw.loc[key, "p_holm"]) if f else np.nan for key, f in zip(keys, found)]
    else:
        contrasts["ttest_mean_diff"] = np.nan
        contrasts["ttest_p_holm"] = np.nan
    td = contrasts["ttest_mean_diff"].to_numpy()
    contrasts["same_direction"] = np.where(np.isfinite(td), np.sign(td) == np.sign(est), False)
    return fixed, emm_table, contrasts[list(CONTRAST_COLUMNS)]


def _separated(data: pd.DataFrame, samples: list, levels: list) -> list[str]:
    """Samples whose every rating is the lowest or every one the highest level: their log-odds are unbounded
    (complete separation), so the proportional-odds fit cannot converge."""
    y = data["rating"].to_numpy()
    code = data["sample"].to_numpy()
    out = []
    for j, s in enumerate(samples):
        r = y[code == j]
        if r.size and (np.all(r == levels[0]) or np.all(r == levels[-1])):
            out.append(f"{s} (every rating {int(r[0])})")
    return out


def cut_points(model, params: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The proportional-odds cut points and their delta-method standard errors.

    statsmodels stores the thresholds as the first cut point then log increments (``theta_m = theta_(m-1) +
    exp(p_m)``); the cut points are their cumulative sums (increasing), with Jacobian
    ``d theta_m / d p_0 = 1``, ``d theta_m / d p_j = exp(p_j)`` for 1 <= j <= m.
    """
    k_th = model.k_levels - 1
    raw = params[-k_th:]
    cuts = model.transform_threshold_params(params)[1:-1]
    J = np.zeros((k_th, k_th))
    J[:, 0] = 1.0
    for m in range(1, k_th):
        J[m:, m] = np.exp(raw[m])
    V = cov[-k_th:, -k_th:]
    return cuts, np.sqrt(np.einsum("ij,jk,ik->i", J, V, J))


def ordinal_model(data: pd.DataFrame, samples: list, reference: int, covariates: list, alpha: float = 0.05):
    """Proportional-odds logit model (statsmodels ``OrderedModel``), cluster-robust by subject.

    Tests and intervals use t on subjects - 1 degrees of freedom (statsmodels' ``use_t`` with clusters).

    Returns
    -------
    fixed : DataFrame
        Log-odds coefficients (a positive one: higher ratings more likely) and the cut points between
        adjacent ratings (``cut a|b``, increasing; no test).
    probabilities : DataFrame
        Per sample and rating 1-7: model probability at the covariates' means, observed share.
    info : dict
    notes : list of str
    """
    X, names, centres = design(data, samples, reference, covariates)
    X, names = X[:, 1:], names[1:]                    # the thresholds take the intercept's place
    y = data["rating"].to_numpy().astype(int)
    levels = sorted(set(y.tolist()))
    groups = data["subject"].to_numpy()
    n_groups = int(np.unique(groups).size)
    info = {"fitted": False, "covariates": covariates, "n_attempts": len(data), "levels": levels}
    notes = []

    def not_fitted(why):
        return _empty(FIXED_COLUMNS), _empty(PROB_COLUMNS), info, notes + [f"ordinal model not fitted: {why}"]

    if len(levels) < 3:
        return not_fitted(f"ratings take {len(levels)} value(s); it needs 3 or more")
    n_params = X.shape[1] + len(levels) - 1
    if len(y) <= n_params:
        return not_fitted(f"{len(y)} attempts for its {n_params} parameters")
    if n_groups < 2:
        return not_fitted(f"its standard errors are clustered by subject and need 2 or more subjects, found {n_groups}")
    separated = _separated(data, samples, levels)
    if separated:
        return not_fitted("the ratings of " + ", ".join(separated) + " are all at one end of the scale used, so "
                          "their log-odds are unbounded (complete separation)")
    endog = pd.Series(pd.Categorical(y, categories=levels, ordered=True))
    model = OrderedLogit(endog, pd.DataFrame(X, columns=names), distr="logit")
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = model.fit(method="bfgs", disp=False, maxiter=2000, cov_type="cluster",
                            cov_kwds={"groups": groups}, use_t=True)
        converged = bool(res.mle_retvals.get("converged", True))
        bad = [w for w in caught if issubclass(w.category, ConvergenceWarning)]
        params = np.asarray(res.params)
        cov = np.asarray(res.cov_params())
    except Exception as exc:          # any library failure is this model's alone (analysis.failures)
        # e.g. a cluster-robust covariance with as many parameters as attempts (statsmodels divides by zero)
        return not_fitted(reason(exc))
    se = np.sqrt(np.diag(cov))
    if not converged or bad or not np.all(np.isfinite(se)):
        return _empty(FIXED_COLUMNS), _empty(PROB_COLUMNS), info | {"converged": False}, notes + [
            "ordinal model did not converge (or gave no standard errors); its estimates are not reported: the "
            "observed rating shares per sample are in sample_summary.csv and the paired tests are the result to use"]
    df = float(n_groups - 1)
    tq = sps.t.ppf(1 - alpha / 2, df)
    nb = X.shape[1]
    b, b_se = params[:nb], se[:nb]
    cuts, cut_se = cut_points(model, params, cov)
    terms = names + [f"cut {a}|{b_}" for a, b_ in zip(levels[:-1], levels[1:])]
    est = np.r_[b, cuts]
    ses = np.r_[b_se, cut_se]
    t = np.r_[b / b_se, np.full(cuts.size, np.nan)]           # a cut point is a position, not an effect: no test
    fixed = pd.DataFrame({"model": "ordinal", "term": terms, "estimate": est, "se": ses,
                          "df": np.r_[np.full(nb, df), np.full(cuts.size, np.nan)], "t": t,
                          "p": 2 * sps.t.sf(np.abs(t), df), "ci_low": est - tq * ses, "ci_high": est + tq * ses})
    fixed = _to_si(fixed, centres)
    k = len(samples)
    at = np.zeros((k, X.shape[1]))
    others = [j for j in range(k) if j != reference]
    for col, j in enumerate(others):
        at[j, col] = 1.0
    prob = np.asarray(model.predict(params, exog=at))            # (k, len(levels))
    code = data["sample"].to_numpy()
    n_att = np.bincount(code, minlength=k)
    rows = []
    for j, s in enumerate(samples):
        obs = np.bincount(y[code == j], minlength=8)
        for r in RATING_LEVELS:
            pm = float(prob[j, levels.index(r)]) if r in levels else 0.0
            rows.append({"sample": s, "rating": r, "p_model": pm,
                         "p_observed": obs[r] / n_att[j] if n_att[j] else np.nan, "n_attempts": int(n_att[j])})
    info.update(fitted=True, converged=True, cov_type="cluster-robust by subject", df=df, n_subjects=n_groups)
    return fixed, pd.DataFrame(rows, columns=list(PROB_COLUMNS)), info, notes


def skipped(reason: str) -> ModelResults:
    """Empty :class:`ModelResults` whose one note is ``reason`` (models not run)."""
    return ModelResults(_empty(FIXED_COLUMNS), _empty(EMM_COLUMNS), _empty(CONTRAST_COLUMNS), _empty(PROB_COLUMNS),
                        {"fitted": False}, {"fitted": False}, (reason,))


def fit_models(study, reference: str, pairwise: pd.DataFrame | None = None, alpha: float = 0.05,
               max_subjects: int = MODELS_MAX_SUBJECTS) -> ModelResults:
    """Both models of the valid testing attempts of all subjects; never raises on data it cannot model.

    Each model fails alone: whatever stops one (its checks, or anything a library raises) is a note naming it,
    and the other is still fitted.

    Parameters
    ----------
    study : analysis.load.Study
    reference : str
        The reference sample (treatment coding; the equivalence tests' reference).
    pairwise : DataFrame or None
        Paired t-tests of the ``all`` group, to compare directions with.
    alpha : float
        1 - confidence level of the CIs; Holm level of the contrasts.
    max_subjects : int
        Above this, the models are skipped with a note.
    """
    data, samples, notes = attempt_data(study, max_subjects)
    if data is None:
        return ModelResults(_empty(FIXED_COLUMNS), _empty(EMM_COLUMNS), _empty(CONTRAST_COLUMNS),
                            _empty(PROB_COLUMNS), {"fitted": False}, {"fitted": False}, tuple(notes))
    covariates, data, cov_notes = _covariates(data)
    notes += cov_notes
    data, samples, gone = _present(data, samples)
    notes += gone
    if len(samples) < 2 or data["subject"].nunique() < 2:
        why = (f"they need 2 or more rated samples, found {len(samples)}" if len(samples) < 2 else
               "they need 2 or more subjects with valid ratings")
        return ModelResults(_empty(FIXED_COLUMNS), _empty(EMM_COLUMNS), _empty(CONTRAST_COLUMNS),
                            _empty(PROB_COLUMNS), {"fitted": False}, {"fitted": False},
                            tuple(notes + [f"models not fitted: {why}"]))
    ref = samples.index(reference) if reference in samples else 0
    if reference not in samples:
        notes.append(f"models: the reference {reference} has no rating; {samples[0]} is the models' reference")
    covariates, est_notes = _estimable(data, samples, ref, covariates)
    notes += est_notes
    empty = (_empty(FIXED_COLUMNS), _empty(EMM_COLUMNS), _empty(CONTRAST_COLUMNS))
    minfo = {"fitted": False}
    try:
        res, minfo, m_notes = mixed_model(data, samples, ref, covariates)
        notes += m_notes
        fixed, emm, contrasts = mixed_tables(res, minfo, samples, ref, data, pairwise, alpha, notes) \
            if res is not None else empty
    except Exception as exc:          # this model's failure is its own (analysis.failures)
        notes.append(f"mixed model not fitted: {reason(exc)}; its estimates are not reported: the paired t-tests "
                     "above are the result to use")
        minfo = {"fitted": False}
        fixed, emm, contrasts = empty
    try:
        o_fixed, probs, oinfo, o_notes = ordinal_model(data, samples, ref, covariates, alpha)
    except Exception as exc:          # ditto
        o_fixed, probs, oinfo, o_notes = _empty(FIXED_COLUMNS), _empty(PROB_COLUMNS), {"fitted": False}, \
            [f"ordinal model not fitted: {reason(exc)}"]
    notes += o_notes
    minfo.pop("names", None)
    fixed_all = pd.concat([t for t in (fixed, o_fixed) if len(t)], ignore_index=True) if len(fixed) or len(o_fixed) \
        else _empty(FIXED_COLUMNS)
    return ModelResults(fixed_all, emm, contrasts, probs, minfo, oinfo, tuple(notes))
