"""Ratings modelled as what they are: a linear mixed model and an ordinal model of every attempt.

The paired t-tests of :mod:`analysis.stats` average each subject's attempts first. The models here use
every valid testing attempt, so unbalanced cells (redraws, missed samples) weigh as much as they hold,
and the tap-to-tap incoming velocity enters as a covariate:

* **linear mixed model** (statsmodels ``MixedLM``, REML): ``rating ~ sample + velocity (+ grip)``
  with a random intercept per subject and, where the data support it, a random slope of velocity;
  estimated marginal means (EMMs) per sample at the mean velocity with 95 % CIs, and every pairwise
  contrast (Wald z, Holm across the pairs), set beside the direction of the paired t-tests;
* **ordinal model** (statsmodels ``OrderedModel``, proportional odds, logit link): the same fixed
  effects; subjects enter through cluster-robust (sandwich) standard errors by subject, so the
  coefficients and the predicted probability of each rating per sample are population-averaged
  (a subject fixed effect per subject would make them subject-specific and biased with few attempts
  per subject; statsmodels has no random-effects ordinal model).

Every failure becomes a one-line note (:attr:`ModelResults.notes`), never an exception: one subject,
a sample nobody rated, a velocity column of NaN, a fit that does not converge (and what was reported
instead).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats as sps
from statsmodels.regression.mixed_linear_model import MixedLM
from statsmodels.tools.sm_exceptions import ConvergenceWarning

from analysis.ordinal import OrderedLogit
from analysis.stats import _holm, codes, valid_testing_mask

#: above this many subjects the models are skipped (said in the report): the tables of the paired tests
#: stay fast at 10,000 subjects, MixedLM's cost grows with the number of subjects and attempts
MODELS_MAX_SUBJECTS = 400
#: a random-slope variance below this share of the residual variance counts as on the boundary (zero):
#: the data do not support a random slope, and the random-intercept model is reported
SLOPE_VARIANCE_FLOOR = 1e-6
#: the per-attempt grip column (N) used when the study table has it: the study runner keeps grip in the traces
#: only and the loader reads the study's trial columns, so today the report says grip is not in the models
GRIP_COLUMN = "grip_mean_N"
RATING_LEVELS = tuple(range(1, 8))

FIXED_COLUMNS = ("model", "term", "estimate", "se", "z", "p", "ci_low", "ci_high")
EMM_COLUMNS = ("sample", "n_attempts", "emm", "se", "ci_low", "ci_high")
CONTRAST_COLUMNS = ("sample_a", "sample_b", "estimate", "se", "z", "p", "p_holm", "ci_low", "ci_high",
                    "ttest_mean_diff", "ttest_p_holm", "same_direction")
PROB_COLUMNS = ("sample", "rating", "p_model", "p_observed", "n_attempts")


@dataclass(frozen=True)
class ModelResults:
    """Both models' tables and what was fitted, with a one-line note for every fallback or failure.

    Attributes
    ----------
    fixed : DataFrame
        Fixed effects of both models (``FIXED_COLUMNS``): rating points for ``mixed``, log-odds of a
        higher rating for ``ordinal`` (and its thresholds).
    emm : DataFrame
        Mixed-model estimated marginal mean rating per sample at the mean velocity (``EMM_COLUMNS``).
    contrasts : DataFrame
        Mixed-model pairwise differences a - b in rating points, Holm-adjusted, beside the paired t-tests.
    probabilities : DataFrame
        Ordinal model: probability of each rating 1-7 per sample at the mean velocity, and the observed share.
    mixed : dict
        ``fitted`` (bool), ``structure``, ``covariates``, ``n_attempts``, ``n_subjects``, ``converged``.
    ordinal : dict
        ``fitted`` (bool), ``covariates``, ``n_attempts``, ``converged``, ``cov_type``.
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
        finite = np.isfinite(data[col].to_numpy())
        if not finite.any():
            notes.append(f"{label} not in the models: {why_absent}")
            continue
        if np.nanstd(data[col].to_numpy()) == 0:
            notes.append(f"{label} not in the models: it does not vary")
            continue
        use.append(col)
    keep = np.all(np.isfinite(data[use].to_numpy()), axis=1) if use else np.ones(len(data), bool)
    if (~keep).any():
        notes.append(f"{int((~keep).sum())} attempt(s) without a value of {', '.join(use)} left out of the models")
    return use, data[keep].reset_index(drop=True), notes


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
    dummies = (code[:, None] == np.array(others)[None, :]).astype(float)
    centres = {c: (float(data[c].mean()), float(data[c].std())) for c in covariates}
    cov = np.column_stack([(data[c].to_numpy() - centres[c][0]) / centres[c][1] for c in covariates]) if covariates else \
        np.empty((len(data), 0))
    X = np.column_stack([np.ones(len(data)), dummies, cov])
    names = ["intercept"] + [f"sample[{samples[j]}]" for j in others] + covariates
    return X, names, centres


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


