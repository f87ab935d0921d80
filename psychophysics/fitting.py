"""Psychometric functions fitted by maximum likelihood, with profile-likelihood and bootstrap intervals.

The function (:mod:`psychophysics.psychometric`, the one the adaptive methods and the simulated observer
use)::

    psi(x) = gamma + (1 - gamma - lambda) * F(x; alpha, beta)
    logistic  F = 1 / (1 + exp(-beta (x - alpha)))
    normal    F = Phi(beta (x - alpha))                      (beta = 1 / sigma)
    weibull   F = 1 - exp(-ln 2 (x / alpha)^beta),  x > 0

so that **the threshold alpha is the stimulus where F = 0.5**, before the guess rate gamma and the
lapse rate lambda scale it (psignifit 4's ``thresh_PC = 0.5``; for a 2AFC task with no lapses that is
the 75 %-correct point). All three are location-scale families of ``z = beta (u - a)`` with
``u = x, a = alpha`` (logistic, normal) or ``u = ln x, a = ln alpha`` (Weibull, a Gumbel in log
stimulus), which is how they are fitted.

Fitting (Wichmann & Hill 2001a): binomial maximum likelihood over ``(a, ln beta, lambda)`` with
gamma = 1/n for n-AFC (0 for yes/no, or gamma = lambda, "equal asymptotes", for a yes/no or "which was
harder?" task whose lapses flip answers either way) and lambda either fixed or fitted in ``[0, lapse_max]``; Fisher scoring with Levenberg-Marquardt damping, vectorised over data sets so
that a parametric bootstrap (Wichmann & Hill 2001b) refits 1,000 resamples at once. Goodness of fit is
the deviance, with its p-value from the bootstrap's deviances (and the chi-square approximation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from .psychometric import base_cdf, base_pdf, base_quantile, check_function, from_axis, guess_rate, stimulus_axis

#: default upper bound of a fitted lapse rate (Wichmann & Hill 2001a bound it at 0.06; psignifit's prior
#: allows up to 0.5 but concentrates below 0.1)
LAPSE_MAX = 0.1
#: the slope is bounded so that the function's 25-75 % width stays between 1/200 and 20 times the span of
#: the tested stimuli: data that a step function fits perfectly (all wrong below, all right above) give
#: the steepest allowed function instead of an infinite slope
WIDTH_RANGE = (1 / 200, 20.0)

# ---------------------------------------------------------------------------------------------------------------
# maximum likelihood


def _loglik(k, n, p):
    """Binomial log-likelihood (without the constant) per data set: k, n, p of shape (B, L)."""
    p = np.clip(p, 1e-12, 1.0 - 1e-12)
    return np.sum(k * np.log(p) + (n - k) * np.log1p(-p), axis=-1)


def deviance(k, n, p):
    """Deviance 2 sum[k ln(k/np) + (n-k) ln((n-k)/(n(1-p)))] of binomial counts against ``p`` (last axis).

    Parameters
    ----------
    k, n : array_like
        Correct responses and trials per stimulus level.
    p : array_like
        Predicted probability of a correct response per level.

    Returns
    -------
    ndarray or float
        Deviance (0 for a saturated fit), over the last axis.
    """
    k, n = np.asarray(k, float), np.asarray(n, float)
    p = np.clip(np.asarray(p, float), 1e-12, 1 - 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = np.where(k > 0, k * np.log(k / (n * p)), 0.0)
        t2 = np.where(n - k > 0, (n - k) * np.log((n - k) / (n * (1 - p))), 0.0)
    return 2.0 * np.sum(t1 + t2, axis=-1)


def _predict(theta, u, guess, lapse_fixed, function):
    """p (B, L) and dp/dtheta (B, L, P) for theta = (a, ln beta[, lambda]) of shape (B, P).

    ``guess`` None: equal asymptotes, gamma = lambda (psignifit's "equal asymptote" type).
    """
    a, s = theta[:, :1], theta[:, 1:2]
    beta = np.exp(s)
    lam = theta[:, 2:3] if lapse_fixed is None else np.full_like(a, lapse_fixed)
    gam = lam if guess is None else guess
    z = beta * (u[None, :] - a)
    g, dg = base_cdf(z, function), base_pdf(z, function)
    scale = 1.0 - gam - lam
    p = gam + scale * g
    cols = [scale * dg * (-beta), scale * dg * z]
    if lapse_fixed is None:
        cols.append(1.0 - 2.0 * g if guess is None else -g)
    return p, np.stack(cols, axis=-1)


def _slope_bounds(u) -> tuple[float, float]:
    """Bounds of ln beta from :data:`WIDTH_RANGE` and the span of the stimuli on the fitting axis."""
    span = float(np.ptp(u)) or 1.0
    # the 25-75 % width of every family is (q75 - q25) / beta with q75 - q25 of order 1-2: 2 is used
    lo = math.log(2.0 / (WIDTH_RANGE[1] * span))
    hi = math.log(2.0 / (WIDTH_RANGE[0] * span))
    return lo, hi


def _start(k, n, u, guess, lapse_fixed, lapse_max, function):
    """Best (a, ln beta[, lambda]) of a coarse grid for each of the B data sets (shape (B, P))."""
    s_lo, s_hi = _slope_bounds(u)
    a_grid = np.linspace(u.min(), u.max(), 15)
    s_grid = np.linspace(s_lo + 0.2 * (s_hi - s_lo), s_hi - 0.2 * (s_hi - s_lo), 9)
    l_grid = [lapse_fixed] if lapse_fixed is not None else sorted({0.0, min(0.02, lapse_max), lapse_max / 2})
    A, S, L = np.meshgrid(a_grid, s_grid, l_grid, indexing="ij")
    A, S, L = A.ravel(), S.ravel(), L.ravel()
    z = np.exp(S)[:, None] * (u[None, :] - A[:, None])
    G = L if guess is None else np.full_like(L, guess)                    # guess None: gamma = lambda
    p = G[:, None] + (1 - G - L)[:, None] * base_cdf(z, function)         # (G, L)
    p = np.clip(p, 1e-12, 1 - 1e-12)
    ll = k @ np.log(p).T + (n - k) @ np.log1p(-p).T                       # (B, G)
    best = np.argmax(ll, axis=1)
    cols = [A[best], S[best]] + ([L[best]] if lapse_fixed is None else [])
    return np.stack(cols, axis=1)


def fit_many(k, n, x, guess: float, lapse=None, function: str = "logistic", lapse_max: float = LAPSE_MAX,
             start=None, max_iter: int = 200, fixed_location=None):
    """Maximum-likelihood fits of B data sets at the same stimulus levels, vectorised.

    Fisher scoring (expected information) with Levenberg-Marquardt damping; lambda is projected onto
    ``[0, lapse_max]`` and ln beta onto the bounds of :data:`WIDTH_RANGE`.

    Parameters
    ----------
    k : array_like, shape (B, L) or (L,)
        Correct responses per level, per data set.
    n : array_like, shape (L,) or (B, L)
        Trials per level.
    x : array_like, shape (L,)
        Stimulus levels (> 0 for the Weibull).
    guess : float or None
        gamma; None for equal asymptotes (gamma = lambda, a yes/no task whose lapses flip answers
        either way).
    lapse : float or None
        Fixed lambda, or None to fit it.
    function : {'logistic', 'normal', 'weibull'}
    lapse_max : float
        Upper bound of a fitted lambda.
    start : array_like, shape (B, P) or (P,), optional
        Starting (a, ln beta[, lambda]); default: the best point of a coarse grid.
    max_iter : int
    fixed_location : array_like, shape (B,), optional
        Hold a (the threshold on the fitting axis) at these values and fit the rest: the profile
        likelihood of the threshold.

    Returns
    -------
    theta : ndarray, shape (B, P)
        (a, ln beta[, lambda]) with a on the fitting axis (:func:`stimulus_axis`).
    loglik : ndarray, shape (B,)
    """
    check_function(function, "psychometric function")
    k = np.atleast_2d(np.asarray(k, dtype=float))
    B = k.shape[0]
    n = np.broadcast_to(np.asarray(n, dtype=float), k.shape)
    u = stimulus_axis(x, function)
    s_lo, s_hi = _slope_bounds(u)
    theta = (_start(k, n, u, guess, lapse, lapse_max, function) if start is None
             else np.array(np.broadcast_to(np.asarray(start, float), (B, 2 if lapse is not None else 3))))
    P = theta.shape[1]

    lo = np.tile(np.array([-np.inf, s_lo, 0.0][:P]), (B, 1))
    hi = np.tile(np.array([np.inf, s_hi, lapse_max][:P]), (B, 1))
    if fixed_location is not None:
        lo[:, 0] = hi[:, 0] = theta[:, 0] = np.broadcast_to(np.asarray(fixed_location, float), (B,))

    def project(t, rows=slice(None)):
        return np.clip(t, lo[rows], hi[rows])

    theta = project(theta)
    p, d = _predict(theta, u, guess, lapse, function)
    ll = _loglik(k, n, p)
    mu = np.full(B, 1e-3)
    active = np.ones(B, dtype=bool)
    eye = np.eye(P)
    for _ in range(max_iter):
        if not active.any():
            break
        idx = np.flatnonzero(active)
        pa = np.clip(p[idx], 1e-12, 1 - 1e-12)
        w = n[idx] / (pa * (1 - pa))                                      # (b, L)
        da = d[idx]
        info = np.einsum("bl,bli,blj->bij", w, da, da)
        score = np.einsum("bl,bli->bi", (k[idx] - n[idx] * pa) / (pa * (1 - pa)), da)
        # active set: a parameter at its bound whose score points outward is held there (its row and
        # column replaced by the identity), so the others take full Newton steps instead of zig-zagging
        t_now = theta[idx]
        held = (((t_now <= lo[idx] + 1e-12) & (score < 0)) | ((t_now >= hi[idx] - 1e-12) & (score > 0))
                | (lo[idx] == hi[idx]))
        free = ~held
        info = info * (free[:, :, None] & free[:, None, :]) + held[:, :, None] * eye
        score = np.where(held, 0.0, score)
        diag = np.einsum("bii->bi", info)
        lhs = info + (mu[idx, None, None] * (diag[:, :, None] * eye + 1e-9 * eye))
        step = np.linalg.solve(lhs, score[:, :, None])[:, :, 0]
        trial = project(theta[idx] + step, idx)
        p_t, d_t = _predict(trial, u, guess, lapse, function)
        ll_t = _loglik(k[idx], n[idx], p_t)
        better = ll_t >= ll[idx] - 1e-12
        gain = ll_t - ll[idx]
        moved = np.max(np.abs(trial - theta[idx]), axis=1)
        acc = idx[better]
        theta[acc], p[acc], d[acc], ll[acc] = trial[better], p_t[better], d_t[better], ll_t[better]
        mu[acc] = np.maximum(mu[acc] / 3.0, 1e-12)
        rej = idx[~better]
        mu[rej] = mu[rej] * 4.0
        done = (better & ((moved < 1e-10) | ((np.abs(gain) < 1e-13) & (moved < 1e-8)))) | (mu[idx] > 1e12)
        active[idx[done]] = False
    return theta, ll


@dataclass(frozen=True)
class Fit:
    """One psychometric fit: estimates, bootstrap intervals and goodness of fit.

    Attributes are in the stimulus's units; ``slope`` is beta of the module docstring; ``jnd`` is
    x(F = 0.75) - x(F = 0.5); ``weber`` is ``jnd / reference`` for a yes/no ("which was harder?")
    task and ``(threshold - reference) / reference`` for an n-AFC task whose intensity is the
    comparison's value (``reference`` given), else NaN. With ``equal_asymptote`` the guess rate is the
    fitted lapse rate (gamma = lambda). ``threshold_ci`` is the profile-likelihood
    interval (:func:`profile_interval`), ``threshold_ci_bootstrap`` the bootstrap's percentile interval;
    the other intervals are the bootstrap's.
    """

    function: str
    alternatives: int
    guess: float
    threshold: float
    slope: float
    lapse: float
    lapse_fitted: bool
    jnd: float
    weber: float
    reference: float
    deviance: float
    deviance_p_chi2: float
    deviance_p_bootstrap: float
    loglik: float
    n_trials: int
    n_levels: int
    bootstrap: int
    ci_level: float
    threshold_ci: tuple = (math.nan, math.nan)
    threshold_ci_bootstrap: tuple = (math.nan, math.nan)
    slope_ci: tuple = (math.nan, math.nan)
    lapse_ci: tuple = (math.nan, math.nan)
    jnd_ci: tuple = (math.nan, math.nan)
    weber_ci: tuple = (math.nan, math.nan)
    levels: tuple = field(default=(), repr=False)
    n_per_level: tuple = field(default=(), repr=False)
    k_per_level: tuple = field(default=(), repr=False)
    equal_asymptote: bool = False

    @property
    def pse(self) -> float:
        """Point of subjective equality: the threshold (F = 0.5) of a yes/no or "which was harder?" fit."""
        return self.threshold

    def as_dict(self) -> dict:
        """JSON-ready dict of every figure (intervals as [low, high])."""
        out = {}
        for name in ("function", "alternatives", "guess", "equal_asymptote", "threshold", "slope", "lapse",
                     "lapse_fitted", "pse",
                     "jnd", "weber", "reference", "deviance", "deviance_p_chi2", "deviance_p_bootstrap", "loglik",
                     "n_trials", "n_levels", "bootstrap", "ci_level"):
            v = getattr(self, name)
            out[name] = None if isinstance(v, float) and not math.isfinite(v) else v
        for name in ("threshold_ci", "threshold_ci_bootstrap", "slope_ci", "lapse_ci", "jnd_ci", "weber_ci"):
            out[name] = [None if not math.isfinite(v) else float(v) for v in getattr(self, name)]
        return out


def aggregate(intensity, correct) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Levels, trials and correct responses per distinct intensity (sorted).

    Parameters
    ----------
    intensity : array_like, shape (T,)
    correct : array_like of 0/1, shape (T,)

    Returns
    -------
    levels, n, k : ndarray, shape (L,)
    """
    intensity = np.asarray(intensity, dtype=float)
    correct = np.asarray(correct, dtype=float)
    levels, inverse = np.unique(intensity, return_inverse=True)
    n = np.bincount(inverse, minlength=len(levels)).astype(float)
    k = np.bincount(inverse, weights=correct, minlength=len(levels))
    return levels, n, k


def _derived(theta, function, yes_no, reference):
    """threshold, slope, lapse, jnd, weber (each shape (B,)) from fitted theta (B, P); ``yes_no``: a yes/no
    ("which was harder?") task, whose Weber fraction is JND / reference."""
    a, beta = theta[:, 0], np.exp(theta[:, 1])
    lam = theta[:, 2] if theta.shape[1] == 3 else None
    threshold = from_axis(a, function)
    x75 = from_axis(a + base_quantile(0.75, function) / beta, function)
    jnd = x75 - threshold
    if reference is None or not math.isfinite(reference) or reference == 0:
        weber = np.full_like(threshold, np.nan)
    elif yes_no:
        weber = jnd / reference
    else:
        weber = (threshold - reference) / reference
    return threshold, beta, lam, jnd, weber


#: points of the profile-likelihood grid, spread over the fitted threshold +- PROFILE_SPAN x the stimulus span
PROFILE_POINTS = 81
PROFILE_SPAN = 1.0


def profile_interval(levels, n, k, theta, loglik, guess: float, lapse=None, function: str = "logistic",
                     lapse_max: float = LAPSE_MAX, ci_level: float = 0.95):
    """Profile-likelihood (Wilks) interval of the threshold, for B data sets at once.

    The interval holds the thresholds a whose profile log-likelihood (slope and lapse refitted with a
    held) is within chi2_1(ci_level) / 2 of the maximum; its ends are interpolated between the points of a
    grid of :data:`PROFILE_POINTS` over the fitted threshold +- :data:`PROFILE_SPAN` times the span of the
    levels (an end beyond the grid is reported as the grid's end).

    Parameters
    ----------
    levels, n : array_like, shape (L,)
    k : array_like, shape (B, L)
    theta : ndarray, shape (B, P)
        The maximum-likelihood fits (:func:`fit_many`).
    loglik : ndarray, shape (B,)
    guess, lapse, function, lapse_max
        As for :func:`fit_many`.
    ci_level : float

    Returns
    -------
    ndarray, shape (B, 2)
        Low and high end, in stimulus units.
    """
    k = np.atleast_2d(np.asarray(k, float))
    B = k.shape[0]
    u = stimulus_axis(levels, function)
    span = float(np.ptp(u)) or 1.0
    offsets = np.linspace(-PROFILE_SPAN, PROFILE_SPAN, PROFILE_POINTS) * span
    grid = theta[:, :1] + offsets[None, :]                                   # (B, G)
    kk = np.repeat(k, PROFILE_POINTS, axis=0)
    start = np.repeat(theta, PROFILE_POINTS, axis=0)
    lp = np.empty(B * PROFILE_POINTS)
    for c in range(0, B * PROFILE_POINTS, CHUNK):
        sl = slice(c, c + CHUNK)
        lp[sl] = fit_many(kk[sl], n, levels, guess, lapse, function, lapse_max, start=start[sl],
                          fixed_location=grid.ravel()[sl])[1]
    drop = loglik[:, None] - lp.reshape(B, PROFILE_POINTS)                  # >= 0 up to the fit's tolerance
    crit = stats.chi2.ppf(ci_level, 1) / 2.0
    out = np.empty((B, 2))
    centre = PROFILE_POINTS // 2
    for b in range(B):
        d, g = drop[b], grid[b]
        outside = np.flatnonzero(d[:centre] > crit)
        if len(outside):
            i = outside[-1]
            lo = np.interp(crit, [d[i + 1], d[i]], [g[i + 1], g[i]]) if d[i] != d[i + 1] else g[i]
        else:
            lo = g[0]
        outside = np.flatnonzero(d[centre:] > crit)
        if len(outside):
            i = centre + outside[0]
            hi = np.interp(crit, [d[i - 1], d[i]], [g[i - 1], g[i]]) if d[i] != d[i - 1] else g[i]
        else:
            hi = g[-1]
        out[b] = (lo, hi)
    return from_axis(out, function)


def _check_options(alternatives, lapse, lapse_max, ci_level, equal_asymptote=False) -> float | None:
    """The guess rate (None: equal asymptotes), after checking the options of :func:`fit` (one ``ValueError``
    per bad value)."""
    guess = guess_rate(alternatives)
    if equal_asymptote and alternatives != 1:
        raise ValueError(f"equal asymptotes (gamma = lambda) are for a yes/no task (alternatives 1); a "
                         f"{alternatives}-AFC task guesses at 1/{alternatives}")
    top = 0.5 if equal_asymptote else 1.0 - guess   # gamma = lambda: the function must still rise
    if lapse is not None and not (0.0 <= lapse < top):
        raise ValueError(f"a fixed lapse rate must be in [0, {top:g}), got {lapse!r}")
    if not (0.0 < lapse_max < top):
        raise ValueError(f"lapse_max must be in (0, {top:g}), got {lapse_max!r}")
    if not (0.5 <= ci_level < 1.0):
        raise ValueError(f"the confidence level must be in [0.5, 1), got {ci_level!r}")
    return None if equal_asymptote else guess


def fit(intensity, correct, alternatives: int = 2, function: str = "logistic", lapse=None,
        lapse_max: float = LAPSE_MAX, bootstrap: int = 1000, ci_level: float = 0.95, reference=None,
        seed: int = 0, equal_asymptote: bool = False) -> Fit:
    """Fit psi to trial-by-trial responses by maximum likelihood, with a parametric bootstrap.

    Parameters
    ----------
    intensity : array_like, shape (T,)
        Stimulus of each trial (physical units; > 0 for the Weibull).
    correct : array_like of 0/1, shape (T,)
        1 for a correct response (n-AFC) or a "yes" / "comparison harder" response (yes/no).
    alternatives : int
        n of the n-AFC task (gamma = 1/n); 1 for yes/no (gamma = 0).
    function : {'logistic', 'normal', 'weibull'}
    lapse : float or None
        Fixed lapse rate, or None (default) to fit it in ``[0, lapse_max]``.
    lapse_max : float
    bootstrap : int
        Parametric bootstrap resamples (Wichmann & Hill 2001b); 0 for none.
    ci_level : float
        Coverage of the percentile intervals.
    reference : float, optional
        The reference stimulus of a discrimination task (for the Weber fraction).
    seed : int
        Seed of the bootstrap's generator.
    equal_asymptote : bool
        A yes/no task (``alternatives = 1``) whose lapses flip answers either way: gamma = lambda, one
        fitted rate at both asymptotes (psignifit 4's "equal asymptote" type; Wichmann & Hill 2001a
        section 2.2). A "which was harder?" discrimination is the case: a lapse says "harder" to a
        much softer comparison as often as "softer" to a much harder one, and a lapse only at the top
        would bias the PSE and JND.

    Returns
    -------
    Fit
    """
    levels, n, k = aggregate(intensity, correct)
    return fit_counts(levels, n, k, alternatives, function, lapse, lapse_max, bootstrap, ci_level, reference,
                      seed, equal_asymptote)[0]


#: bootstrap data sets refitted in one vectorised call (bounds the memory of many observers x resamples)
CHUNK = 20_000


def fit_counts(levels, n, k, alternatives: int = 2, function: str = "logistic", lapse=None,
               lapse_max: float = LAPSE_MAX, bootstrap: int = 1000, ci_level: float = 0.95, reference=None,
               seed: int = 0, equal_asymptote: bool = False) -> list[Fit]:
    """:func:`fit` for counts per level, of one data set or of B data sets at the same levels at once.

    Parameters
    ----------
    levels : array_like, shape (L,)
        Distinct stimulus levels.
    n : array_like, shape (L,)
        Trials per level (the same for every data set).
    k : array_like, shape (L,) or (B, L)
        Correct (or "yes") responses per level, per data set.
    alternatives, function, lapse, lapse_max, bootstrap, ci_level, reference, seed, equal_asymptote
        As for :func:`fit`; data set b's bootstrap draws from the b-th stream of ``seed``.

    Returns
    -------
    list of Fit
        One per data set.
    """
    check_function(function, "psychometric function")
    guess = _check_options(alternatives, lapse, lapse_max, ci_level, equal_asymptote)
    yes_no = alternatives == 1
    levels = np.asarray(levels, dtype=float)
    n = np.asarray(n, dtype=float)
    k = np.atleast_2d(np.asarray(k, dtype=float))
    B, L = k.shape
    if L < 2:
        raise ValueError(f"a psychometric function needs trials at two or more intensities, got {L}")
    if function == "weibull" and levels[0] <= 0:
        raise ValueError(f"the Weibull function needs intensities > 0, got {levels[0]:g}")
    u = stimulus_axis(levels, function)
    theta, ll = fit_many(k, n, levels, guess, lapse, function, lapse_max)
    est = _derived(theta, function, yes_no, reference)
    p_hat = _predict(theta, u, guess, lapse, function)[0]
    dev = deviance(k, n[None, :], p_hat)
    dof = L - theta.shape[1]
    p_chi2 = stats.chi2.sf(dev, dof) if dof > 0 else np.full(B, np.nan)
    names = ("threshold", "slope", "lapse", "jnd", "weber")
    cis = [{name: (math.nan, math.nan) for name in names + ("threshold_bootstrap",)} for _ in range(B)]
    profile = profile_interval(levels, n, k, theta, ll, guess, lapse, function, lapse_max, ci_level)
    p_boot = np.full(B, np.nan)
    if bootstrap:
        R = int(bootstrap)
        streams = np.random.default_rng(seed).spawn(B) if B > 1 else [np.random.default_rng(seed)]
        kb = np.stack([g.binomial(n.astype(np.int64), np.clip(p, 0, 1), size=(R, L)) for g, p in
                       zip(streams, p_hat)]).astype(float).reshape(B * R, L)
        start = np.repeat(theta, R, axis=0)
        tb = np.empty_like(start)
        for c in range(0, B * R, CHUNK):
            tb[c:c + CHUNK] = fit_many(kb[c:c + CHUNK], n, levels, guess, lapse, function, lapse_max,
                                       start=start[c:c + CHUNK])[0]
        devb = deviance(kb, n[None, :], _predict(tb, u, guess, lapse, function)[0]).reshape(B, R)
        p_boot = np.mean(devb >= dev[:, None] - 1e-9, axis=1)
        q = [(1 - ci_level) / 2 * 100, (1 + ci_level) / 2 * 100]
        boot = [None if v is None else v.reshape(B, R) for v in _derived(tb, function, yes_no, reference)]
        for name, v in zip(("threshold_bootstrap",) + names[1:], boot):
            if v is None:
                continue
            ok = np.isfinite(v).all(axis=1)
            bounds = np.percentile(v, q, axis=1)
            for b in np.flatnonzero(ok):
                cis[b][name] = (float(bounds[0, b]), float(bounds[1, b]))
        if lapse is not None:
            for c in cis:
                c["lapse"] = (float(lapse), float(lapse))
    threshold, beta, lam, jnd, weber = est
    out = []
    for b in range(B):
        lapse_b = float(lam[b] if lam is not None else lapse)
        out.append(Fit(function=function, alternatives=int(alternatives), guess=lapse_b if guess is None else guess,
                       threshold=float(threshold[b]), slope=float(beta[b]),
                       lapse=lapse_b, lapse_fitted=lapse is None, equal_asymptote=guess is None,
                       jnd=float(jnd[b]), weber=float(weber[b]),
                       reference=math.nan if reference is None else float(reference), deviance=float(dev[b]),
                       deviance_p_chi2=float(p_chi2[b]), deviance_p_bootstrap=float(p_boot[b]),
                       loglik=float(ll[b]), n_trials=int(n.sum()), n_levels=L, bootstrap=int(bootstrap),
                       ci_level=ci_level, threshold_ci=(float(profile[b, 0]), float(profile[b, 1])),
                       threshold_ci_bootstrap=cis[b]["threshold_bootstrap"], slope_ci=cis[b]["slope"],
                       lapse_ci=cis[b]["lapse"], jnd_ci=cis[b]["jnd"], weber_ci=cis[b]["weber"],
                       levels=tuple(levels.tolist()), n_per_level=tuple(n.tolist()), k_per_level=tuple(k[b].tolist())))
    return out

