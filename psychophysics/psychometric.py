"""The psychometric function: one parametrisation for the adaptive methods, the fits and the simulated observer.

.. math::

    \\psi(x) = \\gamma + (1 - \\gamma - \\lambda)\\, F(x; \\alpha, \\beta)

with the sigmoid ``F`` one of

* ``logistic``: ``F = 1 / (1 + exp(-beta * (x - alpha)))``
* ``normal``:   ``F = Phi(beta * (x - alpha))`` (``beta = 1 / sigma``)
* ``weibull``:  ``F = 1 - exp(-ln(2) * (x / alpha) ** beta)`` (``x > 0``)

The threshold ``alpha`` is the stimulus where ``F = 0.5`` (before the guess rate ``gamma`` and the lapse
rate ``lambda`` scale it), for every function; ``beta`` is the slope parameter as written above. ``gamma`` is
``1/n`` for an n-alternative forced choice and 0 for yes/no and "which was harder?" tasks (Kingdom & Prins
2016, *Psychophysics: a practical introduction*, ch. 4; Wichmann & Hill 2001, *Percept. Psychophys.* 63(8)).
The thresholds and slopes of the three functions are therefore not interchangeable: a logistic slope is per
intensity unit, a Weibull slope is dimensionless (its shape exponent). For a 2AFC task with no lapses the
threshold is the 75 %-correct point (psignifit 4's ``thresh_PC = 0.5``).

All three are location-scale families of ``z = beta (u - a)`` with ``u = x, a = alpha`` (logistic, normal)
or ``u = ln x, a = ln alpha`` (Weibull: a Gumbel in log stimulus): :func:`base_cdf` of ``z`` on
:func:`stimulus_axis`. That is how :mod:`psychophysics.fitting` fits them; :func:`sigmoid` computes the same
numbers directly.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special

from .names import FUNCTIONS

LN2 = math.log(2.0)


def check_function(function: str, name: str = "function") -> str:
    """Return ``function`` if it is one of :data:`FUNCTIONS`, else raise ``ValueError`` naming ``name``."""
    if function not in FUNCTIONS:
        raise ValueError(f"{name} must be one of {', '.join(FUNCTIONS)}, got {function!r}")
    return function


def sigmoid(x, threshold, slope, function: str = "logistic"):
    """The sigmoid ``F(x; alpha, beta)`` (module docstring), broadcasting over all arguments.

    Parameters
    ----------
    x : float or ndarray
        Stimulus intensity (the protocol's unit; ``weibull`` needs ``x >= 0``, ``F(0) = 0``).
    threshold : float or ndarray
        ``alpha``: the intensity where ``F = 0.5``.
    slope : float or ndarray
        ``beta`` (per intensity unit for logistic/normal, the shape exponent for weibull).
    function : {"logistic", "normal", "weibull"}

    Returns
    -------
    float or ndarray
        ``F`` in [0, 1], of the broadcast shape.
    """
    x = np.asarray(x, dtype=float)
    if function == "logistic":
        # exp(-z) overflows to inf for z << 0, giving 1/inf = 0: the right limit, without the warning
        with np.errstate(over="ignore"):
            return 1.0 / (1.0 + np.exp(-slope * (x - threshold)))
    if function == "normal":
        return special.ndtr(slope * (x - threshold))
    if function == "weibull":
        ratio = np.clip(x, 0.0, None) / threshold
        return -np.expm1(-LN2 * ratio ** slope)
    raise ValueError(f"function must be one of {', '.join(FUNCTIONS)}, got {function!r}")


def psi(x, threshold, slope, guess=0.0, lapse=0.0, function: str = "logistic"):
    """Probability of a correct (or "yes", "comparison harder") response: ``gamma + (1-gamma-lambda) F``.

    Parameters
    ----------
    x, threshold, slope : float or ndarray
        As :func:`sigmoid`.
    guess : float or ndarray
        ``gamma``, the lower asymptote (1/n for n-AFC, 0 for yes/no).
    lapse : float or ndarray
        ``lambda``: 1 - the upper asymptote.
    function : {"logistic", "normal", "weibull"}

    Returns
    -------
    float or ndarray
        ``psi(x)`` in [gamma, 1 - lambda].
    """
    return guess + (1.0 - guess - lapse) * sigmoid(x, threshold, slope, function)


def inverse_sigmoid(f, threshold, slope, function: str = "logistic"):
    """The intensity where the sigmoid ``F`` (not ``psi``) equals ``f`` (0 < f < 1): the inverse of :func:`sigmoid`.

    Parameters
    ----------
    f : float or ndarray
        Value of ``F`` (before guess and lapse scaling).
    threshold, slope : float or ndarray
    function : {"logistic", "normal", "weibull"}

    Returns
    -------
    float or ndarray
        Intensity (the protocol's unit).
    """
    f = np.asarray(f, dtype=float)
    if function == "logistic":
        return threshold + np.log(f / (1.0 - f)) / slope
    if function == "normal":
        return threshold + special.ndtri(f) / slope
    if function == "weibull":
        return threshold * (-np.log1p(-f) / LN2) ** (1.0 / slope)
    raise ValueError(f"function must be one of {', '.join(FUNCTIONS)}, got {function!r}")


def intensity_at(p_correct, threshold, slope, guess=0.0, lapse=0.0, function: str = "logistic"):
    """The intensity where ``psi`` equals ``p_correct`` (e.g. 0.707 for a 1-up-2-down staircase's target).

    Parameters
    ----------
    p_correct : float or ndarray
        Target probability, strictly between ``guess`` and ``1 - lapse``.
    threshold, slope, guess, lapse, function
        As :func:`psi`.

    Returns
    -------
    float or ndarray
        Intensity (the protocol's unit).

    Raises
    ------
    ValueError
        ``p_correct`` outside (guess, 1 - lapse): no intensity reaches it.
    """
    p = np.asarray(p_correct, dtype=float)
    lo, hi = guess, 1.0 - lapse
    if np.any(p <= lo) or np.any(p >= hi):
        raise ValueError(f"p_correct must lie in ({lo:g}, {hi:g}) for guess {guess:g} and lapse {lapse:g}, "
                         f"got {p_correct!r}")
    return inverse_sigmoid((p - guess) / (hi - guess), threshold, slope, function)


def jnd(threshold, slope, function: str = "logistic"):
    """Just-noticeable difference: ``x(F = 0.75) - x(F = 0.5)`` (intensity units).

    For a "which was harder?" discrimination with the reference at the PSE ``alpha``; the Weber fraction is
    ``jnd / reference``.
    """
    return inverse_sigmoid(0.75, threshold, slope, function) - threshold


def guess_rate(alternatives: int) -> float:
    """gamma for ``alternatives``-AFC: 1/n; ``alternatives = 1`` is a yes/no (or "which was harder?") task, 0."""
    if isinstance(alternatives, bool) or not isinstance(alternatives, (int, np.integer)) or alternatives < 1:
        raise ValueError(f"--alternatives must be a whole number >= 1 (1: yes/no, n: n-AFC), got {alternatives!r}")
    return 0.0 if alternatives == 1 else 1.0 / alternatives


# -- the location-scale view (module docstring): what the fits work on ---------------------------------------

def base_cdf(z, function: str):
    """The standard sigmoid G(z) of ``function``, with G(0) = 0.5: ``F = G(beta (u - a))``.

    Parameters
    ----------
    z : array_like
        Standardised stimulus ``beta (u - a)``.
    function : {'logistic', 'normal', 'weibull'}

    Returns
    -------
    ndarray
        G(z) in [0, 1].
    """
    z = np.asarray(z, dtype=float)
    if function == "logistic":
        return special.expit(z)
    if function == "normal":
        return special.ndtr(z)
    check_function(function)
    return -np.expm1(-LN2 * np.exp(np.minimum(z, 700.0)))


def base_pdf(z, function: str):
    """dG/dz of :func:`base_cdf`."""
    z = np.asarray(z, dtype=float)
    if function == "logistic":
        e = special.expit(z)
        return e * (1.0 - e)
    if function == "normal":
        return np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
    check_function(function)
    ez = LN2 * np.exp(np.minimum(z, 700.0))
    return ez * np.exp(-ez)


def base_quantile(p, function: str):
    """Inverse of :func:`base_cdf`: the z where G(z) = ``p`` (0 < p < 1)."""
    p = np.asarray(p, dtype=float)
    if function == "logistic":
        return special.logit(p)
    if function == "normal":
        return special.ndtri(p)
    check_function(function)
    return np.log(-np.log1p(-p) / LN2)


def stimulus_axis(x, function: str):
    """The axis the function is a location-scale family on: ``ln x`` for the Weibull, ``x`` otherwise."""
    x = np.asarray(x, dtype=float)
    if function == "weibull":
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.log(x)
    return x


def from_axis(u, function: str):
    """Inverse of :func:`stimulus_axis`."""
    u = np.asarray(u, dtype=float)
    return np.exp(u) if function == "weibull" else u
