"""Bayesian psychometric fits with priors and overdispersion, the method of psignifit 4.

Schütt, Harmeling, Macke & Wichmann (2016), *Painfree and accurate Bayesian estimation of psychometric
functions for (potentially) overdispersed data*, Vision Res. 122:105-123. The function is the contract's
(:mod:`psychophysics.psychometric`) in psignifit's parameters: the threshold ``t`` (where F = 0.5, on the
fitting axis: ``ln x`` for the Weibull) and the width ``w`` = the distance between F = 0.05 and F = 0.95,
so that ``beta = (G^-1(0.95) - G^-1(0.05)) / w``; the lapse rate lambda, the guess rate gamma (1/n, equal
to lambda, or free as in :mod:`psychophysics.fitting`) and the overdispersion ``eta`` in [0, 1).

Likelihood: beta-binomial per level, ``k ~ BetaBin(n, psi eta', (1 - psi) eta')`` with
``eta' = 1 / eta^2 - 1`` (the proportion correct varies between blocks with variance ``eta^2 psi (1 - psi)``,
absorbing non-stationarity, learning and fatigue of long sessions); binomial where ``eta^2 <= 1e-9``.

Default priors (psignifit 4's, on the fitting axis; ``s0..s1`` the tested range, ``r`` its span):

* threshold: uniform on ``s0..s1``, falling to 0 by a raised cosine over ``r / 2`` beyond each end;
* width: uniform on ``2 d .. r`` (``d`` the smallest distance between levels), rising by a cosine from
  ``d`` and falling by a cosine to ``3 r``;
* lambda, gamma (when fitted) and eta: Beta(1, 10) (with equal asymptotes the lapse's prior counts for
  both asymptotes, as in psignifit).

The posterior is evaluated on a grid (coarse over the priors' support, then fine over the region holding
all but 1e-5 of its mass per cell); estimates are the maximum a posteriori parameters (psignifit's default
``MAP``, refined off the grid) and the posterior means; credible intervals are percentiles of the marginal
posteriors (trapezoid rule). Any derived quantity (a threshold at another proportion correct, the JND,
the slope at threshold) gets its credible interval from the posterior over the grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, special, stats

from .fitting import LOWER_ASYMPTOTES, MIN_LEVELS_ON_SLOPE, SLOPE_RANGE, Flag, aggregate, deviance
from .psychometric import base_cdf, base_pdf, base_quantile, check_function, from_axis, guess_rate, stimulus_axis

#: width = distance between F = WIDTH_ALPHA and F = 1 - WIDTH_ALPHA (psignifit's ``width_alpha``)
WIDTH_ALPHA = 0.05
#: Beta(1, BETA_PRIOR) priors of lambda, gamma and eta (psignifit's ``beta_prior``)
BETA_PRIOR = 10
#: grid points per parameter: the coarse pass over the priors' support and the fine pass over the mass
COARSE = {"threshold": 25, "width": 30, "lapse": 10, "guess": 10, "eta": 12}
FINE = {"threshold": 40, "width": 40, "lapse": 14, "guess": 12, "eta": 12}
#: a coarse cell with at least this share of the posterior mass is kept in the fine pass (psignifit's
#: ``max_bound_value``)
MASS_KEPT = 1e-5
#: the parameters in the grid's axis order
PARAMS = ("threshold", "width", "lapse", "guess", "eta")


def _raised(x, lo, hi):
    """0 at ``lo``, 1 at ``hi`` (a raised cosine), for ``lo < x < hi``."""
    return 0.5 * (1.0 - np.cos(np.pi * (x - lo) / (hi - lo)))


def default_priors(stimulus_range, width_min: float) -> dict:
    """psignifit 4's default priors (module docstring) as functions of the parameter values.

    Parameters
    ----------
    stimulus_range : (float, float)
        ``s0, s1`` on the fitting axis.
    width_min : float
        ``d``: the smallest distance between two tested levels (fitting axis).

    Returns
    -------
    dict
        ``threshold``, ``width``, ``lapse``, ``guess``, ``eta`` -> vectorised function (unnormalised density).
    """
    s0, s1 = float(stimulus_range[0]), float(stimulus_range[1])
    r = s1 - s0
    d = float(width_min)

    # The MAP search evaluates each prior at one point thousands of times: a single value takes the one branch
    # that applies (the same arithmetic and ufuncs as the array path, so the same numbers) without the
    # array path's masks.
    def threshold(x):
        x = np.asarray(x, float)
        if x.size == 1:
            v = x.reshape(())[()]
            if s1 <= v <= s1 + r / 2:
                p = 0.5 * (1 + np.cos(2 * np.pi * (v - s1) / r))
            elif s0 - r / 2 <= v <= s0:
                p = 0.5 * (1 + np.cos(2 * np.pi * (s0 - v) / r))
            else:
                p = 1.0 if s0 < v < s1 else 0.0
            return np.full(x.shape, p)
        p = np.where((x > s0) & (x < s1), 1.0, 0.0)
        left = (x >= s0 - r / 2) & (x <= s0)
        right = (x >= s1) & (x <= s1 + r / 2)
        p = np.where(left, 0.5 * (1 + np.cos(2 * np.pi * (s0 - x) / r)), p)
        return np.where(right, 0.5 * (1 + np.cos(2 * np.pi * (x - s1) / r)), p)

    def width(x):
        x = np.asarray(x, float)
        if x.size == 1:
            v = x.reshape(())[()]
            if r <= v <= 3 * r:
                p = 0.5 * (1 + np.cos(np.pi / 2 * (v - r) / r))
            elif d <= v <= 2 * d:
                p = _raised(v, d, 2 * d)
            else:
                p = 1.0 if 2 * d < v < r else 0.0
            return np.full(x.shape, p)
        p = np.where((x > 2 * d) & (x < r), 1.0, 0.0)
        p = np.where((x >= d) & (x <= 2 * d), _raised(x, d, 2 * d), p)
        return np.where((x >= r) & (x <= 3 * r), 0.5 * (1 + np.cos(np.pi / 2 * (x - r) / r)), p)

    def beta(x):
        return stats.beta.pdf(np.asarray(x, float), 1, BETA_PRIOR)

    return {"threshold": threshold, "width": width, "lapse": beta, "guess": beta, "eta": beta}


def _width_constant(function: str) -> float:
    """``G^-1(1 - alpha) - G^-1(alpha)``: beta = this / width."""
    return float(base_quantile(1 - WIDTH_ALPHA, function) - base_quantile(WIDTH_ALPHA, function))


class _Posterior:
    """Log posterior of (threshold, width, lapse, guess, eta) for one data set, on grids or at a point."""

    def __init__(self, u, n, k, function, lower, guess, priors):
        self.u, self.n, self.k = u, n, k
        self.function, self.lower, self.guess = function, lower, guess
        self.priors = priors
        self.cw = _width_constant(function)
        #: which of lapse, guess, eta carry a prior (are fitted), set by the caller
        self.fitted = {"lapse": True, "guess": True, "eta": True}

    def _psi(self, t, w, lam, gam, level):
        z = self.cw / w * (self.u[level] - t)
        return gam + (1.0 - gam - lam) * base_cdf(z, self.function)

    def log_grid(self, grid: dict) -> np.ndarray:
        """Log posterior over the grid (axes in :data:`PARAMS` order; one point on a fixed parameter's axis)."""
        t = grid["threshold"][:, None, None, None]
        w = grid["width"][None, :, None, None]
        lam = grid["lapse"][None, None, :, None]
        gam = lam if self.lower == "equal" else grid["guess"][None, None, None, :]
        etas = grid["eta"]
        shape = (len(grid["threshold"]), len(grid["width"]), len(grid["lapse"]), len(grid["guess"]))
        out = np.zeros(shape + (len(etas),))
        for lv in range(len(self.u)):
            n, k = self.n[lv], self.k[lv]
            if n == 0:
                continue
            p = np.clip(np.broadcast_to(self._psi(t, w, lam, gam, lv), shape), 1e-300, 1.0)
            q = np.clip(1.0 - p, 1e-300, 1.0)
            binom = None
            for e, eta in enumerate(etas):
                if eta * eta <= 1e-9:
                    if binom is None:
                        binom = (k * np.log(p) if k > 0 else 0.0) + ((n - k) * np.log(q) if n > k else 0.0)
                    out[..., e] += binom
                    continue
                ep = 1.0 / (eta * eta) - 1.0
                term = special.gammaln(ep) - special.gammaln(n + ep)
                if k > 0:
                    a = p * ep
                    term = term + special.gammaln(k + a) - special.gammaln(a)
                if n > k:
                    b = q * ep
                    term = term + special.gammaln(n - k + b) - special.gammaln(b)
                out[..., e] += term
        with np.errstate(divide="ignore"):
            lp = np.log(self.priors["threshold"](grid["threshold"]))[:, None, None, None, None]
            lp = lp + np.log(self.priors["width"](grid["width"]))[None, :, None, None, None]
            lp_l = np.log(self.priors["lapse"](grid["lapse"])) if len(grid["lapse"]) > 1 else np.zeros(1)
            if self.lower == "equal":
                lp_l = 2 * lp_l          # the lapse's prior stands for both asymptotes (psignifit)
            lp = lp + lp_l[None, None, :, None, None]
            if len(grid["guess"]) > 1:
                lp = lp + np.log(self.priors["guess"](grid["guess"]))[None, None, None, :, None]
            if len(etas) > 1:
                lp = lp + np.log(self.priors["eta"](etas))[None, None, None, None, :]
        return out + lp

    def log_point(self, x: dict) -> float:
        """Log posterior at one parameter point (``x``: :data:`PARAMS` -> value)."""
        lam = x["lapse"]
        gam = lam if self.lower == "equal" else x["guess"]
        p = np.clip(self._psi(x["threshold"], x["width"], lam, gam, slice(None)), 1e-300, 1.0)
        q = np.clip(1.0 - p, 1e-300, 1.0)
        n, k, eta = self.n, self.k, x["eta"]
        if eta * eta <= 1e-9:
            ll = np.sum(np.where(k > 0, k * np.log(p), 0.0) + np.where(n > k, (n - k) * np.log(q), 0.0))
        else:
            ep = 1.0 / (eta * eta) - 1.0
            a, b = p * ep, q * ep
            ll = np.sum(special.gammaln(ep) - special.gammaln(n + ep) + special.gammaln(k + a) - special.gammaln(a)
                        + special.gammaln(n - k + b) - special.gammaln(b))
        with np.errstate(divide="ignore"):
            lp = math.log(max(float(self.priors["threshold"](np.array([x["threshold"]]))[0]), 0.0) or 1e-320)
            lp += math.log(max(float(self.priors["width"](np.array([x["width"]]))[0]), 0.0) or 1e-320)
            if self.fitted["lapse"]:
                lp += (2 if self.lower == "equal" else 1) * math.log(float(self.priors["lapse"](lam)) or 1e-320)
            if self.fitted["guess"]:
                lp += math.log(float(self.priors["guess"](gam)) or 1e-320)
            if self.fitted["eta"]:
                lp += math.log(float(self.priors["eta"](eta)) or 1e-320)
        return float(ll + lp)


def _weights(values: np.ndarray) -> np.ndarray:
    """Trapezoid weights of a 1-D grid (1 for a single point)."""
    if len(values) == 1:
        return np.ones(1)
    d = np.diff(values)
    w = np.empty(len(values))
    w[0], w[-1] = d[0] / 2, d[-1] / 2
    w[1:-1] = (d[:-1] + d[1:]) / 2
    return w


def _mass(logp: np.ndarray, grid: dict) -> np.ndarray:
    """Posterior probability mass of each grid cell (sums to 1)."""
    p = np.exp(logp - np.max(logp))
    for axis, name in enumerate(PARAMS):
        shape = [1] * len(PARAMS)
        shape[axis] = -1
        p = p * _weights(grid[name]).reshape(shape)
    return p / p.sum()


def _grid(bounds: dict, steps: dict) -> dict:
    return {name: (np.array([bounds[name][0]]) if bounds[name][0] == bounds[name][1]
                   else np.linspace(bounds[name][0], bounds[name][1], steps[name])) for name in PARAMS}


def weighted_interval(values, mass, ci_level: float) -> tuple[float, float]:
    """Central credible interval of a quantity taking ``values`` with posterior ``mass`` (trapezoid CDF)."""
    v = np.asarray(values, float).ravel()
    m = np.asarray(mass, float).ravel()
    ok = np.isfinite(v) & (m > 0)
    v, m = v[ok], m[ok]
    if not len(v):
        return math.nan, math.nan
    order = np.argsort(v, kind="stable")
    v, m = v[order], m[order] / m.sum()
    cdf = np.cumsum(m) - m / 2
    alpha = (1 - ci_level) / 2
    return float(np.interp(alpha, cdf, v)), float(np.interp(1 - alpha, cdf, v))


@dataclass(frozen=True)
class BayesFit:
    """A Bayesian psychometric fit: MAP estimates (the attributes :class:`psychophysics.fitting.Fit` has,
    with the same definitions), posterior means, credible intervals and the overdispersion ``eta``.

    ``*_ci`` are central credible intervals of the marginal posterior (``threshold_ci``: the threshold's,
    psignifit's ``confidence_intervals["threshold"]``).
    """

    function: str
    alternatives: int
    lower_asymptote: str
    threshold: float
    threshold_mean: float
    threshold_ci: tuple
    width: float
    width_ci: tuple
    slope: float
    slope_ci: tuple
    lapse: float
    lapse_ci: tuple
    lapse_fitted: bool
    guess: float
    guess_ci: tuple
    eta: float
    eta_ci: tuple
    pse: float
    pse_ci: tuple
    jnd: float
    jnd_ci: tuple
    weber: float
    weber_ci: tuple
    slope_at_threshold: float
    slope_at_threshold_ci: tuple
    reference: float
    deviance: float
    n_trials: int
    n_levels: int
    ci_level: float
    levels: tuple = field(default=(), repr=False)
    n_per_level: tuple = field(default=(), repr=False)
    k_per_level: tuple = field(default=(), repr=False)
    flags: tuple = ()
    estimator: str = "MAP"
    _grid: dict = field(default=None, repr=False, compare=False)
    _mass: np.ndarray = field(default=None, repr=False, compare=False)

    # what a maximum-likelihood Fit has and a Bayesian fit has not
    bootstrap: int = 0
    deviance_p_bootstrap: float = math.nan
    deviance_p_chi2: float = math.nan
    deviance_p_chi2_withheld: str = "a Bayesian fit reports no goodness-of-fit test"

    @property
    def equal_asymptote(self) -> bool:
        return self.lower_asymptote == "equal"

    @property
    def yes_no(self) -> bool:
        return self.alternatives == 1

    def threshold_at(self, pc: float, unscaled: bool = False, interval: bool = True) -> dict:
        """The stimulus where psi = ``pc`` (psignifit's ``Result.threshold(pc)``; ``unscaled``: where F = ``pc``)
        at the MAP parameters, with its credible interval from the posterior over the grid (cells whose
        function does not reach ``pc`` count beyond the far end).

        Returns
        -------
        dict
            ``pc``, ``unscaled``, ``threshold``, ``ci``, ``ci_method``.
        """
        lo, hi = (0.0, 1.0) if unscaled else (self.guess, 1.0 - self.lapse)
        if not (lo < pc < hi):
            raise ValueError(f"a threshold at {pc:g} needs a proportion in ({lo:g}, {hi:g}) for this fit")
        q = pc if unscaled else (pc - self.guess) / (1.0 - self.guess - self.lapse)
        a = float(stimulus_axis(self.threshold, self.function))
        x = float(from_axis(a + base_quantile(q, self.function) / self.slope, self.function))
        ci = (math.nan, math.nan)
        if interval and self._grid is not None:
            values, mass = _derived_on_grid(self._grid, self._mass, self.function, self.lower_asymptote,
                                            lambda t, beta, lam, gam: _x_at(t, beta, lam, gam, pc, unscaled,
                                                                             self.function, far=True))
            ci = weighted_interval(values, mass, self.ci_level)
        return {"pc": float(pc), "unscaled": bool(unscaled), "threshold": x, "ci": list(ci),
                "ci_method": "posterior"}

    def interval_of(self, fn) -> tuple[float, float]:
        """Credible interval of any quantity ``fn(t, beta, lambda, gamma)`` (``t`` on the fitting axis) from the
        posterior over the grid."""
        values, mass = _derived_on_grid(self._grid, self._mass, self.function, self.lower_asymptote, fn)
        return weighted_interval(values, mass, self.ci_level)

    def as_dict(self) -> dict:
        out = {}
        for name in ("function", "alternatives", "lower_asymptote", "estimator", "threshold", "threshold_mean",
                     "width", "slope", "lapse", "lapse_fitted", "guess", "eta", "pse", "jnd", "weber",
                     "reference", "slope_at_threshold", "deviance", "n_trials", "n_levels", "ci_level"):
            v = getattr(self, name)
            out[name] = None if isinstance(v, float) and not math.isfinite(v) else v
        for name in ("threshold_ci", "width_ci", "slope_ci", "lapse_ci", "guess_ci", "eta_ci", "pse_ci", "jnd_ci",
                     "weber_ci", "slope_at_threshold_ci"):
            out[name] = [None if not math.isfinite(v) else float(v) for v in getattr(self, name)]
        out["flags"] = [{"name": f.name, "message": f.message} for f in self.flags]
        return out


def _x_at(t, beta, lam, gam, pc, unscaled, function, far=False):
    """Stimulus where psi (or F) = pc, on a grid of parameters (NaN, or +inf with ``far``, where unreachable)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        q = np.full(np.broadcast(t, beta, lam, gam).shape, pc) if unscaled else (pc - gam) / (1.0 - gam - lam)
        ok = (q > 0) & (q < 1)
        u = t + base_quantile(np.where(ok, q, 0.5), function) / beta
    x = from_axis(u, function)
    return np.where(ok, x, np.inf if far else np.nan)


def _derived_on_grid(grid, mass, function, lower, fn):
    """Values of ``fn(t, beta, lambda, gamma)`` over the grid and their mass (eta summed out)."""
    m = mass.sum(axis=-1)
    t = grid["threshold"][:, None, None, None]
    beta = _width_constant(function) / grid["width"][None, :, None, None]
    lam = grid["lapse"][None, None, :, None]
    gam = lam if lower == "equal" else grid["guess"][None, None, None, :]
    values = np.broadcast_to(fn(t, beta, lam, gam), m.shape)
    return values, m


def fit_bayes(intensity, correct, alternatives: int = 2, function: str = "logistic", lower_asymptote: str = "fixed",
              lapse=None, eta=None, ci_level: float = 0.95, reference=None, priors: dict | None = None,
              stimulus_range=None) -> BayesFit:
    """Bayesian fit of trial-by-trial answers (module docstring); :func:`fit_bayes_counts` for counts."""
    levels, n, k = aggregate(intensity, correct)
    return fit_bayes_counts(levels, n, k, alternatives, function, lower_asymptote, lapse, eta, ci_level, reference,
                            priors, stimulus_range)


def fit_bayes_counts(levels, n, k, alternatives: int = 2, function: str = "logistic", lower_asymptote: str = "fixed",
                     lapse=None, eta=None, ci_level: float = 0.95, reference=None, priors: dict | None = None,
                     stimulus_range=None) -> BayesFit:
    """Bayesian fit with priors and beta-binomial overdispersion (psignifit 4's method, module docstring).

    Parameters
    ----------
    levels, n, k : array_like, shape (L,)
        Distinct levels (stimulus units), trials and correct (or "yes") answers per level.
    alternatives : int
        n of the n-AFC task (gamma = 1/n); 1 for yes/no.
    function : {'logistic', 'normal', 'weibull'}
    lower_asymptote : {'fixed', 'equal', 'free'}
        As for :func:`psychophysics.fitting.fit` (``free``: psignifit's "yes/no", ``equal``: its "equal
        asymptote").
    lapse : float or None
        Fixed lapse rate, or None to give it the Beta(1, 10) prior on [0, 0.5].
    eta : float or None
        Fixed overdispersion (0: binomial), or None to fit it with the Beta(1, 10) prior.
    ci_level : float
        Credible mass of the intervals.
    reference : float, optional
        Reference stimulus (JND of an n-AFC task, Weber fraction).
    priors : dict, optional
        Replace default priors: parameter name (``threshold``, ``width`` on the fitting axis; ``lapse``,
        ``guess``, ``eta``) -> vectorised density.
    stimulus_range : (float, float), optional
        The range the default threshold and width priors cover (stimulus units); default the tested levels'.

    Returns
    -------
    BayesFit
    """
    check_function(function, "psychometric function")
    if lower_asymptote not in LOWER_ASYMPTOTES:
        raise ValueError(f"the lower asymptote must be one of {', '.join(LOWER_ASYMPTOTES)}, got {lower_asymptote!r}")
    if lower_asymptote != "fixed" and alternatives != 1:
        raise ValueError(f"a {lower_asymptote} lower asymptote is for a yes/no task (alternatives 1)")
    if not (0.5 <= ci_level < 1.0):
        raise ValueError(f"the credible mass must be in [0.5, 1), got {ci_level!r}")
    if lapse is not None and not (0.0 <= lapse < 0.5):
        raise ValueError(f"a fixed lapse rate must be in [0, 0.5), got {lapse!r}")
    if eta is not None and not (0.0 <= eta < 1.0):
        raise ValueError(f"a fixed eta must be in [0, 1), got {eta!r}")
    guess = guess_rate(alternatives)
    levels, n, k = (np.asarray(v, float) for v in (levels, n, k))
    if len(levels) < 2:
        raise ValueError(f"a psychometric function needs trials at two or more intensities, got {len(levels)}")
    if function == "weibull" and levels[0] <= 0:
        raise ValueError(f"the Weibull function needs intensities > 0, got {levels[0]:g}")
    u = stimulus_axis(levels, function)
    rng_u = (u.min(), u.max()) if stimulus_range is None else tuple(stimulus_axis(np.asarray(stimulus_range, float),
                                                                                  function))
    spread = rng_u[1] - rng_u[0]
    wmin = float(np.min(np.diff(np.unique(u)))) if stimulus_range is None else spread / 100
    pri = default_priors(rng_u, wmin)
    if priors:
        unknown = set(priors) - set(PARAMS)
        if unknown:
            raise ValueError(f"priors are for {', '.join(PARAMS)}; got {sorted(unknown)}")
        pri.update(priors)
    bounds = {"threshold": (rng_u[0] - spread / 2, rng_u[1] + spread / 2), "width": (wmin, 3 * spread),
              "lapse": (0.0, 0.5) if lapse is None else (float(lapse), float(lapse)),
              "guess": (0.0, 0.5) if lower_asymptote == "free" else (guess, guess),
              "eta": (0.0, 1 - 1e-10) if eta is None else (float(eta), float(eta))}
    post = _Posterior(u, n, k, function, lower_asymptote, guess, pri)
    grid = _grid(bounds, COARSE)
    mass = _mass(post.log_grid(grid), grid)
    keep = np.nonzero(mass >= MASS_KEPT)
    fine_bounds = {}
    for axis, name in enumerate(PARAMS):
        values = grid[name]
        idx = keep[axis]
        lo, hi = 0, len(values) - 1
        if len(idx):
            lo, hi = max(lo, int(idx.min()) - 1), min(hi, int(idx.max()) + 1)
        fine_bounds[name] = (float(values[lo]), float(values[hi]))
    grid = _grid(fine_bounds, FINE)
    logp = post.log_grid(grid)
    mass = _mass(logp, grid)
    # MAP: the grid's best cell, refined by Nelder-Mead within the priors' support (psignifit's fmin)
    best = np.unravel_index(int(np.argmax(logp)), logp.shape)
    free = [name for name in PARAMS if len(grid[name]) > 1]
    fixed = {name: float(grid[name][0]) for name in PARAMS if len(grid[name]) == 1}
    x0 = [float(grid[name][best[PARAMS.index(name)]]) for name in free]

    post.fitted = {name: len(grid[name]) > 1 or bounds[name][0] != bounds[name][1]
                   for name in ("lapse", "guess", "eta")}
    lo = np.array([bounds[name][0] for name in free])
    span = np.array([bounds[name][1] - bounds[name][0] for name in free])

    def neg(z):
        x = lo + z * span          # the search runs on the priors' support scaled to 0..1
        if np.any(z < 0) or np.any(z > 1):
            return np.inf
        v = post.log_point(dict(fixed, **dict(zip(free, x))))
        return -v if np.isfinite(v) else np.inf

    z0 = (np.array(x0) - lo) / span
    res = optimize.minimize(neg, z0, method="Nelder-Mead",
                            options={"xatol": 1e-9, "fatol": 1e-10, "maxiter": 3000, "maxfev": 3000})
    z = res.x if np.isfinite(res.fun) and res.fun <= neg(z0) else z0
    map_ = dict(fixed, **dict(zip(free, (lo + z * span).tolist())))
    # marginals and means
    marg = {}
    for axis, name in enumerate(PARAMS):
        other = tuple(i for i in range(len(PARAMS)) if i != axis)
        marg[name] = mass.sum(axis=other)
    mean = {name: float(np.sum(marg[name] * grid[name])) for name in PARAMS}

    def interval(name):
        if len(grid[name]) == 1:
            return float(grid[name][0]), float(grid[name][0])
        return weighted_interval(grid[name], marg[name], ci_level)

    cw = _width_constant(function)
    t_map, w_map = map_["threshold"], map_["width"]
    lam_map = map_["lapse"]
    gam_map = lam_map if lower_asymptote == "equal" else map_["guess"]
    beta_map = cw / w_map
    threshold = float(from_axis(t_map, function))
    t_ci = tuple(float(v) for v in from_axis(np.array(interval("threshold")), function))
    w_ci = interval("width")
    yes_no = alternatives == 1
    has_ref = reference is not None and math.isfinite(reference) and reference != 0
    scale = 1.0 - gam_map - lam_map
    g0 = float(base_pdf(0.0, function))

    def slope_at(t, beta, lam, gam):
        return (1.0 - gam - lam) * g0 * beta / (from_axis(t, function) if function == "weibull" else 1.0)

    def jnd_of(t, beta, lam, gam):
        if yes_no:
            return from_axis(t + base_quantile(0.75, function) / beta, function) - from_axis(t, function)
        return from_axis(t, function) - reference if has_ref else np.full(np.broadcast(t, beta).shape, np.nan)

    def ci_of(fn):
        values, m = _derived_on_grid(grid, mass, function, lower_asymptote, fn)
        return weighted_interval(values, m, ci_level)

    jnd = float(jnd_of(t_map, beta_map, lam_map, gam_map))
    jnd_ci = ci_of(jnd_of) if (yes_no or has_ref) else (math.nan, math.nan)
    weber = jnd / reference if has_ref else math.nan
    weber_ci = tuple(sorted((jnd_ci[0] / reference, jnd_ci[1] / reference))) if has_ref else (math.nan, math.nan)
    p_map = gam_map + scale * base_cdf(beta_map * (u - t_map), function)
    dev = float(deviance(k, n, p_map))
    lam_ci = interval("lapse")
    flags = _flags(levels, n, k, u, t_map, beta_map, threshold, marg, function)
    return BayesFit(function=function, alternatives=int(alternatives), lower_asymptote=lower_asymptote,
                    threshold=threshold, threshold_mean=float(from_axis(mean["threshold"], function)),
                    threshold_ci=t_ci, width=float(w_map), width_ci=w_ci, slope=float(beta_map),
                    slope_ci=(cw / w_ci[1], cw / w_ci[0]), lapse=float(lam_map), lapse_ci=lam_ci,
                    lapse_fitted=lapse is None, guess=float(gam_map),
                    guess_ci=lam_ci if lower_asymptote == "equal" else interval("guess"),
                    eta=float(map_["eta"]), eta_ci=interval("eta"),
                    pse=threshold if yes_no else math.nan, pse_ci=t_ci if yes_no else (math.nan, math.nan),
                    jnd=jnd, jnd_ci=jnd_ci, weber=weber, weber_ci=weber_ci,
                    slope_at_threshold=float(slope_at(t_map, beta_map, lam_map, gam_map)),
                    slope_at_threshold_ci=ci_of(slope_at), reference=float(reference) if has_ref else math.nan,
                    deviance=dev, n_trials=int(n.sum()), n_levels=len(levels), ci_level=ci_level,
                    levels=tuple(levels.tolist()), n_per_level=tuple(n.tolist()), k_per_level=tuple(k.tolist()),
                    flags=flags, _grid=grid, _mass=mass)


def _flags(levels, n, k, u, t, beta, threshold, marg, function) -> tuple:
    """The flags of :mod:`psychophysics.fitting` that apply to a Bayesian fit, and psignifit's warning of a
    posterior cut by the priors' support."""
    out = []
    for name in ("threshold", "width"):
        m = marg[name] / max(float(marg[name].sum()), 1e-300)
        if len(m) > 1 and (m[0] > 1e-3 or m[-1] > 1e-3):
            out.append(Flag("posterior_at_grid_edge", f"the {name}'s posterior is not near 0 at the edge of the "
                                                      "priors' support: the data do not bound it (psignifit's "
                                                      "bound warning)"))
            break
    if not (levels[0] <= threshold <= levels[-1]):
        out.append(Flag("threshold_outside_range", f"the threshold {threshold:.4g} lies outside the tested range "
                                                   f"{levels[0]:.4g}..{levels[-1]:.4g}"))
    f_levels = base_cdf(beta * (u - t), function)
    on_slope = int(np.sum((f_levels >= SLOPE_RANGE[0]) & (f_levels <= SLOPE_RANGE[1])))
    if on_slope < MIN_LEVELS_ON_SLOPE:
        out.append(Flag("few_levels_on_slope", f"{on_slope} tested level(s) on the slope (F between "
                                               f"{SLOPE_RANGE[0]:g} and {SLOPE_RANGE[1]:g}); at least "
                                               f"{MIN_LEVELS_ON_SLOPE} are needed to measure it"))
    if np.all(k == 0) or np.all(k == n):
        word = "correct (or 'yes')" if np.all(k == n) else "wrong (or 'no')"
        out.append(Flag("one_response", f"every answer is {word}: the data hold no psychometric function"))
    return tuple(out)
