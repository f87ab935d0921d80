"""JZS Bayes factors of paired t-tests (Rouder, Speckman, Sun, Morey & Iverson 2009).

A Bayes factor weighs the evidence for a difference (BF10 > 1) against the evidence for no
difference (BF10 < 1, i.e. BF01 = 1/BF10 > 1), which a non-significant p-value cannot do. The
prior on the standardised effect d_z is a Cauchy with scale ``r`` (default 0.707, the "medium"
prior of pingouin, JASP and the R package BayesFactor).
"""

from __future__ import annotations

import numpy as np
from scipy.special import logsumexp

#: scale of the Cauchy prior on the standardised effect (Rouder et al. 2009; pingouin/JASP default)
JZS_R = 0.707

# the integral over g is taken on u = ln g (its integrand is smooth and unimodal there): the
# inverse-gamma(1/2, 1/2) prior of g vanishes like exp(-e^-u / 2) below u = -8 (< 1e-600) and the
# integrand decays like e^-u above; a trapezoid on this grid (step 0.057) is accurate to ~1e-11 relative
# (checked against adaptive quadrature and pingouin in tests/analysis/test_analysis_models.py)
_U = np.linspace(-8.0, 60.0, 1201)


def log_bf10_paired(t, n, r: float = JZS_R) -> np.ndarray:
    """Natural log of the JZS Bayes factor BF10 of one-sample / paired t-statistics.

    Rouder et al. (2009), eq. 1, with ``df = n - 1``:
    ``BF10 = int_0^inf (1 + n g r^2)^(-1/2) (1 + t^2 / ((1 + n g r^2) df))^(-(df+1)/2)
    (2 pi)^(-1/2) g^(-3/2) exp(-1/(2 g)) dg / (1 + t^2/df)^(-(df+1)/2)``,
    evaluated in log space, so that the very large t of thousands of subjects gives a finite
    log instead of an overflow.

    Parameters
    ----------
    t : array_like of float, shape (m,)
        Paired t-statistics (NaN gives NaN).
    n : array_like of int, shape (m,) or scalar
        Number of pairs behind each t (n < 2 gives NaN).
    r : float
        Scale of the Cauchy prior on d_z.

    Returns
    -------
    ndarray of float, shape (m,)
    """
    t = np.atleast_1d(np.asarray(t, dtype=float))
    n = np.broadcast_to(np.asarray(n, dtype=float), t.shape)
    out = np.full(t.shape, np.nan)
    ok = np.isfinite(t) & (n >= 2)
    if not ok.any():
        return out
    tt, nn = t[ok][:, None], n[ok][:, None]
    df = nn - 1.0
    g = np.exp(_U)[None, :]
    a = 1.0 + nn * g * r * r
    log_f = (-0.5 * np.log(a) - 0.5 * (df + 1.0) * np.log1p(tt * tt / (a * df))
             - 0.5 * np.log(2.0 * np.pi) - 1.5 * _U[None, :] - 0.5 / g + _U[None, :])   # + u: dg = g du
    du = _U[1] - _U[0]
    weights = np.full(_U.size, du)
    weights[[0, -1]] = du / 2.0
    log_int = logsumexp(log_f + np.log(weights)[None, :], axis=1)
    log_null = -0.5 * (df[:, 0] + 1.0) * np.log1p(tt[:, 0] ** 2 / df[:, 0])
    out[ok] = log_int - log_null
    return out


def bf10_paired(t, n, r: float = JZS_R) -> np.ndarray:
    """JZS Bayes factor BF10 of paired t-statistics (see :func:`log_bf10_paired`); inf when above ~1e308."""
    with np.errstate(over="ignore"):
        return np.exp(log_bf10_paired(t, n, r))


def evidence_words(bf10: float) -> str:
    """Plain words for a BF10 on Jeffreys' scale as revised by Lee & Wagenmakers (2013).

    Returns e.g. ``"moderate evidence for no difference (BF01 = 4.2)"``.
    """
    if bf10 is None or np.isnan(bf10):
        return "no Bayes factor (too few subjects)"
    for_diff = bf10 >= 1.0
    b = bf10 if for_diff else (np.inf if bf10 == 0 else 1.0 / bf10)
    strength = ("anecdotal" if b < 3 else "moderate" if b < 10 else "strong" if b < 30
                else "very strong" if b < 100 else "extreme")
    what = "a difference" if for_diff else "no difference"
    label = ("BF10 > 1e308" if np.isinf(b) else f"BF10 = {bf10:.3g}") if for_diff else \
        ("BF01 > 1e308" if np.isinf(b) else f"BF01 = {b:.3g}")
    return f"{strength} evidence for {what} ({label})"
