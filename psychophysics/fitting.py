"""Psychometric functions fitted by maximum likelihood, with exact profile-likelihood and bootstrap intervals.

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

The lower asymptote (Wichmann & Hill 2001a; psignifit 4's experiment types; Palamedes' guess-rate options):

* ``"fixed"``: gamma = 1/n for an n-alternative forced choice, 0 for a yes/no task whose answers have no
  false alarms;
* ``"equal"``: gamma = lambda, one fitted rate at both ends (psignifit's "equal asymptote"): a "which was
  harder?" task whose lapses flip answers either way;
* ``"free"``: gamma fitted in ``[0, guess_max]`` (psignifit's "yes/no"): a yes/no task with false alarms.

Fitting: binomial maximum likelihood over ``(a, ln beta[, lambda][, gamma])``, Fisher scoring with
Levenberg-Marquardt damping and an active set for parameters at their bounds, vectorised over data sets
(a parametric bootstrap, Wichmann & Hill 2001b, refits 1,000 resamples at once) and over conditions that
share parameters (:func:`fit_multiple`, Palamedes' ``PAL_PFML_FitMultiple``). The threshold's interval is
the profile likelihood's (Wilks), its ends found by root finding on the profile (where the lapse rate is
not identified, with a one-sided or a bootstrap-calibrated cut-off: :func:`profile_bounds`); the bootstrap gives
percentile and BCa intervals (Efron 1987) of every derived quantity. Goodness of fit is the deviance, with
its p-value from the bootstrap's deviances and the chi-square approximation (withheld where a level holds
fewer than :data:`CHI2_MIN_TRIALS` trials). :func:`compare_models` is a likelihood-ratio test between two
such models (Palamedes' ``PAL_PFLR_ModelComparison``).

Derived quantities, one definition each (docs/psychophysics.md, "Thresholds, PSE, JND and Weber fraction"):
``threshold`` = alpha (F = 0.5); ``threshold_at(pc)`` = where psi = pc (psignifit's ``threshold(pc)``;
``unscaled=True``: where F = pc); ``slope_at_threshold`` = d psi / dx at alpha (per stimulus unit);
``pse`` = alpha for a yes/no task (undefined for n-AFC); ``jnd`` = x(F = 0.75) - x(F = 0.5) for a yes/no
task and ``threshold - reference`` for an n-AFC task whose stimulus is the comparison's value; ``weber`` =
``jnd / reference`` always.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy import special, stats

from .psychometric import base_cdf, base_pdf, base_quantile, check_function, from_axis, guess_rate, stimulus_axis

#: default upper bound of a fitted lapse rate (Wichmann & Hill 2001a bound it at 0.06; psignifit's prior
#: allows up to 0.5 but concentrates below 0.1)
LAPSE_MAX = 0.1
#: default upper bound of a fitted lower asymptote (false-alarm rate) of a yes/no task (psignifit's bound)
GUESS_MAX = 0.5
#: the lower-asymptote models (module docstring)
LOWER_ASYMPTOTES = ("fixed", "equal", "free")
#: the slope is bounded so that the function's 25-75 % width stays between 1/200 and 20 times the span of
#: the tested stimuli: data that a step function fits perfectly (all wrong below, all right above) give
#: the steepest allowed function instead of an infinite slope
WIDTH_RANGE = (1 / 200, 20.0)
#: the profile's search for an interval's end stops this many stimulus spans (fitting axis) from the
#: estimate: an end not reached there is open (reported as -inf / +inf)
PROFILE_LIMIT = 5.0
#: a chi-square p-value of the deviance is withheld where a level holds fewer trials than this (the
#: chi-square approximation needs a few trials per level; the bootstrap p-value does not)
CHI2_MIN_TRIALS = 3
#: a level is "on the slope" where the fitted F lies in this range
SLOPE_RANGE = (0.1, 0.9)
#: fewer levels on the slope than this is flagged
MIN_LEVELS_ON_SLOPE = 2
#: bootstrap data sets refitted in one vectorised call (bounds the memory of many observers x resamples)
CHUNK = 20_000
#: simulated data sets that calibrate the cut-off of a yes/no threshold whose lapse rate is not identified
#: (:func:`calibrated_cutoff`), and the lapse rates along the allowed range they are drawn from
CALIBRATION_DRAWS = 500
CALIBRATION_WORLDS = 10

# ---------------------------------------------------------------------------------------------------------------
# the model: which parameter column gives each level its location, slope, lapse and guess rate


@dataclass(frozen=True, eq=False)
class Model:
    """A psychometric model of one or several conditions, as the fitting engine sees it.

    Each stimulus level ``l`` (all conditions' levels concatenated) takes its location from column
    ``ia[l]`` of the parameter vector, its ln-slope from ``islope[l]``, its lapse rate from ``il[l]`` (or
    the fixed ``lapse``) and its guess rate from ``ig[l]`` (or the fixed ``guess``, or the lapse rate with
    ``equal``). ``offset`` shifts the standardised stimulus, ``z = beta (u - a) + offset``: with
    ``offset = G^-1(q)`` the location column is the point where ``F = q`` (a profile of that point).
    """

    u: np.ndarray
    function: str
    ia: np.ndarray
    islope: np.ndarray
    il: np.ndarray | None
    ig: np.ndarray | None
    lapse: float | None
    guess: float | None
    equal: bool
    lo: np.ndarray
    hi: np.ndarray
    offset: float = 0.0

    @property
    def n_params(self) -> int:
        return len(self.lo)

    def with_offset(self, offset: float) -> "Model":
        return Model(self.u, self.function, self.ia, self.islope, self.il, self.ig, self.lapse, self.guess,
                     self.equal, self.lo, self.hi, float(offset))

    def parts(self, theta):
        """a, beta, lambda, gamma per level, each (B, L)."""
        a = theta[:, self.ia]
        beta = np.exp(theta[:, self.islope])
        lam = theta[:, self.il] if self.il is not None else np.full_like(a, self.lapse)
        if self.equal:
            gam = lam
        elif self.ig is not None:
            gam = theta[:, self.ig]
        else:
            gam = np.full_like(a, self.guess)
        return a, beta, lam, gam

    @cached_property
    def _columns(self):
        """(a, ln beta, lambda, gamma) columns if each kind takes one column for every level (a model of one
        condition, or of several sharing every parameter), else None; lambda and gamma are None when fixed."""
        one = [np.unique(idx) if idx is not None else None for idx in (self.ia, self.islope, self.il, self.ig)]
        if any(c is not None and len(c) != 1 for c in one):
            return None
        return tuple(int(c[0]) if c is not None else None for c in one)

    def evaluate(self, theta):
        """p (B, L) for parameters ``theta`` (B, P), and what :meth:`jacobian` needs to give dp/dtheta.

        With one column per kind the parameters enter as (B, 1) columns broadcast over the levels (one
        exp per data set, not per level); every p and derivative is the same number as gathered per level.
        """
        cols = self._columns
        if cols is None:
            a, beta, lam, gam = self.parts(theta)
        else:
            ca, cs, cl, cg = cols
            a = theta[:, ca:ca + 1]
            beta = np.exp(theta[:, cs:cs + 1])
            lam = theta[:, cl:cl + 1] if cl is not None else self.lapse
            gam = lam if self.equal else theta[:, cg:cg + 1] if cg is not None else self.guess
        zc = beta * (self.u[None, :] - a)
        z = zc + self.offset if self.offset else zc    # + 0.0 changes no value of G or G'
        g = base_cdf(z, self.function)
        scale = 1.0 - gam - lam
        p = gam + scale * g
        return p, (zc, z, g, scale, beta)

    def jacobian(self, state, rows=None):
        """dp/dtheta (B, L, P) from :meth:`evaluate`'s ``state``, of the data sets ``rows`` (a boolean mask or
        indices; default all)."""
        zc, z, g, scale, beta = state
        if rows is not None:
            zc, z, g = zc[rows], z[rows], g[rows]
            scale = scale[rows] if np.ndim(scale) else scale
            beta = beta[rows]
        B, L = g.shape
        sdg = scale * base_pdf(z, self.function)
        cols = self._columns
        if cols is not None:
            # each column written once (every level takes it): no zeroing, no scattered adds
            ca, cs, cl, cg = cols
            jac = np.empty((B, L, self.n_params))
            np.multiply(sdg, -beta, out=jac[:, :, ca])
            np.multiply(sdg, zc, out=jac[:, :, cs])
            if cl is not None:
                if self.equal:
                    np.subtract(1.0, 2.0 * g, out=jac[:, :, cl])
                else:
                    np.negative(g, out=jac[:, :, cl])
            if cg is not None:
                np.subtract(1.0, g, out=jac[:, :, cg])
            return jac
        jac = np.zeros((B, L, self.n_params))
        ar = np.arange(L)
        jac[:, ar, self.ia] += sdg * (-beta)
        jac[:, ar, self.islope] += sdg * zc
        if self.il is not None:
            jac[:, ar, self.il] += (1.0 - 2.0 * g) if self.equal else -g
        if self.ig is not None:
            jac[:, ar, self.ig] += 1.0 - g
        return jac

    def predict(self, theta, jacobian: bool = True):
        """p (B, L) and dp/dtheta (B, L, P) for parameters ``theta`` (B, P)."""
        p, state = self.evaluate(theta)
        return p, (self.jacobian(state) if jacobian else None)


def _slope_bounds(u) -> tuple[float, float]:
    """Bounds of ln beta from :data:`WIDTH_RANGE` and the span of the stimuli on the fitting axis."""
    span = float(np.ptp(u)) or 1.0
    # the 25-75 % width of every family is (q75 - q25) / beta with q75 - q25 of order 1-2: 2 is used
    lo = math.log(2.0 / (WIDTH_RANGE[1] * span))
    hi = math.log(2.0 / (WIDTH_RANGE[0] * span))
    return lo, hi


def _columns(mode: str, n_cond: int, cond: np.ndarray, start: int):
    """Column index per level and the number of columns for one parameter kind: ``constrained`` (one shared
    column) or ``unconstrained`` (one per condition)."""
    if mode == "constrained":
        return np.full(len(cond), start), 1
    return start + cond, n_cond


def build_model(u_levels, function: str, lower: str, guess: float, lapse, lapse_max: float = LAPSE_MAX,
                guess_max: float = GUESS_MAX, condition=None, thresholds: str = "unconstrained",
                slopes: str = "unconstrained", lapses: str = "unconstrained",
                guesses: str = "unconstrained") -> Model:
    """The :class:`Model` of one condition, or of several that share parameters (Palamedes' options).

    Parameters
    ----------
    u_levels : array_like, shape (L,)
        Levels on the fitting axis (:func:`psychophysics.psychometric.stimulus_axis`), all conditions'
        concatenated.
    function : str
    lower : {'fixed', 'equal', 'free'}
        Lower-asymptote model (module docstring); ``guess`` is its value when fixed.
    guess : float
    lapse : float or None
        Fixed lapse rate, or None to fit it in ``[0, lapse_max]``.
    lapse_max, guess_max : float
    condition : array_like of int, shape (L,), optional
        Condition index of each level (0..C-1); default one condition.
    thresholds, slopes, lapses, guesses : {'constrained', 'unconstrained'}
        Shared across conditions (``constrained``) or one per condition (Palamedes' terms).
    """
    u = np.asarray(u_levels, dtype=float)
    cond = np.zeros(len(u), dtype=int) if condition is None else np.asarray(condition, dtype=int)
    n_cond = int(cond.max()) + 1 if len(cond) else 1
    for name, mode in (("thresholds", thresholds), ("slopes", slopes), ("lapses", lapses), ("guesses", guesses)):
        if mode not in ("constrained", "unconstrained"):
            raise ValueError(f"{name} must be 'constrained' or 'unconstrained', got {mode!r}")
    s_lo, s_hi = _slope_bounds(u)
    ia, na = _columns(thresholds, n_cond, cond, 0)
    islope, ns = _columns(slopes, n_cond, cond, na)
    lo = [-np.inf] * na + [s_lo] * ns
    hi = [np.inf] * na + [s_hi] * ns
    il = ig = None
    if lapse is None:
        il, nl = _columns(lapses, n_cond, cond, len(lo))
        lo += [0.0] * nl
        hi += [lapse_max] * nl
    if lower == "free":
        ig, ng = _columns(guesses, n_cond, cond, len(lo))
        lo += [0.0] * ng
        hi += [guess_max] * ng
    return Model(u=u, function=function, ia=ia, islope=islope, il=il, ig=ig,
                 lapse=None if lapse is None else float(lapse), guess=None if lower != "fixed" else float(guess),
                 equal=lower == "equal", lo=np.array(lo, float), hi=np.array(hi, float))


# ---------------------------------------------------------------------------------------------------------------
# maximum likelihood


def _loglik(k, n, p):
    """Binomial log-likelihood (without the constant) per data set: k, n, p of shape (B, L)."""
    p = np.clip(p, 1e-12, 1.0 - 1e-12)
    return np.sum(k * np.log(p) + (n - k) * np.log1p(-p), axis=-1)


def _clip_p(p):
    """p clipped to [1e-12, 1 - 1e-12], as :func:`_loglik` clips it (the same numbers, NaN kept)."""
    return np.minimum(np.maximum(p, 1e-12), 1.0 - 1e-12)


def _loglik_clipped(k, n_minus_k, pc):
    """:func:`_loglik` of an already clipped ``pc``, with ``n - k`` given (the same sums)."""
    return np.add.reduce(k * np.log(pc) + n_minus_k * np.log1p(-pc), axis=-1)


try:    # np.clip's own ufunc, without the Python wrapper's few microseconds per call in the solver's loop
    from numpy._core.umath import clip as _clip
except ImportError:     # pragma: no cover - another numpy's layout: the wrapper, the same numbers
    _clip = np.clip


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


def _information(w, d):
    """``einsum("bl,bli,blj->bij", w, d, d)``: sum over levels of w d_i d_j, (w d_i) d_j added level by level.

    Beyond a few dozen data sets one two-operand einsum per column ``i`` is about twice as fast as the
    three-operand one, with the same products added in the same order (the same numbers)."""
    B, _, P = d.shape
    if B < 32:
        return np.einsum("bl,bli,blj->bij", w, d, d)
    out = np.empty((B, P, P))
    for i in range(P):
        out[:, i, :] = np.einsum("bl,blj->bj", w * d[:, :, i], d)
    return out


def solve(model: Model, k, n, start, hold=None, max_iter: int = 200):
    """Maximum-likelihood parameters of B data sets under ``model``, from ``start``.

    Fisher scoring (expected information) with Levenberg-Marquardt damping; parameters are projected onto
    their bounds, and one at a bound whose score points outward is held there (active set) so that the
    others take full Newton steps.

    Parameters
    ----------
    model : Model
    k : array_like, shape (B, L)
    n : array_like, shape (L,) or (B, L)
    start : array_like, shape (B, P)
    hold : (int or sequence of int, array_like of shape (B,)), optional
        Hold parameter column ``hold[0]`` (or each of several columns) at these values (a profile
        likelihood).
    max_iter : int

    Returns
    -------
    theta : ndarray, shape (B, P)
    loglik : ndarray, shape (B,)
    """
    k = np.atleast_2d(np.asarray(k, dtype=float))
    B = k.shape[0]
    n = np.broadcast_to(np.asarray(n, dtype=float), k.shape)
    P = model.n_params
    theta = np.array(np.broadcast_to(np.asarray(start, float), (B, P)))
    if hold is None:
        # the bounds are the model's for every data set: (P,) rows, broadcast
        lo, hi = model.lo, model.hi
    else:
        lo = np.tile(model.lo, (B, 1))
        hi = np.tile(model.hi, (B, 1))
        cols, values = hold
        values = np.broadcast_to(np.asarray(values, float), (B,))
        for col in np.atleast_1d(cols):
            lo[:, col] = hi[:, col] = theta[:, col] = values
    theta = _clip(theta, lo, hi)
    p, state = model.evaluate(theta)
    pc = _clip_p(p)
    nk = n - k
    ll = _loglik_clipped(k, nk, pc)
    # The data sets still iterating, compacted as they converge (each array holds only their rows): every
    # row's arithmetic is the same as over the full arrays, without gathering them again each iteration.
    # ``pc`` is the clipped p the information and the log-likelihood use.
    rows = np.arange(B)
    th, llw, kw, nw, nkw = theta.copy(), ll.copy(), k, n, nk
    d = model.jacobian(state)
    lo_w, hi_w = lo, hi
    lo_in, hi_in = lo + 1e-12, hi - 1e-12
    per_row = hold is not None          # the bounds are per data set and compacted with them
    fixed = lo == hi if per_row else None   # the model's own bounds never coincide
    mu = np.full(B, 1e-3)
    diag_ix = np.arange(P)
    eye = np.eye(P)
    for _ in range(max_iter):
        if not len(rows):
            break
        var = pc * (1 - pc)
        info = _information(nw / var, d)
        score = np.einsum("bl,bli->bi", (kw - nw * pc) / var, d)
        held = ((th <= lo_in) & (score < 0)) | ((th >= hi_in) & (score > 0))
        if per_row:
            held |= fixed
        free = ~held
        info = info * (free[:, :, None] & free[:, None, :]) + held[:, :, None] * eye
        score = np.where(held, 0.0, score)
        # Levenberg-Marquardt: info + mu (diag(info) + 1e-9) on the diagonal, the off-diagonal unchanged
        diag = info[:, diag_ix, diag_ix]
        info[:, diag_ix, diag_ix] = diag + mu[:, None] * (diag + 1e-9)
        step = np.linalg.solve(info, score[:, :, None])[:, :, 0]
        trial = _clip(th + step, lo_w, hi_w)
        p_t, state = model.evaluate(trial)
        pc_t = _clip_p(p_t)
        ll_t = _loglik_clipped(kw, nkw, pc_t)
        better = ll_t >= llw - 1e-12
        gain = ll_t - llw
        moved = np.maximum.reduce(np.abs(trial - th), axis=1)
        mu = np.where(better, np.maximum(mu / 3.0, 1e-12), mu * 4.0)
        done = (better & ((moved < 1e-10) | ((np.abs(gain) < 1e-13) & (moved < 1e-8)))) | (mu > 1e12)
        # (the branches below skip gathers that would copy every row: the same numbers)
        if better.all():
            th, llw, pc = trial, ll_t, pc_t
        else:
            th[better], llw[better], pc[better] = trial[better], ll_t[better], pc_t[better]
        if done.all():
            theta[rows], ll[rows] = th, llw
            return theta, ll
        go_on = better & ~done          # the derivatives only where the next iteration uses them
        if go_on.all():
            d = model.jacobian(state)
        elif go_on.any():
            d[go_on] = model.jacobian(state, go_on)
        if done.any():
            theta[rows[done]], ll[rows[done]] = th[done], llw[done]
            keep = ~done
            rows, th, llw, pc, d, kw, nw, nkw, mu = (v[keep] for v in (rows, th, llw, pc, d, kw, nw, nkw, mu))
            if per_row:
                lo_w, hi_w, lo_in, hi_in, fixed = (v[keep] for v in (lo_w, hi_w, lo_in, hi_in, fixed))
    theta[rows], ll[rows] = th, llw
    return theta, ll


def start_values(model: Model, k, n):
    """Best parameters of a coarse grid for each of B data sets of a one-condition model (shape (B, P))."""
    k = np.atleast_2d(np.asarray(k, float))
    n = np.broadcast_to(np.asarray(n, float), k.shape)
    u = model.u
    s_lo, s_hi = model.lo[model.islope[0]], model.hi[model.islope[0]]
    a_grid = np.linspace(u.min(), u.max(), 15)
    s_grid = np.linspace(s_lo + 0.2 * (s_hi - s_lo), s_hi - 0.2 * (s_hi - s_lo), 9)
    cols = [a_grid, s_grid]
    if model.il is not None:
        lmax = model.hi[model.il[0]]
        cols.append(np.array(sorted({0.0, min(0.02, lmax), lmax / 2})))
    if model.ig is not None:
        gmax = model.hi[model.ig[0]]
        cols.append(np.array(sorted({0.0, min(0.05, gmax), min(0.2, gmax)})))
    mesh = np.meshgrid(*cols, indexing="ij")
    grid = np.stack([m.ravel() for m in mesh], axis=1)                   # (G, P)
    p = np.clip(model.predict(grid, jacobian=False)[0], 1e-12, 1 - 1e-12)  # (G, L)
    ll = k @ np.log(p).T + (n - k) @ np.log1p(-p).T if n.ndim == 1 else (
        np.einsum("bl,gl->bg", k, np.log(p)) + np.einsum("bl,gl->bg", n - k, np.log1p(-p)))
    return grid[np.argmax(ll, axis=1)]


def _info_se(model: Model, k, n, theta, col: int) -> np.ndarray:
    """Wald standard error of parameter ``col`` at ``theta`` (B,), from the expected information of the
    parameters not at a bound; NaN where ``col`` is at a bound or the information is singular."""
    k = np.atleast_2d(k)
    n = np.broadcast_to(np.asarray(n, float), k.shape)
    p, d = model.predict(theta)
    p = np.clip(p, 1e-12, 1 - 1e-12)
    info = np.einsum("bl,bli,blj->bij", n / (p * (1 - p)), d, d)
    at_bound = (theta <= model.lo + 1e-9) | (theta >= model.hi - 1e-9)
    out = np.full(len(theta), np.nan)
    for b in range(len(theta)):
        free = ~at_bound[b]
        if not free[col]:
            continue
        sub = info[b][np.ix_(free, free)]
        try:
            cov = np.linalg.inv(sub)
        except np.linalg.LinAlgError:
            continue
        j = int(np.sum(free[:col]))
        if cov[j, j] > 0:
            out[b] = math.sqrt(cov[j, j])
    return out


def lapse_unidentified(model: Model, theta_low, theta_high, col: int = 0) -> np.ndarray:
    """True where a lapse rate that acts on the location ``col`` sits at its upper bound (``lapse_max``) at one
    end of a threshold's profile interval and at 0 at the other.

    The profile then trades the threshold against an upper asymptote the data do not show (levels below the
    threshold): every lapse rate the model allows fits about as well, so the data pin down only a range of
    thresholds (a partially identified parameter), whose length comes from the assumed bound.

    Parameters
    ----------
    model : Model
    theta_low, theta_high : ndarray, shape (B, P)
        Profile parameters at the low and the high end of the interval.
    col : int
        The location's column.

    Returns
    -------
    ndarray of bool, shape (B,)
    """
    out = np.zeros(len(theta_low), dtype=bool)
    if model.il is None:
        return out
    for j in np.unique(model.il[model.ia == col]):
        lo, hi = model.lo[j], model.hi[j]
        at_lo = [t[:, j] <= lo + 1e-6 for t in (theta_low, theta_high)]
        at_hi = [t[:, j] >= hi - 1e-6 for t in (theta_low, theta_high)]
        out |= (at_hi[0] & at_lo[1]) | (at_lo[0] & at_hi[1])
    return out


def profile_cutoff(ci_level: float = 0.95, one_sided: bool = False) -> float:
    """The likelihood-ratio cut-off 2 (lnL_max - lnL_profile) of a profile interval.

    ``chi2_1(ci_level)`` (Wilks; 3.841 at 0.95), or ``chi2_1(2 ci_level - 1) = z_{ci_level}^2`` (2.706 at
    0.95) for an interval of a partially identified parameter, each of whose ends needs only one-sided
    coverage (Imbens & Manski 2004, Econometrica 72:1845, the limit of their c_n for an identified set long
    against the sampling error).
    """
    return float(stats.chi2.ppf(2.0 * ci_level - 1.0 if one_sided else ci_level, 1))


def _data_seed(model: Model, k, n, tag: int) -> int:
    """A seed drawn from the data themselves (levels, trials, answers) and ``tag``: the same data give the same
    simulated draws, so a fit is reproducible."""
    h = hashlib.sha256()
    for arr in (model.u, n, k):
        h.update(np.ascontiguousarray(arr, dtype=float).tobytes())
    h.update(f"{model.function} {model.offset!r} {tag}".encode())
    return int.from_bytes(h.digest()[:8], "little")


def calibrated_cutoff(model: Model, k, n, theta_hat, col: int = 0, ci_level: float = 0.95,
                      draws: int = CALIBRATION_DRAWS, worlds: int = CALIBRATION_WORLDS) -> np.ndarray:
    """Likelihood-ratio cut-off of a threshold whose lapse rate the data do not identify, calibrated by a
    parametric bootstrap averaged over the lapse rates the model allows.

    Where the profile runs the lapse rate from one bound to the other (:func:`lapse_unidentified`), the data
    fit a ridge of observers equally well: every lapse rate in ``[0, lapse_max]`` with its own threshold.
    For each data set, ``worlds`` lapse rates are taken evenly over that range (the midpoints of equal
    bins) and the other parameters refitted with the lapse held there (a world on the ridge);
    ``draws / worlds`` data sets are simulated from each world and fitted twice, freely (from the world and
    from ``theta_hat``, the better kept) and with the location ``col`` held at the world's own value. The
    cut-off is the ``ci_level`` quantile of their likelihood-ratio statistics
    ``W = 2 (lnL_max - lnL_profile)`` pooled over the worlds (the bootstrap calibration of a likelihood-
    ratio interval, Efron & Tibshirani 1993 ch. 16, Hall 1992), at most Wilks' ``chi2_1(ci_level)``.
    The interval then covers ``ci_level`` of observers on average over the allowed lapse rates (a flat
    prior on the unidentified parameter: Moon & Schorfheide 2012, Econometrica 80:755), where the
    one-sided cut-off (:func:`profile_cutoff`, Imbens & Manski 2004) covers at least ``ci_level`` at every
    lapse rate, and so more than that inside the range. The draws are seeded from the data
    (:func:`_data_seed`): the same data give the same cut-off.

    Parameters
    ----------
    model : Model
    k : array_like, shape (B, L)
    n : array_like, shape (L,) or (B, L)
    theta_hat : ndarray, shape (B, P)
        The data's maximum-likelihood parameters.
    col : int
        The location's column.
    ci_level : float
    draws : int
        Simulated data sets per cut-off (rounded up to a multiple of ``worlds``).
    worlds : int
        Lapse rates held along the range.

    Returns
    -------
    ndarray, shape (B,)
    """
    k = np.atleast_2d(np.asarray(k, float))
    n = np.broadcast_to(np.asarray(n, float), k.shape)
    B, L = k.shape
    cap = profile_cutoff(ci_level)
    lapse_cols = np.unique(model.il[model.ia == col]) if model.il is not None else np.array([], int)
    if B == 0 or len(lapse_cols) == 0:
        return np.full(B, cap)
    per = max(1, math.ceil(draws / worlds))
    R = per * worlds
    top = float(model.hi[lapse_cols].min())
    kb = np.empty((B, worlds, per, L))
    world = np.empty((B, worlds, model.n_params))
    rngs = [np.random.default_rng(_data_seed(model, k[b], n[b], col)) for b in range(B)]
    for i, lam in enumerate((np.arange(worlds) + 0.5) / worlds * top):
        start = theta_hat.copy()
        start[:, lapse_cols] = lam
        world[:, i], _ = solve(model, k, n, start, hold=(lapse_cols, np.full(B, lam)))
    p0 = np.clip(model.predict(world.reshape(B * worlds, -1), False)[0], 0.0, 1.0).reshape(B, worlds, L)
    for b in range(B):
        kb[b] = rngs[b].binomial(n[b].astype(np.int64), p0[b][:, None, :], size=(worlds, per, L))
    kb = kb.reshape(B * R, L)
    nb = np.repeat(n, R, axis=0)
    s0 = np.repeat(world.reshape(B * worlds, -1), per, axis=0)
    sh = np.repeat(theta_hat, R, axis=0)
    w = np.empty(B * R)
    for c in range(0, B * R, CHUNK):
        sl = slice(c, c + CHUNK)
        ll_full = np.maximum(solve(model, kb[sl], nb[sl], s0[sl])[1], solve(model, kb[sl], nb[sl], sh[sl])[1])
        _, ll_prof = solve(model, kb[sl], nb[sl], s0[sl], hold=(col, s0[sl, col]))
        w[sl] = np.maximum(2.0 * (ll_full - ll_prof), 0.0)
    return np.minimum(np.quantile(w.reshape(B, R), ci_level, axis=1), cap)


def profile_bounds(model: Model, k, n, theta, loglik, col: int = 0, ci_level: float = 0.95,
                   bound_aware: bool = True, with_cutoff: bool = False, calibrate: int = CALIBRATION_DRAWS):
    """Ends of the profile-likelihood (Wilks) interval of parameter ``col``, found by root finding.

    The interval holds the values v whose profile log-likelihood (every other parameter refitted with
    ``col`` held at v) is within ``c / 2`` of the maximum, ``c = chi2_1(ci_level)`` (3.841 at 0.95). Each
    end is bracketed by steps growing from the Wald standard error, then found by regula falsi with the
    Illinois modification (converged to 1e-9 of the stimulus span). An end not bracketed within
    :data:`PROFILE_LIMIT` stimulus spans of the estimate is open: -inf or +inf.

    Bound-aware (default): where a fitted lapse rate runs from its upper bound at one end of that interval to
    0 at the other (:func:`lapse_unidentified`: levels that never reach the upper asymptote), the threshold
    is only partially identified and the interval is found again with the one-sided cut-off
    ``chi2_1(2 ci_level - 1)`` (2.706 at 0.95; :func:`profile_cutoff`, Imbens & Manski 2004). With Wilks'
    3.841 such intervals cover a true threshold 97-99 % of the time instead of 95 %
    (docs/psychophysics.md, "On- and off-slope designs"). Where the model also fits a lower asymptote
    (a yes/no task's false-alarm rate), that one-sided cut-off still covers 97 %, and the cut-off is
    calibrated instead by a parametric bootstrap over the lapse rates the model allows
    (:func:`calibrated_cutoff`, seeded from the data; ``calibrate`` draws, 0 for the one-sided cut-off).

    Parameters
    ----------
    model : Model
    k : array_like, shape (B, L)
    n : array_like, shape (L,) or (B, L)
    theta : ndarray, shape (B, P)
        Maximum-likelihood parameters.
    loglik : ndarray, shape (B,)
    col : int
        The parameter's column.
    ci_level : float
    bound_aware : bool
        Use the one-sided cut-off where the lapse rate is not identified (False: Wilks' everywhere).
    with_cutoff : bool
        Also return the cut-off used for each data set.
    calibrate : int
        Simulated data sets of :func:`calibrated_cutoff` (0: the one-sided cut-off there too).

    Returns
    -------
    ndarray, shape (B, 2)
        Low and high ends on the parameter's own scale (the fitting axis for a location).
    cutoff : ndarray, shape (B,)
        Only with ``with_cutoff``: the cut-off ``c`` each interval used.
    """
    k = np.atleast_2d(np.asarray(k, float))
    n = np.broadcast_to(np.asarray(n, float), k.shape)
    B = k.shape[0]
    cutoff = np.full(B, profile_cutoff(ci_level))
    out, th_ends = _profile_ends(model, k, n, theta, loglik, col, cutoff / 2.0)
    if bound_aware:
        redo = np.flatnonzero(lapse_unidentified(model, th_ends[0], th_ends[1], col))
        if len(redo):
            cutoff[redo] = profile_cutoff(ci_level, one_sided=True)
            if calibrate and model.ig is not None:
                cutoff[redo] = calibrated_cutoff(model, k[redo], n[redo], theta[redo], col, ci_level, calibrate)
            out[redo], _ = _profile_ends(model, k[redo], n[redo], theta[redo], loglik[redo], col,
                                         cutoff[redo] / 2.0)
    return (out, cutoff) if with_cutoff else out


def _profile_ends(model: Model, k, n, theta, loglik, col, crit):
    """Root finding of :func:`profile_bounds` for a log-likelihood drop ``crit`` (B,): the ends (B, 2) and
    the profile's parameters at each (low, high: (B, P) each; at the search limit for an open end)."""
    B = k.shape[0]
    span = float(np.ptp(model.u)) or 1.0
    limit = PROFILE_LIMIT * span
    tol = 1e-9 * span
    est = theta[:, col].copy()
    se = _info_se(model, k, n, theta, col)
    step0 = np.where(np.isfinite(se) & (se > 0), np.clip(1.5 * se, 1e-3 * span, span), 0.1 * span)
    out = np.empty((B, 2))
    th_ends = []

    def drop(rows, values, warm):
        th, lp = solve(model, k[rows], n[rows], warm, hold=(col, values))
        return th, loglik[rows] - lp - crit[rows]

    for side, sign in enumerate((-1.0, 1.0)):
        # bracket: (x_in, d_in < 0) towards the estimate, (x_out, d_out > 0) beyond the end
        x_in, d_in, th_in = est.copy(), -crit.copy(), theta.copy()
        step = step0.copy()
        x_out = est + sign * step
        th_out, d_out = drop(np.arange(B), x_out, theta)
        searching = d_out < 0
        for _ in range(40):
            if not searching.any():
                break
            r = np.flatnonzero(searching)
            x_in[r], d_in[r], th_in[r] = x_out[r], d_out[r], th_out[r]
            at_limit = step[r] >= limit
            step[r] = np.minimum(step[r] * 3.0, limit)
            x_out[r] = est[r] + sign * step[r]
            th_out[r], d_out[r] = drop(r, x_out[r], th_in[r])
            searching[r] = (d_out[r] < 0) & ~at_limit
        open_end = d_out < 0
        # regula falsi, Illinois: neg = the point inside (d < 0), pos = outside (d > 0)
        x_neg, d_neg, th_neg = x_in, d_in, th_in
        x_pos, d_pos, th_pos = x_out, d_out.copy(), th_out
        root = np.where(open_end, sign * np.inf, np.nan)
        last = np.zeros(B, dtype=int)
        active = ~open_end
        for _ in range(100):
            if not active.any():
                break
            r = np.flatnonzero(active)
            c = (x_neg[r] * d_pos[r] - x_pos[r] * d_neg[r]) / (d_pos[r] - d_neg[r])
            inside = np.minimum(x_neg[r], x_pos[r]), np.maximum(x_neg[r], x_pos[r])
            c = np.where((c > inside[0]) & (c < inside[1]), c, 0.5 * (x_neg[r] + x_pos[r]))
            th_c, d_c = drop(r, c, th_neg[r])
            neg = d_c < 0
            rn, rp = r[neg], r[~neg]
            x_neg[rn], d_neg[rn], th_neg[rn] = c[neg], d_c[neg], th_c[neg]
            d_pos[rn] = np.where(last[rn] == -1, 0.5 * d_pos[rn], d_pos[rn])
            last[rn] = -1
            x_pos[rp], d_pos[rp], th_pos[rp] = c[~neg], d_c[~neg], th_c[~neg]
            d_neg[rp] = np.where(last[rp] == 1, 0.5 * d_neg[rp], d_neg[rp])
            last[rp] = 1
            done = (np.abs(d_c) < 1e-9) | (np.abs(x_pos[r] - x_neg[r]) < tol)
            root[r[done]] = c[done]
            active[r[done]] = False
        left = np.flatnonzero(active)
        root[left] = 0.5 * (x_neg[left] + x_pos[left])
        out[:, side] = root
        th_ends.append(np.where(open_end[:, None], th_out, th_neg))
    return out, th_ends


# ---------------------------------------------------------------------------------------------------------------
# the fit of one condition


@dataclass(frozen=True)
class Flag:
    """A reason not to trust a fit as it stands: ``name`` (stable, for tables) and ``message`` (words)."""

    name: str
    message: str


#: the flags a fit can carry (docs/psychophysics.md, "Flags")
FLAG_NAMES = ("lapse_at_bound", "guess_at_bound", "slope_at_bound", "threshold_interval_open",
              "threshold_outside_range", "few_levels_on_slope", "poor_fit", "one_response")


@dataclass(frozen=True)
class Fit:
    """One psychometric fit: estimates, intervals, goodness of fit and flags.

    Attributes are in the stimulus's units (the definitions are the module docstring's); ``slope`` is beta;
    ``guess`` is gamma (fixed, the lapse rate with ``lower_asymptote = "equal"``, or fitted with
    ``"free"``). ``threshold_ci`` is the exact profile-likelihood interval (an open end is -inf/+inf);
    ``*_ci`` of the other quantities are the bootstrap's percentile intervals and ``*_ci_bca`` its BCa
    intervals (NaN without a bootstrap); ``pse_ci`` is ``threshold_ci`` for a yes/no task; ``jnd_ci`` and
    ``weber_ci`` of an n-AFC task with a reference follow from ``threshold_ci`` (exact).
    ``threshold_ci_cutoff`` is the likelihood-ratio cut-off that interval used (:func:`profile_bounds`:
    3.841 at 95 %, or where the lapse rate is not identified 2.706, or for a yes/no fit with a free lower
    asymptote a cut-off calibrated by a parametric bootstrap, :func:`calibrated_cutoff`).
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
    lower_asymptote: str = "fixed"
    pse: float = math.nan
    pse_ci: tuple = (math.nan, math.nan)
    guess_ci: tuple = (math.nan, math.nan)
    slope_at_threshold: float = math.nan
    slope_at_threshold_ci: tuple = (math.nan, math.nan)
    threshold_ci_bca: tuple = (math.nan, math.nan)
    slope_ci_bca: tuple = (math.nan, math.nan)
    jnd_ci_bca: tuple = (math.nan, math.nan)
    weber_ci_bca: tuple = (math.nan, math.nan)
    deviance_p_chi2_withheld: str = ""
    threshold_ci_cutoff: float = math.nan
    flags: tuple = ()
    lapse_max: float = LAPSE_MAX
    guess_max: float = GUESS_MAX
    slope_bounds: tuple = field(default=(math.nan, math.nan), repr=False)
    boot_params: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def equal_asymptote(self) -> bool:
        """True for the equal-asymptote model (gamma = lambda)."""
        return self.lower_asymptote == "equal"

    @property
    def yes_no(self) -> bool:
        """A yes/no or "which was harder?" task (``alternatives = 1``)."""
        return self.alternatives == 1

    def _model(self, offset: float = 0.0) -> Model:
        u = stimulus_axis(np.asarray(self.levels), self.function)
        m = build_model(u, self.function, self.lower_asymptote, self.guess,
                        None if self.lapse_fitted else self.lapse, self.lapse_max, self.guess_max)
        return m.with_offset(offset) if offset else m

    def _theta(self) -> np.ndarray:
        a = float(stimulus_axis(self.threshold, self.function))
        t = [a, math.log(self.slope)]
        if self.lapse_fitted:
            t.append(self.lapse)
        if self.lower_asymptote == "free":
            t.append(self.guess)
        return np.array([t])

    def threshold_at(self, pc: float, unscaled: bool = False, interval: bool = True) -> dict:
        """The stimulus where psi = ``pc`` (psignifit's ``threshold(pc)``), or where F = ``pc`` (``unscaled``).

        Parameters
        ----------
        pc : float
            Proportion correct (or "yes"): in (gamma, 1 - lambda), or in (0, 1) with ``unscaled``.
        unscaled : bool
            Take ``pc`` as a value of the sigmoid F before guess and lapse scale it.
        interval : bool
            Compute its interval: the exact profile likelihood where the point's F-value is fixed by
            ``pc`` (``unscaled``, or gamma and lambda both fixed), else the bootstrap's percentile interval
            (NaN without a bootstrap).

        Returns
        -------
        dict
            ``pc``, ``unscaled``, ``threshold``, ``ci`` ([low, high]), ``ci_method``.

        Raises
        ------
        ValueError
            ``pc`` outside the function's range.
        """
        lam, gam = self.lapse, self.guess
        lo, hi = (0.0, 1.0) if unscaled else (gam, 1.0 - lam)
        if not (lo < pc < hi):
            raise ValueError(f"a threshold at {pc:g} needs a proportion in ({lo:g}, {hi:g}) for this fit"
                             f"{'' if unscaled else f' (guess rate {gam:.3g}, lapse rate {lam:.3g})'}")
        q = pc if unscaled else (pc - gam) / (1.0 - gam - lam)
        a = float(stimulus_axis(self.threshold, self.function))
        zq = float(base_quantile(q, self.function))
        x = float(from_axis(a + zq / self.slope, self.function))
        ci, method = (math.nan, math.nan), "none"
        fixed_q = unscaled or (not self.lapse_fitted and self.lower_asymptote == "fixed")
        if interval and fixed_q:
            model = self._model(zq)
            theta = self._theta()
            theta[0, 0] = a + zq / self.slope
            n, k = np.asarray(self.n_per_level), np.asarray(self.k_per_level)
            ll = _loglik(k[None], n[None], model.predict(theta, False)[0])
            b = profile_bounds(model, k[None], n, theta, ll, 0, self.ci_level)[0]
            ci, method = (float(from_axis(b[0], self.function)), float(from_axis(b[1], self.function))), "profile"
        elif interval and self.boot_params is not None:
            a_b, beta_b, lam_b, gam_b = (v[:, 0] for v in self._model().parts(self.boot_params))
            with np.errstate(invalid="ignore", divide="ignore"):
                q_b = np.full(len(a_b), q) if unscaled else (pc - gam_b) / (1.0 - gam_b - lam_b)
                ok = (q_b > 0) & (q_b < 1)
                xb = from_axis(a_b[ok] + base_quantile(q_b[ok], self.function) / beta_b[ok], self.function)
            if ok.mean() >= 0.99:     # nearly every resample's function reaches pc
                ci = tuple(float(v) for v in np.quantile(xb, [(1 - self.ci_level) / 2, (1 + self.ci_level) / 2]))
                method = "bootstrap percentile"
        return {"pc": float(pc), "unscaled": bool(unscaled), "threshold": x, "ci": list(ci), "ci_method": method}

    def interval_of(self, fn) -> tuple[float, float]:
        """Percentile interval of any quantity ``fn(a, beta, lambda, gamma)`` (``a`` on the fitting axis, arrays)
        over the bootstrap's parameters; NaN without a bootstrap (e.g. the physical JND of a log10 axis)."""
        if self.boot_params is None:
            return math.nan, math.nan
        a, beta, lam, gam = (v[:, 0] for v in self._model().parts(self.boot_params))
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            values = np.asarray(fn(a, beta, lam, gam), float)
        values = values[np.isfinite(values)]
        if len(values) < 0.99 * len(a):
            return math.nan, math.nan
        lo, hi = np.quantile(values, [(1 - self.ci_level) / 2, (1 + self.ci_level) / 2])
        return float(lo), float(hi)

    def as_dict(self) -> dict:
        """JSON-ready dict of every figure (intervals as [low, high]; NaN and infinite ends as None; flags
        as ``[{"name", "message"}]``)."""
        out = {}
        for name in ("function", "alternatives", "lower_asymptote", "guess", "equal_asymptote", "threshold",
                     "slope", "lapse", "lapse_fitted", "pse", "jnd", "weber", "reference", "slope_at_threshold",
                     "deviance", "deviance_p_chi2", "deviance_p_chi2_withheld", "deviance_p_bootstrap",
                     "threshold_ci_cutoff", "loglik",
                     "n_trials", "n_levels", "bootstrap", "ci_level"):
            v = getattr(self, name)
            out[name] = None if isinstance(v, float) and not math.isfinite(v) else v
        for name in ("threshold_ci", "threshold_ci_bootstrap", "threshold_ci_bca", "pse_ci", "slope_ci",
                     "slope_ci_bca", "lapse_ci", "guess_ci", "jnd_ci", "jnd_ci_bca", "weber_ci", "weber_ci_bca",
                     "slope_at_threshold_ci"):
            out[name] = [None if not math.isfinite(v) else float(v) for v in getattr(self, name)]
        out["flags"] = [{"name": f.name, "message": f.message} for f in self.flags]
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


def derived(model: Model, theta, yes_no: bool, reference) -> dict:
    """The one set of derived quantities (module docstring) of one-condition parameters ``theta`` (B, P).

    Returns
    -------
    dict of ndarray, shape (B,)
        ``threshold``, ``slope``, ``lapse``, ``guess``, ``pse``, ``jnd``, ``weber``, ``slope_at_threshold``.
    """
    a, beta, lam, gam = (v[:, 0] for v in model.parts(theta))
    f = model.function
    threshold = from_axis(a, f)
    scale = 1.0 - gam - lam
    # d psi / dx at alpha: (1 - gamma - lambda) G'(0) beta / (dx/du); dx/du = x on the Weibull's log axis
    slope_thr = scale * float(base_pdf(0.0, f)) * beta / (threshold if f == "weibull" else 1.0)
    has_ref = reference is not None and math.isfinite(reference) and reference != 0
    if yes_no:
        pse = threshold
        jnd = from_axis(a + base_quantile(0.75, f) / beta, f) - threshold
    else:
        pse = np.full_like(threshold, np.nan)
        jnd = threshold - reference if has_ref else np.full_like(threshold, np.nan)
    weber = jnd / reference if has_ref else np.full_like(threshold, np.nan)
    return {"threshold": threshold, "slope": beta, "lapse": lam, "guess": gam, "pse": pse, "jnd": jnd,
            "weber": weber, "slope_at_threshold": slope_thr}


def bca_interval(estimate: float, boot, jackknife, weights=None, ci_level: float = 0.95) -> tuple[float, float]:
    """Bias-corrected and accelerated bootstrap interval (Efron 1987; Efron & Tibshirani 1993, ch. 14).

    Parameters
    ----------
    estimate : float
        The statistic on the data.
    boot : array_like, shape (R,)
        The statistic on R bootstrap resamples.
    jackknife : array_like, shape (J,)
        The statistic with each observation left out (distinct values, see ``weights``).
    weights : array_like, shape (J,), optional
        How many observations give each jackknife value (e.g. the trials at a level with a given answer).
    ci_level : float

    Returns
    -------
    (low, high)
        NaN when the bootstrap distribution is degenerate (every resample on one side of the estimate).
    """
    boot = np.asarray(boot, float)
    boot = boot[np.isfinite(boot)]
    jack = np.asarray(jackknife, float)
    w = np.ones_like(jack) if weights is None else np.asarray(weights, float)
    if len(boot) < 10 or not np.isfinite(estimate):
        return math.nan, math.nan
    frac = (np.sum(boot < estimate) + 0.5 * np.sum(boot == estimate)) / len(boot)
    if frac <= 0.0 or frac >= 1.0:
        return math.nan, math.nan
    z0 = special.ndtri(frac)
    ok = np.isfinite(jack)
    jack, w = jack[ok], w[ok]
    mean = np.sum(w * jack) / np.sum(w)
    dev = mean - jack
    den = np.sum(w * dev ** 2)
    acc = np.sum(w * dev ** 3) / (6.0 * den ** 1.5) if den > 0 else 0.0
    alpha = (1 - ci_level) / 2
    zs = special.ndtri(np.array([alpha, 1 - alpha]))
    adj = special.ndtr(z0 + (z0 + zs) / (1 - acc * (z0 + zs)))
    lo, hi = np.quantile(boot, adj)
    return float(lo), float(hi)


def _check_options(alternatives, lapse, lapse_max, ci_level, lower_asymptote, guess_max) -> float:
    """The fixed guess rate, after checking the options of :func:`fit` (one ``ValueError`` per bad value)."""
    guess = guess_rate(alternatives)
    if lower_asymptote not in LOWER_ASYMPTOTES:
        raise ValueError(f"the lower asymptote must be one of {', '.join(LOWER_ASYMPTOTES)}, "
                         f"got {lower_asymptote!r}")
    if lower_asymptote == "equal" and alternatives != 1:
        raise ValueError(f"equal asymptotes (gamma = lambda) are for a yes/no task (alternatives 1); a "
                         f"{alternatives}-AFC task guesses at 1/{alternatives}")
    if lower_asymptote == "free" and alternatives != 1:
        raise ValueError(f"a free lower asymptote (false-alarm rate) is for a yes/no task (alternatives 1); a "
                         f"{alternatives}-AFC task guesses at 1/{alternatives}")
    top = 0.5 if lower_asymptote == "equal" else 1.0 - guess   # gamma = lambda: the function must still rise
    if lapse is not None and not (0.0 <= lapse < top):
        raise ValueError(f"a fixed lapse rate must be in [0, {top:g}), got {lapse!r}")
    if not (0.0 < lapse_max < top):
        raise ValueError(f"lapse_max must be in (0, {top:g}), got {lapse_max!r}")
    if lower_asymptote == "free" and not (0.0 < guess_max < 1.0 - lapse_max):
        raise ValueError(f"guess_max must be in (0, {1.0 - lapse_max:g}), got {guess_max!r}")
    if not (0.5 <= ci_level < 1.0):
        raise ValueError(f"the confidence level must be in [0.5, 1), got {ci_level!r}")
    return guess


def fit(intensity, correct, alternatives: int = 2, function: str = "logistic", lapse=None,
        lapse_max: float = LAPSE_MAX, bootstrap: int = 1000, ci_level: float = 0.95, reference=None,
        seed: int = 0, equal_asymptote: bool = False, lower_asymptote: str | None = None,
        guess_max: float = GUESS_MAX) -> Fit:
    """Fit psi to trial-by-trial responses by maximum likelihood, with a parametric bootstrap.

    Parameters
    ----------
    intensity : array_like, shape (T,)
        Stimulus of each trial (physical units; > 0 for the Weibull).
    correct : array_like of 0/1, shape (T,)
        1 for a correct response (n-AFC) or a "yes" / "comparison harder" response (yes/no).
    alternatives : int
        n of the n-AFC task (gamma = 1/n); 1 for yes/no.
    function : {'logistic', 'normal', 'weibull'}
    lapse : float or None
        Fixed lapse rate, or None (default) to fit it in ``[0, lapse_max]``.
    lapse_max : float
    bootstrap : int
        Parametric bootstrap resamples (Wichmann & Hill 2001b); 0 for none.
    ci_level : float
        Coverage of the intervals.
    reference : float, optional
        The reference stimulus of a discrimination task (for the JND of an n-AFC task and the Weber
        fraction).
    seed : int
        Seed of the bootstrap's generator.
    equal_asymptote : bool
        Shorthand for ``lower_asymptote="equal"``.
    lower_asymptote : {'fixed', 'equal', 'free'}, optional
        The lower-asymptote model (module docstring); default ``"fixed"`` (gamma = 1/n, 0 for yes/no).
        ``"equal"`` suits a "which was harder?" discrimination (a lapse says "harder" to a much softer
        comparison as often as "softer" to a much harder one); ``"free"`` a yes/no detection with false
        alarms.
    guess_max : float
        Upper bound of a free lower asymptote.

    Returns
    -------
    Fit
    """
    levels, n, k = aggregate(intensity, correct)
    return fit_counts(levels, n, k, alternatives, function, lapse, lapse_max, bootstrap, ci_level, reference,
                      seed, equal_asymptote, lower_asymptote, guess_max)[0]


def _flags(model, theta, derived_b, profile_b, levels, n, k, p_boot, p_chi2, lapse_max, guess_max) -> tuple:
    """The flags of one fit (:data:`FLAG_NAMES`); arguments are that fit's own."""
    out = []
    if model.il is not None and theta[model.il[0]] >= lapse_max - 1e-6:
        out.append(Flag("lapse_at_bound", f"the lapse rate sits at its bound {lapse_max:g}: more lapses than "
                                          "the model allows, or a function that does not fit"))
    if model.ig is not None and theta[model.ig[0]] >= guess_max - 1e-6:
        out.append(Flag("guess_at_bound", f"the false-alarm rate sits at its bound {guess_max:g}"))
    col = model.islope[0]
    s = theta[col]
    s_lo, s_hi = model.lo[col], model.hi[col]
    # at its bound, or running towards it: the likelihood no worse there (data a step function fits, whose
    # slope has no finite estimate)
    ll = _loglik(k[None], n[None], model.predict(theta[None], False)[0])[0]
    for bound, which in ((s_hi, "steepest"), (s_lo, "shallowest")):
        t = theta.copy()
        t[col] = bound
        if _loglik(k[None], n[None], model.predict(t[None], False)[0])[0] >= ll - 1e-6:
            out.append(Flag("slope_at_bound", f"the slope runs to its bound (the {which} function allowed): the "
                                              "data do not pin the slope down"))
            break
    if not np.all(np.isfinite(profile_b)):
        out.append(Flag("threshold_interval_open", "the threshold's interval is open: the data do not bound it "
                                                   f"within {PROFILE_LIMIT:g} stimulus spans"))
    thr = derived_b["threshold"]
    if not (levels[0] <= thr <= levels[-1]):
        out.append(Flag("threshold_outside_range", f"the threshold {thr:.4g} lies outside the tested range "
                                                   f"{levels[0]:.4g}..{levels[-1]:.4g}"))
    a, beta = theta[model.ia[0]], math.exp(s)
    f_levels = base_cdf(beta * (model.u - a), model.function)
    on_slope = int(np.sum((f_levels >= SLOPE_RANGE[0]) & (f_levels <= SLOPE_RANGE[1])))
    if on_slope < MIN_LEVELS_ON_SLOPE:
        out.append(Flag("few_levels_on_slope", f"{on_slope} tested level(s) on the slope (F between "
                                               f"{SLOPE_RANGE[0]:g} and {SLOPE_RANGE[1]:g}); at least "
                                               f"{MIN_LEVELS_ON_SLOPE} are needed to measure it"))
    p = p_boot if math.isfinite(p_boot) else p_chi2
    if math.isfinite(p) and p < 0.05:
        which = "bootstrap" if math.isfinite(p_boot) else "chi-square"
        out.append(Flag("poor_fit", f"the deviance says the function does not fit the data ({which} p = {p:.3g} "
                                    "< 0.05)"))
    if np.all(k == 0) or np.all(k == n):
        word = "correct (or 'yes')" if np.all(k == n) else "wrong (or 'no')"
        out.append(Flag("one_response", f"every answer is {word}: the data hold no psychometric function"))
    return tuple(out)


def _bootstrap_draws(streams, n, p_hat, R):
    L = len(n)
    return np.stack([g.binomial(n.astype(np.int64), np.clip(p, 0, 1), size=(R, L)) for g, p in
                     zip(streams, p_hat)]).astype(float)


def fit_counts(levels, n, k, alternatives: int = 2, function: str = "logistic", lapse=None,
               lapse_max: float = LAPSE_MAX, bootstrap: int = 1000, ci_level: float = 0.95, reference=None,
               seed: int = 0, equal_asymptote: bool = False, lower_asymptote: str | None = None,
               guess_max: float = GUESS_MAX) -> list[Fit]:
    """:func:`fit` for counts per level, of one data set or of B data sets at the same levels at once.

    Parameters
    ----------
    levels : array_like, shape (L,)
        Distinct stimulus levels.
    n : array_like, shape (L,)
        Trials per level (the same for every data set).
    k : array_like, shape (L,) or (B, L)
        Correct (or "yes") responses per level, per data set.
    alternatives, function, lapse, lapse_max, bootstrap, ci_level, reference, seed, equal_asymptote,
    lower_asymptote, guess_max
        As for :func:`fit`; data set b's bootstrap draws from the b-th stream of ``seed``.

    Returns
    -------
    list of Fit
        One per data set.
    """
    check_function(function, "psychometric function")
    lower = lower_asymptote or ("equal" if equal_asymptote else "fixed")
    if equal_asymptote and lower != "equal":
        raise ValueError("equal_asymptote=True contradicts lower_asymptote={lower!r}")
    guess = _check_options(alternatives, lapse, lapse_max, ci_level, lower, guess_max)
    yes_no = alternatives == 1
    levels = np.asarray(levels, dtype=float)
    n = np.asarray(n, dtype=float)
    k = np.atleast_2d(np.asarray(k, dtype=float))
    B, L = k.shape
    if L < 2:
        raise ValueError(f"a psychometric function needs trials at two or more intensities, got {L}")
    if function == "weibull" and levels[0] <= 0:
        raise ValueError(f"the Weibull function needs intensities > 0, got {levels[0]:g}")
    if reference is not None and not math.isfinite(reference):
        reference = None
    u = stimulus_axis(levels, function)
    model = build_model(u, function, lower, guess, lapse, lapse_max, guess_max)
    theta, ll = solve(model, k, n, start_values(model, k, n))
    est = derived(model, theta, yes_no, reference)
    p_hat = model.predict(theta, False)[0]
    dev = deviance(k, n[None, :], p_hat)
    dof = L - model.n_params
    withheld = ""
    if dof <= 0:
        p_chi2 = np.full(B, np.nan)
        withheld = f"{L} levels leave no degrees of freedom"
    elif n.min() < CHI2_MIN_TRIALS:
        p_chi2 = np.full(B, np.nan)
        withheld = (f"{int(np.sum(n < CHI2_MIN_TRIALS))} of {L} levels hold fewer than {CHI2_MIN_TRIALS} trials: "
                    "the chi-square approximation does not hold (see the bootstrap p-value)")
    else:
        p_chi2 = stats.chi2.sf(dev, dof)
    profile, cutoff = profile_bounds(model, k, n, theta, ll, 0, ci_level, with_cutoff=True)
    thr_ci = from_axis(profile, function)
    names = ("threshold", "slope", "lapse", "guess", "jnd", "weber", "slope_at_threshold")
    pct = [{name: (math.nan, math.nan) for name in names} for _ in range(B)]
    bca = [{name: (math.nan, math.nan) for name in names} for _ in range(B)]
    p_boot = np.full(B, np.nan)
    boot_params = [None] * B
    if bootstrap:
        R = int(bootstrap)
        streams = np.random.default_rng(seed).spawn(B) if B > 1 else [np.random.default_rng(seed)]
        kb = _bootstrap_draws(streams, n, p_hat, R).reshape(B * R, L)
        start = np.repeat(theta, R, axis=0)
        tb = np.empty_like(start)
        for c in range(0, B * R, CHUNK):
            tb[c:c + CHUNK] = solve(model, kb[c:c + CHUNK], n, start[c:c + CHUNK])[0]
        devb = deviance(kb, n[None, :], model.predict(tb, False)[0]).reshape(B, R)
        p_boot = np.mean(devb >= dev[:, None] - 1e-9, axis=1)
        q = [(1 - ci_level) / 2, (1 + ci_level) / 2]
        boot = {name: v.reshape(B, R) for name, v in derived(model, tb, yes_no, reference).items()}
        jack_theta, jack_w, jack_owner = _jackknife(model, levels, n, k, theta)
        jack = derived(model, jack_theta, yes_no, reference)
        for b in range(B):
            boot_params[b] = tb[b * R:(b + 1) * R]
            own = jack_owner == b
            for name in names:
                v = boot[name][b]
                if not np.isfinite(v).all():
                    continue
                pct[b][name] = tuple(float(x) for x in np.quantile(v, q))
                bca[b][name] = bca_interval(float(est[name][b]), v, jack[name][own], jack_w[own], ci_level)
    out = []
    for b in range(B):
        lapse_b = float(est["lapse"][b])
        guess_b = float(est["guess"][b])
        tci = (float(thr_ci[b, 0]), float(thr_ci[b, 1]))
        jnd_ci, weber_ci = pct[b]["jnd"], pct[b]["weber"]
        jnd_bca, weber_bca = bca[b]["jnd"], bca[b]["weber"]
        if not yes_no and reference is not None and reference != 0:
            # JND = threshold - reference: its interval is the threshold's, exact
            jnd_ci = jnd_bca = (tci[0] - reference, tci[1] - reference)
            weber_ci = weber_bca = tuple(sorted((jnd_ci[0] / reference, jnd_ci[1] / reference)))
        flags = _flags(model, theta[b], {key: float(v[b]) for key, v in est.items()}, profile[b], levels, n, k[b],
                       float(p_boot[b]), float(p_chi2[b]), lapse_max, guess_max)
        out.append(Fit(function=function, alternatives=int(alternatives), guess=guess_b,
                       threshold=float(est["threshold"][b]), slope=float(est["slope"][b]),
                       lapse=lapse_b, lapse_fitted=lapse is None, lower_asymptote=lower,
                       jnd=float(est["jnd"][b]), weber=float(est["weber"][b]), pse=float(est["pse"][b]),
                       pse_ci=tci if yes_no else (math.nan, math.nan),
                       slope_at_threshold=float(est["slope_at_threshold"][b]),
                       reference=math.nan if reference is None else float(reference), deviance=float(dev[b]),
                       deviance_p_chi2=float(p_chi2[b]), deviance_p_chi2_withheld=withheld,
                       deviance_p_bootstrap=float(p_boot[b]),
                       loglik=float(ll[b]), n_trials=int(n.sum()), n_levels=L, bootstrap=int(bootstrap),
                       ci_level=ci_level, threshold_ci=tci, threshold_ci_cutoff=float(cutoff[b]),
                       threshold_ci_bootstrap=pct[b]["threshold"], threshold_ci_bca=bca[b]["threshold"],
                       slope_ci=pct[b]["slope"], slope_ci_bca=bca[b]["slope"],
                       lapse_ci=(float(lapse), float(lapse)) if lapse is not None and bootstrap else pct[b]["lapse"],
                       guess_ci=pct[b]["guess"] if lower != "fixed" else (guess_b, guess_b),
                       jnd_ci=jnd_ci, jnd_ci_bca=jnd_bca, weber_ci=weber_ci, weber_ci_bca=weber_bca,
                       slope_at_threshold_ci=pct[b]["slope_at_threshold"],
                       levels=tuple(levels.tolist()), n_per_level=tuple(n.tolist()), k_per_level=tuple(k[b].tolist()),
                       flags=flags, lapse_max=lapse_max, guess_max=guess_max,
                       slope_bounds=(float(model.lo[1]), float(model.hi[1])), boot_params=boot_params[b]))
    return out


def _jackknife(model, levels, n, k, theta):
    """Leave-one-trial-out refits of B data sets: one per (data set, level, answer) with trials, weighted by
    how many trials share it (the BCa acceleration's jackknife, without refitting identical sets).

    Returns
    -------
    theta : ndarray, shape (J, P)
    weights : ndarray, shape (J,)
    owner : ndarray of int, shape (J,)
        The data set each refit belongs to.
    """
    B, L = k.shape
    rows_k, rows_n, weights, owner, starts = [], [], [], [], []
    for b in range(B):
        for lvl in range(L):
            for correct, count in ((1.0, k[b, lvl]), (0.0, n[lvl] - k[b, lvl])):
                if count <= 0:
                    continue
                kk, nn = k[b].copy(), n.copy()
                kk[lvl] -= correct
                nn[lvl] -= 1.0
                rows_k.append(kk)
                rows_n.append(nn)
                weights.append(count)
                owner.append(b)
                starts.append(theta[b])
    kk, nn = np.array(rows_k), np.array(rows_n)
    th = np.empty((len(kk), theta.shape[1]))
    for c in range(0, len(kk), CHUNK):
        th[c:c + CHUNK] = solve(model, kk[c:c + CHUNK], nn[c:c + CHUNK], np.array(starts[c:c + CHUNK]))[0]
    return th, np.array(weights), np.array(owner)


def profile_interval(levels, n, k, alternatives: int = 2, function: str = "logistic", lapse=None,
                     lapse_max: float = LAPSE_MAX, ci_level: float = 0.95, lower_asymptote: str = "fixed",
                     guess_max: float = GUESS_MAX) -> np.ndarray:
    """The exact profile-likelihood interval of the threshold of B data sets (:func:`profile_bounds`).

    Parameters
    ----------
    levels, n : array_like, shape (L,)
    k : array_like, shape (L,) or (B, L)
    alternatives, function, lapse, lapse_max, ci_level, lower_asymptote, guess_max
        As for :func:`fit`.

    Returns
    -------
    ndarray, shape (B, 2)
        Low and high end in stimulus units (an open end is -inf or +inf; 0 for an open low end of a
        Weibull).
    """
    guess = _check_options(alternatives, lapse, lapse_max, ci_level, lower_asymptote, guess_max)
    k = np.atleast_2d(np.asarray(k, float))
    n = np.asarray(n, float)
    model = build_model(stimulus_axis(np.asarray(levels, float), function), function, lower_asymptote, guess, lapse,
                        lapse_max, guess_max)
    theta, ll = solve(model, k, n, start_values(model, k, n))
    return from_axis(profile_bounds(model, k, n, theta, ll, 0, ci_level), function)


# ---------------------------------------------------------------------------------------------------------------
# several conditions: shared parameters and likelihood-ratio model comparison (Palamedes)


@dataclass(frozen=True)
class MultiFit:
    """Fits of several conditions with some parameters shared (Palamedes' ``PAL_PFML_FitMultiple``).

    ``thresholds``, ``slopes``, ``lapses``, ``guesses`` hold one value per condition (equal where the
    parameter is constrained); ``threshold_ci`` the exact profile interval of each condition's threshold
    (one interval, repeated, when the thresholds are constrained).
    """

    conditions: tuple
    function: str
    alternatives: int
    options: dict
    thresholds: tuple
    slopes: tuple
    lapses: tuple
    guesses: tuple
    threshold_ci: tuple
    loglik: float
    n_params: int
    n_trials: int
    deviance: float

    def as_dict(self) -> dict:
        def clean(v):
            return None if isinstance(v, float) and not math.isfinite(v) else v
        return {"conditions": list(self.conditions), "function": self.function, "alternatives": self.alternatives,
                **self.options, "thresholds": [clean(v) for v in self.thresholds],
                "slopes": [clean(v) for v in self.slopes], "lapses": [clean(v) for v in self.lapses],
                "guesses": [clean(v) for v in self.guesses],
                "threshold_ci": [[clean(a), clean(b)] for a, b in self.threshold_ci],
                "loglik": self.loglik, "n_params": self.n_params, "n_trials": self.n_trials,
                "deviance": self.deviance}


def _stack(data, function):
    """Concatenated levels (fitting axis), trials, correct and condition index of ``data``."""
    if len(data) < 2:
        raise ValueError(f"a fit of several conditions needs two or more, got {len(data)}")
    us, ns, ks, cs = [], [], [], []
    for c, (levels, n, k) in enumerate(data):
        levels = np.asarray(levels, float)
        if function == "weibull" and np.any(levels <= 0):
            raise ValueError(f"condition {c + 1}: the Weibull function needs intensities > 0")
        us.append(stimulus_axis(levels, function))
        ns.append(np.asarray(n, float))
        ks.append(np.asarray(k, float))
        cs.append(np.full(len(levels), c))
    return np.concatenate(us), np.concatenate(ns), np.concatenate(ks), np.concatenate(cs)


def _fit_joint(data, alternatives, function, lapse, lapse_max, lower, guess_max, options, k_all=None):
    """Joint maximum-likelihood fit: (model, theta (B, P), loglik (B,), stacked n, stacked k (B, L))."""
    guess = _check_options(alternatives, lapse, lapse_max, 0.95, lower, guess_max)
    u, n, k, cond = _stack(data, function)
    model = build_model(u, function, lower, guess, lapse, lapse_max, guess_max, cond, **options)
    kk = np.atleast_2d(k if k_all is None else k_all)
    # start: each condition alone, then shared parameters at the mean of the conditions' own
    singles = []
    for c in range(int(cond.max()) + 1):
        m1 = build_model(u[cond == c], function, lower, guess, lapse, lapse_max, guess_max)
        kc = kk[:, cond == c]
        t1, _ = solve(m1, kc, n[cond == c], start_values(m1, kc, n[cond == c]))
        singles.append(t1)
    B = kk.shape[0]
    start = np.zeros((B, model.n_params))
    for kind, idx, col1 in (("a", model.ia, 0), ("s", model.islope, 1), ("l", model.il, 2),
                            ("g", model.ig, 2 + (model.il is not None))):
        if idx is None:
            continue
        for j in np.unique(idx):
            conds = np.unique(cond[idx == j])
            start[:, j] = np.mean([singles[c][:, col1] for c in conds], axis=0)
    theta, ll = solve(model, kk, n, start)
    return model, theta, ll, n, kk, cond


def fit_multiple(data, alternatives: int = 2, function: str = "logistic", thresholds: str = "unconstrained",
                 slopes: str = "constrained", lapses: str = "constrained", guesses: str = "constrained",
                 lapse=None, lapse_max: float = LAPSE_MAX, lower_asymptote: str = "fixed",
                 guess_max: float = GUESS_MAX, ci_level: float = 0.95, names=None,
                 intervals: bool = True) -> MultiFit:
    """Fit several conditions at once, each parameter shared or per condition (Palamedes' ``PAL_PFML_FitMultiple``).

    Parameters
    ----------
    data : list of (levels, n, k)
        Each condition's levels (stimulus units), trials and correct (or "yes") answers per level.
    alternatives, function, lapse, lapse_max, lower_asymptote, guess_max, ci_level
        As for :func:`fit` (a fixed ``lapse`` is every condition's).
    thresholds, slopes, lapses, guesses : {'constrained', 'unconstrained'}
        ``constrained``: one value shared by every condition; ``unconstrained``: one per condition.
        The default shares slope and lapse rate and lets the thresholds differ (comparing renderings).
    names : list of str, optional
        The conditions' names.
    intervals : bool
        Compute the thresholds' profile intervals (NaN without).

    Returns
    -------
    MultiFit
    """
    check_function(function, "psychometric function")
    options = {"thresholds": thresholds, "slopes": slopes, "lapses": lapses, "guesses": guesses}
    model, theta, ll, n, k, cond = _fit_joint(data, alternatives, function, lapse, lapse_max, lower_asymptote,
                                              guess_max, options)
    a, beta, lam, gam = (v[0] for v in model.parts(theta))
    C = len(data)
    first = [int(np.flatnonzero(cond == c)[0]) for c in range(C)]
    cis = []
    cols = sorted(set(int(model.ia[i]) for i in first))
    bounds = {col: (from_axis(profile_bounds(model, k, n, theta, ll, col, ci_level)[0], function) if intervals
                    else (math.nan, math.nan)) for col in cols}
    for c in range(C):
        lo, hi = bounds[int(model.ia[first[c]])]
        cis.append((float(lo), float(hi)))
    p = model.predict(theta, False)[0]
    return MultiFit(conditions=tuple(names) if names is not None else tuple(str(c + 1) for c in range(C)),
                    function=function, alternatives=int(alternatives),
                    options={**options, "lower_asymptote": lower_asymptote,
                             "lapse": None if lapse is None else float(lapse)},
                    thresholds=tuple(float(from_axis(a[i], function)) for i in first),
                    slopes=tuple(float(beta[i]) for i in first), lapses=tuple(float(lam[i]) for i in first),
                    guesses=tuple(float(gam[i]) for i in first), threshold_ci=tuple(cis), loglik=float(ll[0]),
                    n_params=model.n_params, n_trials=int(n.sum()), deviance=float(deviance(k, n, p)[0]))


@dataclass(frozen=True)
class ModelComparison:
    """A likelihood-ratio test of a lesser model against a fuller one (Palamedes' ``PAL_PFLR_ModelComparison``);
    the two fits carry no intervals (:func:`fit_multiple` gives them)."""

    lesser: MultiFit
    fuller: MultiFit
    lr: float
    df: int
    p_chi2: float
    p_bootstrap: float
    bootstrap: int
    lr_draws: np.ndarray | None = field(default=None, repr=False, compare=False)

    def as_dict(self) -> dict:
        def clean(v):
            return None if isinstance(v, float) and not math.isfinite(v) else v
        return {"lesser": self.lesser.as_dict(), "fuller": self.fuller.as_dict(), "lr": clean(self.lr),
                "df": self.df, "p_chi2": clean(self.p_chi2), "p_bootstrap": clean(self.p_bootstrap),
                "bootstrap": self.bootstrap}


def compare_models(data, lesser: dict, fuller: dict, alternatives: int = 2, function: str = "logistic",
                   lapse=None, lapse_max: float = LAPSE_MAX, lower_asymptote: str = "fixed",
                   guess_max: float = GUESS_MAX, bootstrap: int = 1000, seed: int = 0,
                   names=None) -> ModelComparison:
    """Likelihood-ratio test between two nested multi-condition models (Palamedes' ``PAL_PFLR_ModelComparison``).

    ``LR = 2 (lnL_fuller - lnL_lesser)``, compared with chi-square on ``df`` = the difference in free
    parameters, and with its distribution over ``bootstrap`` data sets simulated from the lesser model's
    fit, each fitted by both models (Palamedes' Monte Carlo p-value: the fraction of simulated LRs at least
    as large as the observed).

    Parameters
    ----------
    data : list of (levels, n, k)
    lesser, fuller : dict
        Options of :func:`fit_multiple` (``thresholds``, ``slopes``, ``lapses``, ``guesses``); the lesser
        model must be nested in the fuller (each parameter at least as constrained).
    alternatives, function, lapse, lapse_max, lower_asymptote, guess_max
        As for :func:`fit_multiple`.
    bootstrap : int
        Simulated data sets (0: chi-square only).
    seed : int
    names : list of str, optional

    Returns
    -------
    ModelComparison
    """
    keys = ("thresholds", "slopes", "lapses", "guesses")
    opt_l = {key: lesser.get(key, "constrained" if key != "thresholds" else "unconstrained") for key in keys}
    opt_f = {key: fuller.get(key, "constrained" if key != "thresholds" else "unconstrained") for key in keys}
    unknown = (set(lesser) | set(fuller)) - set(keys)
    if unknown:
        raise ValueError(f"model options are {', '.join(keys)}; got {sorted(unknown)}")
    if any(opt_l[key] == "unconstrained" and opt_f[key] == "constrained" for key in keys):
        raise ValueError(f"the lesser model {opt_l} is not nested in the fuller {opt_f}")
    common = dict(alternatives=alternatives, function=function, lapse=lapse, lapse_max=lapse_max,
                  lower_asymptote=lower_asymptote, guess_max=guess_max, names=names, intervals=False)
    fit_l = fit_multiple(data, **opt_l, **common)
    fit_f = fit_multiple(data, **opt_f, **common)
    lr = max(2.0 * (fit_f.loglik - fit_l.loglik), 0.0)
    df = fit_f.n_params - fit_l.n_params
    p_chi2 = float(stats.chi2.sf(lr, df)) if df > 0 else math.nan
    p_boot = math.nan
    if bootstrap:
        model_l, theta_l, _, n, _, _ = _fit_joint(data, alternatives, function, lapse, lapse_max, lower_asymptote,
                                                  guess_max, opt_l)
        p_l = model_l.predict(theta_l, False)[0][0]
        rng = np.random.default_rng(seed)
        kb = rng.binomial(n.astype(np.int64), np.clip(p_l, 0, 1), size=(int(bootstrap), len(n))).astype(float)
        lls = []
        for opts in (opt_l, opt_f):
            _, _, ll, _, _, _ = _fit_joint(data, alternatives, function, lapse, lapse_max, lower_asymptote,
                                           guess_max, opts, k_all=kb)
            lls.append(ll)
        lr_b = np.maximum(2.0 * (lls[1] - lls[0]), 0.0)
        p_boot = float(np.mean(lr_b >= lr - 1e-9))
    return ModelComparison(fit_l, fit_f, float(lr), int(df), p_chi2, p_boot, int(bootstrap),
                           lr_b if bootstrap else None)
