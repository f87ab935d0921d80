"""A linear mixed model of repeated ratings, fitted by REML, with Satterthwaite degrees of freedom.

The model (:mod:`analysis.models` builds its design)::

    y = X beta + Z_i b_i + u_c + e,    b_i ~ N(0, G),  u_c ~ N(0, s2_cell),  e ~ N(0, s2)

with ``i`` the subject, ``Z_i`` its random-effect columns (an intercept, and a velocity slope where the
data support it) and ``c`` the subject x sample cell (nested in the subject): the subjects' own rating
level, their own velocity effect, and their own view of each sample beyond their attempts' noise. The
cell term is lme4's ``(1 | subject:sample)`` beside ``(1 | subject)``: without it every attempt counts
as an independent look at a sample effect that in fact varies between subjects, and a few subjects' many
attempts give far too many "significant" contrasts (Barr, Levy, Scheepers & Tily 2013; the design is the
classical split plot, whose within-subject contrasts have (n - 1)(k - 1) error degrees of freedom).

Why not statsmodels ``MixedLM`` with a variance component: on 40 subjects x 12 samples x 3 attempts it
took 1.3-2.8 s per fit, and on 200 subjects its lbfgs fit stopped 116 REML log-likelihood units below
the maximum its Powell fit found. Here the covariance is nested (cells inside subjects), so V^-1 has a
closed form per cell and a q x q Woodbury step per subject, and every evaluation is a few vectorised
sums over rows, cells and subjects (a fit of 40 subjects: ~30 ms). The log-likelihood is statsmodels'
own REML log-likelihood (equal to ~1e-9 at its estimates, tested) and the estimates equal its fit's.

Degrees of freedom: Satterthwaite (1946) for each linear combination ``L beta`` as lmerTest computes
them (Kuznetsova, Brockhoff & Christensen 2017; Giesbrecht & Burns 1985)::

    df = 2 (L C L')^2 / (g' A g),   g_k = L (dC/dtheta_k) L',   A = 2 H^-1

with ``C`` the covariance of beta-hat as a function of the variance parameters theta (G's entries,
s2_cell, s2), ``H`` the Hessian of the REML deviance (-2 log-likelihood) in theta, both by central
differences at the estimate (lmerTest differentiates numerically too). A variance estimated at zero is
held at zero (it is not a free parameter there). On a balanced design the df are exact: (n - 1)(k - 1)
for a within-subject contrast, and the Welch-Satterthwaite combination of the subject and
subject x sample mean squares for a sample's mean (tested against those hand formulas and against
statsmodels' OLS on the cell means).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

#: a variance below this share of the residual variance counts as zero (on the boundary)
ZERO_VARIANCE = 1e-6
STEP = 2e-2
LOG_2PI = float(np.log(2 * np.pi))


class NotFitted(ValueError):
    """The model cannot be fitted to these data (the message says why, in words)."""


@dataclass(frozen=True)
class LMMFit:
    """A fitted model: fixed effects, variances and what the degrees of freedom need.

    Attributes
    ----------
    beta : ndarray, shape (p,)
        Fixed effects (GLS at the REML variances).
    cov_beta : ndarray, shape (p, p)
        Their covariance ``C = (X' V^-1 X)^-1``.
    G : ndarray, shape (q, q)
        Covariance of the subjects' random effects (rating units squared; ``G[0, 0]`` the intercept's).
    cell_var : float
        Variance of the subject x sample cells (0 where the cell term is absent or at zero).
    resid_var : float
        Attempt-to-attempt variance.
    loglik : float
        REML log-likelihood (statsmodels' ``MixedLMResults.llf`` convention).
    converged : bool
    varpar_names : tuple of str
        The variance parameters free at the estimate (those at zero are held there).
    varpar_cov : ndarray or None
        Their asymptotic covariance ``2 H^-1``; None where the Hessian is not positive definite.
    jac : ndarray, shape (k, p, p)
        ``dC/dtheta_k`` for each free variance parameter.
    """

    beta: np.ndarray
    cov_beta: np.ndarray
    G: np.ndarray
    cell_var: float
    resid_var: float
    loglik: float
    converged: bool
    varpar_names: tuple
    varpar_cov: np.ndarray | None
    jac: np.ndarray
    n_obs: int
    n_subjects: int


class NestedLMM:
    """The REML likelihood of the nested model for one data set (rows sorted by subject and cell once).

    Parameters
    ----------
    y : ndarray, shape (n,)
    X : ndarray, shape (n, p)
        Fixed-effect design, full column rank.
    subject : ndarray of int, shape (n,)
    cell : ndarray of int or None, shape (n,)
        Cell of each row (nested in the subject: a cell holds one subject's rows); None: no cell term.
    Z : ndarray, shape (n, q) or None
        Random-effect columns per subject; None: a random intercept.
    """

    def __init__(self, y, X, subject, cell=None, Z=None):
        y = np.asarray(y, dtype=float)
        X = np.asarray(X, dtype=float)
        subject = np.asarray(subject)
        n, p = X.shape
        Z = np.ones((n, 1)) if Z is None else np.asarray(Z, dtype=float).reshape(n, -1)
        self.with_cell = cell is not None
        cell = np.asarray(cell) if cell is not None else np.arange(n)
        order = np.lexsort((cell, subject))
        s, c = subject[order], cell[order]
        self.n, self.p, self.q = n, p, Z.shape[1]
        XY = np.column_stack([X[order], y[order]])
        Zs = Z[order]
        new_cell = np.r_[True, (c[1:] != c[:-1]) | (s[1:] != s[:-1])]
        new_subject = np.r_[True, s[1:] != s[:-1]]
        cell_start = np.flatnonzero(new_cell)
        subj_start = np.flatnonzero(new_subject)
        self.n_subjects = subj_start.size
        self.n_cell = np.diff(np.r_[cell_start, n]).astype(float)              # rows per cell
        # the cells of each subject are contiguous: where each subject's first cell is among the cells
        self.cell_subj_start = np.searchsorted(cell_start, subj_start)
        self.XtX = XY.T @ XY
        self.sXY = np.add.reduceat(XY, cell_start, axis=0)                     # (C, p + 1) cell sums
        self.sZ = np.add.reduceat(Zs, cell_start, axis=0)                      # (C, q)
        self.ZtXY = np.add.reduceat(Zs[:, :, None] * XY[:, None, :], subj_start, axis=0)   # (S, q, p + 1)
        self.ZtZ = np.add.reduceat(Zs[:, :, None] * Zs[:, None, :], subj_start, axis=0)    # (S, q, q)
        self.ZsZs = self.sZ[:, :, None] * self.sZ[:, None, :]                 # (C, q, q)

    # -- the likelihood ---------------------------------------------------------------------------------------
    def _relative(self, G_rel: np.ndarray, cell_rel: float):
        """Quadratic forms of ``H = V / s2`` with relative variances: ``([X y]' H^-1 [X y], log|H|)``.

        Per cell, ``A = I + cell_rel J`` has ``A^-1 = I - w J``, ``w = cell_rel / (1 + n_c cell_rel)``;
        per subject, ``H^-1 = A^-1 - A^-1 Z (I + G U)^-1 G Z' A^-1`` with ``U = Z' A^-1 Z`` (Woodbury,
        no inverse of G: a variance at zero is allowed).
        """
        if self.with_cell:
            w = cell_rel / (1.0 + self.n_cell * cell_rel)
            sXYw = self.sXY * w[:, None]
            XtAiXY = self.XtX - sXYw.T @ self.sXY
            U = self.ZtZ - np.add.reduceat(w[:, None, None] * self.ZsZs, self.cell_subj_start, axis=0)
            P = self.ZtXY - np.add.reduceat(self.sZ[:, :, None] * sXYw[:, None, :], self.cell_subj_start, axis=0)
            logdet_A = float(np.sum(np.log1p(self.n_cell * cell_rel)))
        else:
            XtAiXY, U, P, logdet_A = self.XtX, self.ZtZ, self.ZtXY, 0.0
        if self.q == 1:                         # scalars per subject (most fits): no batched linear algebra
            K = 1.0 + G_rel[0, 0] * U[:, 0, 0]
            if np.any(K <= 0):
                return None, np.inf
            P0 = P[:, 0, :]
            quad = XtAiXY - (P0.T * (G_rel[0, 0] / K)) @ P0
            return quad, logdet_A + float(np.sum(np.log(K)))
        if self.q == 2:                         # a random slope: 2 x 2 per subject in closed form
            g00, g01, g11 = G_rel[0, 0], G_rel[1, 0], G_rel[1, 1]
            u00, u01, u11 = U[:, 0, 0], U[:, 1, 0], U[:, 1, 1]
            k00, k01 = 1.0 + g00 * u00 + g01 * u01, g00 * u01 + g01 * u11
            k10, k11 = g01 * u00 + g11 * u01, 1.0 + g01 * u01 + g11 * u11
            det = k00 * k11 - k01 * k10
            if np.any(det <= 0):
                return None, np.inf
            # M = K^-1 G (symmetric: (G^-1 + U)^-1)
            m00 = (k11 * g00 - k01 * g01) / det
            m01 = (k11 * g01 - k01 * g11) / det
            m11 = (k00 * g11 - k10 * g01) / det
            P0, P1 = P[:, 0, :], P[:, 1, :]
            cross = (P0.T * m01) @ P1
            quad = XtAiXY - (P0.T * m00) @ P0 - cross - cross.T - (P1.T * m11) @ P1
            return quad, logdet_A + float(np.sum(np.log(det)))
        K = np.eye(self.q)[None] + G_rel[None] @ U                              # (S, q, q)
        sign, logdet_K = np.linalg.slogdet(K)
        if np.any(sign <= 0):
            return None, np.inf
        M = np.linalg.solve(K, np.broadcast_to(G_rel, K.shape))                 # (I + G U)^-1 G
        quad = XtAiXY - np.einsum("sqa,sqr,srb->ab", P, M, P)
        return quad, logdet_A + float(logdet_K.sum())

    def _gls(self, quad):
        """GLS pieces of ``quad`` = [X y]' H^-1 [X y]: (beta, (X'H^-1X)^-1, log|X'H^-1X|, residual quadratic form)."""
        p = self.p
        xtx = quad[:p, :p]
        try:
            chol = np.linalg.cholesky(xtx)
        except np.linalg.LinAlgError:
            return None
        beta = np.linalg.solve(xtx, quad[:p, p])
        inv = np.linalg.inv(xtx)
        rss = float(quad[p, p] - quad[:p, p] @ beta)
        return beta, (inv + inv.T) / 2, 2.0 * float(np.sum(np.log(np.diag(chol)))), rss

    def profiled_deviance(self, G_rel: np.ndarray, cell_rel: float) -> float:
        """REML deviance (-2 log-likelihood) with the residual variance profiled out."""
        quad, logdet_H = self._relative(G_rel, cell_rel)
        if quad is None:
            return np.inf
        gls = self._gls(quad)
        if gls is None or not gls[3] > 0:
            return np.inf
        dof = self.n - self.p
        return dof * (np.log(gls[3] / dof) + 1.0 + LOG_2PI) + logdet_H + gls[2]

    def deviance(self, G: np.ndarray, cell_var: float, resid_var: float) -> float:
        """REML deviance at absolute variances (for the Hessian of the degrees of freedom)."""
        if not resid_var > 0:
            return np.inf
        quad, logdet_H = self._relative(G / resid_var, cell_var / resid_var)
        if quad is None:
            return np.inf
        gls = self._gls(quad)
        if gls is None:
            return np.inf
        dof = self.n - self.p
        return (self.n * np.log(resid_var) + logdet_H + gls[2] - self.p * np.log(resid_var)
                + gls[3] / resid_var + dof * LOG_2PI)

    def cov_beta(self, G: np.ndarray, cell_var: float, resid_var: float) -> np.ndarray:
        """``C = (X' V^-1 X)^-1`` at absolute variances."""
        quad, _ = self._relative(G / resid_var, cell_var / resid_var)
        gls = self._gls(quad) if quad is not None else None
        if gls is None:
            return np.full((self.p, self.p), np.nan)
        return resid_var * gls[1]

    def estimates(self, G_rel: np.ndarray, cell_rel: float):
        """(beta, C, residual variance) at relative variances."""
        quad, _ = self._relative(G_rel, cell_rel)
        beta, inv, _, rss = self._gls(quad)
        s2 = rss / (self.n - self.p)
        return beta, s2 * inv, s2


def _unpack(theta: np.ndarray, q: int, with_cell: bool) -> tuple[np.ndarray, float]:
    """Relative Cholesky factor of G (lme4's theta) and the cell's relative SD -> (G / s2, s2_cell / s2)."""
    L = np.zeros((q, q))
    L[np.tril_indices(q)] = theta[: q * (q + 1) // 2]
    cell = float(theta[-1]) ** 2 if with_cell else 0.0
    return L @ L.T, cell


def fit_lmm(y, X, subject, cell=None, Z=None) -> LMMFit:
    """REML fit of the nested model (module docstring) and what Satterthwaite's df need.

    Raises
    ------
    NotFitted
        With the reason in words: a singular design, no finite likelihood, no convergence.
    """
    model = NestedLMM(y, X, subject, cell, Z)
    n, p, q = model.n, model.p, model.q
    if n - p < 1:
        raise NotFitted(f"{n} attempts for {p} fixed effects: no residual degrees of freedom")
    if np.linalg.matrix_rank(np.asarray(X, dtype=float)) < p:
        raise NotFitted("the fixed effects are not estimable (a sample or covariate column is a combination of "
                        "the others)")
    k_chol = q * (q + 1) // 2
    k = k_chol + (1 if model.with_cell else 0)
    diag = {i * (i + 1) // 2 + i for i in range(q)}            # positions of L's diagonal in the packed lower triangle
    positive = np.array([j in diag or j >= k_chol for j in range(k)])     # the SDs (not the correlations)

    def objective(theta):
        return model.profiled_deviance(*_unpack(theta, q, model.with_cell))

    def gradient(theta):
        h = 1e-6 * np.maximum(np.abs(theta), 1e-2)
        g = np.empty_like(theta)
        for j in range(theta.size):
            e = np.zeros_like(theta)
            e[j] = h[j]
            g[j] = (objective(theta + e) - objective(theta - e)) / (2 * h[j])
        return g

    def converged_at(theta):
        g = gradient(theta)
        free = ~positive | (theta > 1e-4)           # a relative SD at zero: the variance is on the boundary
        # the deviance grows with the attempts: its gradient's noise and a negligible slope alike
        return bool(np.all(np.isfinite(g)) and np.all(np.abs(g[free]) < 1e-3 + 1e-6 * abs(objective(theta))))

    best, converged = None, False
    for start in (0.5, 0.1, 1.5):
        theta0 = np.where(positive, start, 0.0)
        if not np.isfinite(objective(theta0)):
            continue
        # unbounded: the deviance is even in each relative SD (G = L L', s2_cell = c^2), so a variance at zero
        # is an ordinary stationary point (statsmodels' MixedLM too optimises square roots with BFGS)
        with np.errstate(all="ignore"):
            res = optimize.minimize(objective, theta0, jac=gradient, method="BFGS",
                                    options={"gtol": 1e-5, "maxiter": 200})
        if not np.isfinite(res.fun):
            continue
        theta = _newton_polish(objective, np.where(positive, np.abs(res.x), res.x), positive)
        dev = objective(theta)
        if best is None or dev < best[1] - 1e-9:
            best = (theta, dev)
        converged = converged_at(best[0])
        if converged:
            break
    if best is None:
        raise NotFitted("the REML likelihood is not finite at any start (the data leave no variance to model)")
    theta, dev = best
    G_rel, cell_rel = _unpack(theta, q, model.with_cell)
    beta, C, s2 = model.estimates(G_rel, cell_rel)
    if not (np.all(np.isfinite(C)) and s2 > 0):
        raise NotFitted("no finite standard errors at the estimate")
    G, cell_var = s2 * G_rel, s2 * cell_rel
    names, jac, vcov = _varpar_derivatives(model, G, cell_var, s2)
    return LMMFit(beta, C, G, float(cell_var), float(s2), -0.5 * dev, converged, names, vcov, jac, n,
                  model.n_subjects)


def _newton_polish(objective, theta: np.ndarray, positive: np.ndarray, steps: int = 3) -> np.ndarray:
    """A few Newton steps (central-difference gradient and Hessian) on the free coordinates of ``theta``.

    BFGS on a numerical gradient stops ~1e-5 short of the optimum in the variances; the degrees of freedom
    are ratios of the likelihood's curvature and need the optimum itself. Coordinates at zero (a variance
    on the boundary) stay there; a step that does not lower the deviance ends the polish.
    """
    f = objective(theta)
    for _ in range(steps):
        free = np.flatnonzero(~positive | (theta > 1e-4))
        if free.size == 0:
            break
        h = 1e-4 * np.maximum(np.abs(theta[free]), 1e-2)
        g = np.empty(free.size)
        H = np.empty((free.size, free.size))
        for a, i in enumerate(free):
            ei = np.zeros_like(theta)
            ei[i] = h[a]
            fp, fm = objective(theta + ei), objective(theta - ei)
            g[a] = (fp - fm) / (2 * h[a])
            H[a, a] = (fp - 2 * f + fm) / h[a] ** 2
            for b in range(a):
                ej = np.zeros_like(theta)
                ej[free[b]] = h[b]
                H[a, b] = H[b, a] = (objective(theta + ei + ej) - objective(theta + ei - ej)
                                     - objective(theta - ei + ej) + objective(theta - ei - ej)) / (4 * h[a] * h[b])
        if not (np.all(np.isfinite(H)) and np.all(np.isfinite(g))):
            break
        try:
            if np.linalg.eigvalsh(H).min() <= 0:
                break
            step = np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            break
        trial = theta.copy()
        trial[free] -= step
        trial = np.where(positive, np.abs(trial), trial)
        ft = objective(trial)
        if not ft <= f:
            break
        theta, f = trial, ft
        if np.max(np.abs(step)) < 1e-10:
            break
    return theta


def _varpar_derivatives(model: NestedLMM, G: np.ndarray, cell_var: float, s2: float):
    """Free variance parameters, ``dC/dtheta`` (k, p, p) and ``2 H^-1`` (central differences, lmerTest's way).

    G's entries enter as variances and covariances; a variance at zero (below :data:`ZERO_VARIANCE` of s2)
    and its covariances are held at zero; so is the cell variance.
    """
    q = model.q
    names, getters = [], []
    live = [i for i in range(q) if G[i, i] > ZERO_VARIANCE * s2]
    for a in range(q):
        for b in range(a + 1):
            if a in live and b in live:
                names.append(f"G[{a},{b}]")
                getters.append((a, b))
    if model.with_cell and cell_var > ZERO_VARIANCE * s2:
        names.append("cell")
        getters.append("cell")
    names.append("residual")
    getters.append("residual")
    theta0 = np.array([G[g] if isinstance(g, tuple) else cell_var if g == "cell" else s2 for g in getters])

    def build(theta):
        Gt = np.zeros((q, q))
        cell, resid = 0.0, s2
        for value, g in zip(theta, getters):
            if isinstance(g, tuple):
                Gt[g] = Gt[g[::-1]] = value
            elif g == "cell":
                cell = value
            else:
                resid = value
        return Gt, cell, resid

    # steps: a share of each variance (of the geometric mean of the two for a covariance); central differences
    # at steps h and h/2 combined by Richardson's extrapolation, (4 D(h/2) - D(h)) / 3, which cancels the h^2
    # error: with h = 2 % the df of a balanced design are exact to ~1e-7 (one step of 1e-4 left roundoff of
    # ~3e-4 in the deviance's second differences, one of 1 % an h^2 error of ~1e-3)
    scale = np.array([np.sqrt(G[g[0], g[0]] * G[g[1], g[1]]) if isinstance(g, tuple) else
                      cell_var if g == "cell" else s2 for g in getters])
    k = theta0.size

    def derivatives(step):
        jac = np.empty((k, model.p, model.p))
        H = np.empty((k, k))
        f0 = model.deviance(*build(theta0))
        for i in range(k):
            ei = np.zeros(k)
            ei[i] = step[i]
            jac[i] = (model.cov_beta(*build(theta0 + ei)) - model.cov_beta(*build(theta0 - ei))) / (2 * step[i])
            H[i, i] = (model.deviance(*build(theta0 + ei)) - 2 * f0 + model.deviance(*build(theta0 - ei))) / step[i] ** 2
            for j in range(i):
                ej = np.zeros(k)
                ej[j] = step[j]
                H[i, j] = H[j, i] = (model.deviance(*build(theta0 + ei + ej)) - model.deviance(*build(theta0 + ei - ej))
                                     - model.deviance(*build(theta0 - ei + ej))
                                     + model.deviance(*build(theta0 - ei - ej))) / (4 * step[i] * step[j])
        return jac, H

    jac_h, H_h = derivatives(STEP * scale)
    jac_h2, H_h2 = derivatives(STEP / 2 * scale)
    jac, H = (4 * jac_h2 - jac_h) / 3, (4 * H_h2 - H_h) / 3
    vcov = None
    if np.all(np.isfinite(H)):
        eig = np.linalg.eigvalsh((H + H.T) / 2)
        if eig.min() > 0:
            vcov = 2.0 * np.linalg.inv(H)
    return tuple(names), jac, vcov


def satterthwaite_df(fit: LMMFit, L: np.ndarray) -> np.ndarray:
    """Satterthwaite degrees of freedom of each row of ``L`` (shape (m, p)): ``2 (L C L')^2 / (g' A g)``.

    NaN where the variance parameters' covariance is not available (Hessian not positive definite) or the
    denominator vanishes; the df never exceed the residual df ``n - p`` nor fall below 1.
    """
    L = np.atleast_2d(np.asarray(L, dtype=float))
    if fit.varpar_cov is None:
        return np.full(L.shape[0], np.nan)
    var = np.einsum("ij,jk,ik->i", L, fit.cov_beta, L)
    g = np.einsum("ij,mjk,ik->im", L, fit.jac, L)                  # (m, k)
    denom = np.einsum("im,mn,in->i", g, fit.varpar_cov, g)
    with np.errstate(divide="ignore", invalid="ignore"):
        df = 2.0 * var ** 2 / denom
    df = np.where(np.isfinite(df) & (denom > 0), df, np.nan)
    return np.clip(df, 1.0, fit.n_obs - fit.beta.size)