def _fit_mixed(y, X, groups, slope_col: np.ndarray | None, methods: tuple):
    """MixedLM REML fits with each optimiser of ``methods`` until one is clean; else the best converged one.

    Returns
    -------
    result : MixedLMResults or None
        A clean fit (converged, no warning, finite standard errors); else, of the converged fits with
        finite standard errors, the one with the highest REML log-likelihood; None if there is none.
    boundary : bool
        ``result`` has a variance at zero (statsmodels warned of the boundary or a singular covariance).
    reason : str
        Why no result ("did not converge", ...), else "".
    """
    exog_re = None if slope_col is None else np.column_stack([np.ones_like(slope_col), slope_col])
    model = MixedLM(y, X, groups=groups, exog_re=exog_re)
    usable = []
    for method in methods:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = model.fit(reml=True, method=method)
        bad = [str(w.message).splitlines()[0] for w in caught if issubclass(w.category, ConvergenceWarning)]
        if not (res.converged and np.all(np.isfinite(res.bse_fe))):
            continue
        boundary = any("boundary" in b or "singular" in b for b in bad)
        if not bad:
            return res, False, ""
        usable.append((res.llf, res, boundary))
    if not usable:
        return None, False, "did not converge"
    _, res, boundary = max(usable, key=lambda u: u[0])
    return res, boundary, ""


def mixed_model(data: pd.DataFrame, samples: list, reference: int, covariates: list):
    """Fit the mixed model, random slope of velocity first, random intercept only where the slope is not supported.

    The slope is dropped (with a note saying why) when its fit does not converge or its variance is
    at zero (on the boundary: the subjects' velocity effects do not differ measurably). A random
    intercept whose variance is at zero is kept (the model then equals ordinary least squares), with a note.

    Returns
    -------
    result : statsmodels MixedLMResults or None
    info : dict
        ``structure`` (``random intercept + velocity slope`` or ``random intercept``), ``converged``,
        ``fitted``, ``n_attempts``, ``n_subjects``, ``covariates``, ``centres``.
    notes : list of str
        Each fallback and why.
    """
    y = data["rating"].to_numpy()
    X, names, centres = design(data, samples, reference, covariates)
    groups = data["subject"].to_numpy()
    info = {"fitted": False, "covariates": covariates, "names": names, "centres": centres,
            "n_attempts": len(data), "n_subjects": int(np.unique(groups).size)}
    notes = []
    attempts_per_subject = np.bincount(groups)[np.unique(groups)]
    drop = "mixed model: random slope of velocity dropped, random intercept only"
    if "velocity_m_s" in covariates and attempts_per_subject.min() >= 3:
        v = X[:, names.index("velocity_m_s")]
        try:
            res, boundary, why = _fit_mixed(y, X, groups, v, ("lbfgs", "powell"))
        except (np.linalg.LinAlgError, ValueError, ZeroDivisionError, FloatingPointError) as exc:
            res, boundary, why = None, False, f"failed ({str(exc).splitlines()[0]})"
        if res is not None:
            sd_v = centres["velocity_m_s"][1]
            slope_var = float(np.asarray(res.cov_re)[1, 1])
            if not boundary and slope_var > SLOPE_VARIANCE_FLOOR * res.scale:
                info.update(fitted=True, converged=True, structure="random intercept + velocity slope",
                            slope_sd=float(np.sqrt(slope_var)) / sd_v)
                return res, info, notes
            notes.append(f"{drop}: the slope's variance is at zero ({slope_var / sd_v ** 2:.2g} (rating/(m/s))^2, "
                         "on the boundary): the subjects' velocity effects do not differ measurably")
        else:
            notes.append(f"{drop}: the slope model {why}")
    elif "velocity_m_s" in covariates:
        notes.append(f"{drop}: a random velocity slope needs 3 or more attempts per subject")
    try:
        # Powell first: lbfgs from statsmodels' start point stopped at a zero subject variance on synthetic
        # data whose subjects' biases have an SD of 0.4 rating points (a false boundary); of the two, the
        # fit with the higher likelihood is kept
        res, boundary, why = _fit_mixed(y, X, groups, None, ("powell", "lbfgs"))
    except (np.linalg.LinAlgError, ValueError, ZeroDivisionError, FloatingPointError) as exc:
        res, boundary, why = None, False, f"failed ({str(exc).splitlines()[0]})"
    if res is None:
        notes.append(f"mixed model {why}; its estimates are not reported: the paired t-tests above are the "
                     "result to use")
        return None, info | {"converged": False, "structure": "none"}, notes
    if boundary:
        notes.append("mixed model: the subjects' random-intercept variance is estimated at zero (on the boundary): "
                     "the subjects' mean ratings do not differ beyond the attempts' noise, and the model equals "
                     "ordinary least squares; its estimates are reported")
    info.update(fitted=True, converged=True, structure="random intercept")
    return res, info, notes


