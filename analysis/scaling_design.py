"""How many trials a participant needs in the scaling kinds: settings per reference for the method of adjustment's
PSE, repetitions of the levels for magnitude estimation's exponent (docs/study.md, "How many trials").

A participant's PSE is the geometric mean of its n settings; with settings of log-SD s its error is normal on
the log scale with SD s / sqrt(n). A participant's exponent is the OLS slope of ln N on ln phi; its SD is
``r / sqrt(R * sum (ln phi - mean ln phi)^2)`` for R repetitions of the levels and a residual log-SD r of the
numbers about the power law (:func:`magnitude_residual_sd`: the percept's Weber noise times the exponent and
the response noise, in quadrature).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from psychophysics.sdt import Z75_SQRT2  # the percept's log-SD per unit of ln(1 + W) for a 2-interval JND W

TOLERANCE_PSE, TOLERANCE_EXPONENT, WITHIN = 0.05, 0.05, 0.95


def fraction_within(sd_log: float, n: int, tolerance: float = TOLERANCE_PSE) -> float:
    """Expected fraction of participants whose PSE, the geometric mean of ``n`` settings of log-SD ``sd_log``,
    lies within ``+-tolerance`` (a fraction) of their true PSE.

    The log of the geometric mean is normal with SD ``sd_log / sqrt(n)`` about the log of the truth, so the
    fraction is ``Phi(ln(1 + tol) sqrt(n) / sd) - Phi(ln(1 - tol) sqrt(n) / sd)``.
    """
    z = math.sqrt(n) / sd_log
    return float(stats.norm.cdf(math.log1p(tolerance) * z) - stats.norm.cdf(math.log1p(-tolerance) * z))


def trials_needed(sd_log: float, tolerance: float = TOLERANCE_PSE, within: float = WITHIN) -> int:
    """The fewest settings per participant that put a fraction ``within`` of participants' PSEs within
    ``+-tolerance`` (:func:`fraction_within`); about ``(1.96 sd_log / ln(1 + tol))^2`` for 95 %."""
    n = 1
    while fraction_within(sd_log, n, tolerance) < within:
        n += 1
    return n


def magnitude_residual_sd(weber: float, exponent: float, response_sd: float, modulus: bool = False) -> float:
    """Log-SD of a participant's numbers about its power law: the percept's Weber noise, log-SD
    ``ln(1 + W) / (z75 sqrt 2)`` (a 2-interval JND W), times the exponent, and the response noise, in
    quadrature; with a ``modulus`` the standard's remembered percept (as noisy as any percept, times the
    exponent) sets each run of trials' scale, once more in quadrature."""
    percept = exponent * math.log1p(weber) / Z75_SQRT2
    return math.sqrt(percept ** 2 * (2 if modulus else 1) + response_sd ** 2)


def exponent_fraction_within(residual_sd: float, levels, repetitions: int,
                             tolerance: float = TOLERANCE_EXPONENT) -> float:
    """Expected fraction of participants whose exponent (the OLS slope of ln N on ln phi over ``repetitions``
    presentations of each of ``levels``) lies within ``+-tolerance`` of their true exponent:
    ``2 Phi(tol / se) - 1``, ``se = residual_sd / sqrt(repetitions * sum (ln phi - mean ln phi)^2)``."""
    x = np.log(np.asarray(levels, float))
    se = residual_sd / math.sqrt(repetitions * float(np.sum((x - x.mean()) ** 2)))
    return float(2 * stats.norm.cdf(tolerance / se) - 1)


def repetitions_needed(residual_sd: float, levels, tolerance: float = TOLERANCE_EXPONENT,
                       within: float = WITHIN) -> int:
    """The fewest repetitions of ``levels`` that put a fraction ``within`` of participants' exponents within
    ``+-tolerance`` (:func:`exponent_fraction_within`)."""
    r = 1
    while exponent_fraction_within(residual_sd, levels, r, tolerance) < within:
        r += 1
    return r