def mixed_tables(res, info: dict, samples: list, reference: int, data: pd.DataFrame,
                 pairwise: pd.DataFrame | None, alpha: float = 0.05) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """Fixed effects, EMMs (with 95 % Wald CIs) and Holm-adjusted pairwise contrasts of a fitted mixed model.

    ``pairwise``: the paired t-tests of the ``all`` group (:func:`analysis.stats.pairwise_ttests`), whose
    direction each contrast is compared with (``same_direction``).
    """
    k = len(samples)
    n_fe = len(info["names"])
    beta = np.asarray(res.fe_params)
    cov = np.asarray(res.cov_params())[:n_fe, :n_fe]
    z975 = sps.norm.ppf(1 - alpha / 2)
    se = np.sqrt(np.diag(cov))
    fixed = pd.DataFrame({"model": "mixed", "term": info["names"], "estimate": beta, "se": se, "z": beta / se,
                          "p": 2 * sps.norm.sf(np.abs(beta / se)), "ci_low": beta - z975 * se,
                          "ci_high": beta + z975 * se})
    fixed = _to_si(fixed, info["centres"])
    L = _sample_contrast_matrix(k, reference, n_fe - k)
    emm = L @ beta
    emm_se = np.sqrt(np.einsum("ij,jk,ik->i", L, cov, L))
    n_att = np.bincount(data["sample"].to_numpy(), minlength=k)
    emm_table = pd.DataFrame({"sample": samples, "n_attempts": n_att, "emm": emm, "se": emm_se,
                              "ci_low": emm - z975 * emm_se, "ci_high": emm + z975 * emm_se})
    ia, ib = np.triu_indices(k, 1)
    D = L[ia] - L[ib]
    est = D @ beta
    c_se = np.sqrt(np.einsum("ij,jk,ik->i", D, cov, D))
    z = est / c_se
    p = 2 * sps.norm.sf(np.abs(z))
    contrasts = pd.DataFrame({"sample_a": np.array(samples, dtype=object)[ia],
                              "sample_b": np.array(samples, dtype=object)[ib], "estimate": est, "se": c_se, "z": z,
                              "p": p, "p_holm": _holm(p), "ci_low": est - z975 * c_se, "ci_high": est + z975 * c_se})
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


def ordinal_model(data: pd.DataFrame, samples: list, reference: int, covariates: list, alpha: float = 0.05):
    """Proportional-odds logit model (statsmodels ``OrderedModel``), cluster-robust by subject.

    Returns
    -------
    fixed : DataFrame
        Log-odds coefficients (a positive one: higher ratings more likely) and the thresholds.
    probabilities : DataFrame
        Per sample and rating 1-7: model probability at the covariates' means, observed share.
    info : dict
    notes : list of str
    """
    X, names, centres = design(data, samples, reference, covariates)
    X, names = X[:, 1:], names[1:]                    # the thresholds take the intercept's place
    y = data["rating"].to_numpy().astype(int)
    levels = sorted(set(y.tolist()))
    info = {"fitted": False, "covariates": covariates, "n_attempts": len(data), "levels": levels}
    notes = []
    if len(levels) < 3:
        return _empty(FIXED_COLUMNS), _empty(PROB_COLUMNS), info, \
            [f"ordinal model not fitted: ratings take {len(levels)} value(s); it needs 3 or more"]
    n_params = X.shape[1] + len(levels) - 1
    if len(y) <= n_params:
        return _empty(FIXED_COLUMNS), _empty(PROB_COLUMNS), info, \
            [f"ordinal model not fitted: {len(y)} attempts for its {n_params} parameters"]
    endog = pd.Series(pd.Categorical(y, categories=levels, ordered=True))
    groups = data["subject"].to_numpy()
    model = OrderedLogit(endog, pd.DataFrame(X, columns=names), distr="logit")
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = model.fit(method="bfgs", disp=False, maxiter=2000, cov_type="cluster",
                            cov_kwds={"groups": groups})
        converged = bool(res.mle_retvals.get("converged", True))
        bad = [w for w in caught if issubclass(w.category, ConvergenceWarning)]
    except (np.linalg.LinAlgError, ValueError, ZeroDivisionError, FloatingPointError) as exc:
        # e.g. a cluster-robust covariance with as many parameters as attempts (statsmodels divides by zero)
        return _empty(FIXED_COLUMNS), _empty(PROB_COLUMNS), info, \
            [f"ordinal model not fitted: {(str(exc).splitlines() or [type(exc).__name__])[0]}"]
    params = np.asarray(res.params)
    se = np.asarray(res.bse)
    if not converged or bad or not np.all(np.isfinite(se)):
        return _empty(FIXED_COLUMNS), _empty(PROB_COLUMNS), info | {"converged": False}, \
            ["ordinal model did not converge (or gave no standard errors); its estimates are not reported: the "
             "observed rating shares per sample are in sample_summary.csv and the paired tests are the result to use"]
    z975 = sps.norm.ppf(1 - alpha / 2)
    terms = names + [f"threshold {a}|{b}" for a, b in zip(levels[:-1], levels[1:])]
    fixed = pd.DataFrame({"model": "ordinal", "term": terms, "estimate": params, "se": se, "z": params / se,
                          "p": 2 * sps.norm.sf(np.abs(params / se)), "ci_low": params - z975 * se,
                          "ci_high": params + z975 * se})
    fixed = _to_si(fixed, centres)
    # thresholds past the first are stored as log increments (statsmodels' parametrisation): not a test
    fixed.loc[fixed["term"].str.startswith("threshold"), ["z", "p"]] = np.nan
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
    info.update(fitted=True, converged=True, cov_type="cluster-robust by subject")
    return fixed, pd.DataFrame(rows, columns=list(PROB_COLUMNS)), info, notes


def skipped(reason: str) -> ModelResults:
    """Empty :class:`ModelResults` whose one note is ``reason`` (models not run)."""
    return ModelResults(_empty(FIXED_COLUMNS), _empty(EMM_COLUMNS), _empty(CONTRAST_COLUMNS), _empty(PROB_COLUMNS),
                        {"fitted": False}, {"fitted": False}, (reason,))


def fit_models(study, reference: str, pairwise: pd.DataFrame | None = None, alpha: float = 0.05,
               max_subjects: int = MODELS_MAX_SUBJECTS) -> ModelResults:
    """Both models of the valid testing attempts of all subjects; never raises on data it cannot model.

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
    ref = samples.index(reference) if reference in samples else 0
    if reference not in samples:
        notes.append(f"models: the reference {reference} has no rating; {samples[0]} is the models' reference")
    res, minfo, m_notes = mixed_model(data, samples, ref, covariates)
    notes += m_notes
    if res is not None:
        fixed, emm, contrasts = mixed_tables(res, minfo, samples, ref, data, pairwise, alpha)
    else:
        fixed, emm, contrasts = _empty(FIXED_COLUMNS), _empty(EMM_COLUMNS), _empty(CONTRAST_COLUMNS)
    o_fixed, probs, oinfo, o_notes = ordinal_model(data, samples, ref, covariates, alpha)
    notes += o_notes
    minfo.pop("names", None)
    fixed_all = pd.concat([t for t in (fixed, o_fixed) if len(t)], ignore_index=True) if len(fixed) or len(o_fixed) \
        else _empty(FIXED_COLUMNS)
    return ModelResults(fixed_all, emm, contrasts, probs, minfo, oinfo, tuple(notes))
