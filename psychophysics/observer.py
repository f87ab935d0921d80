"""A simulated observer: answers each trial with the probability of the contract's psychometric function.

Used by ``python -m study simulate-observer`` (planning: how many trials a method needs), by the simulated
participant of the psychophysics kinds and by the tests. Its parameters are those of
:func:`psychophysics.psychometric.psi`: threshold ``alpha``, slope ``beta``, lapse rate ``lambda``, guess rate
``gamma`` (1/n for n-AFC) and the sigmoid's family.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plumbing.validation import require_number

from .psychometric import check_function, intensity_at, psi

#: default parameter names in error messages; the command line passes its flags instead
FIELD_NAMES = {"threshold": "threshold", "slope": "slope", "lapse": "lapse", "guess": "guess",
               "function": "function"}


def check_observer(threshold, slope, lapse, guess, function, names: dict | None = None) -> None:
    """Validate an observer's parameters; the message names the field (or the flag in ``names``).

    Parameters
    ----------
    threshold : float
        ``alpha`` (> 0 for weibull; any finite number for logistic/normal).
    slope : float
        ``beta`` > 0.
    lapse : float
        ``lambda`` in [0, 0.5): a lapse rate of a half or more leaves no psychometric function to measure.
    guess : float
        ``gamma`` in [0, 1).
    function : str
        One of :data:`psychophysics.psychometric.FUNCTIONS`.
    names : dict or None
        Field -> name used in the message (e.g. ``{"lapse": "--lapse"}``).

    Raises
    ------
    ValueError
        One message naming the first bad field.
    """
    n = dict(FIELD_NAMES, **(names or {}))
    check_function(function, n["function"])
    require_number(n["threshold"], threshold, minimum=0.0 if function == "weibull" else None,
                   strict=True, prefix="")
    require_number(n["slope"], slope, minimum=0.0, strict=True)
    require_number(n["lapse"], lapse)
    if not 0.0 <= lapse < 0.5:
        raise ValueError(f"{n['lapse']} must be in [0, 0.5) (a lapse rate of a half or more leaves nothing to "
                         f"measure), got {lapse!r}")
    require_number(n["guess"], guess)
    if not 0.0 <= guess < 1.0:
        raise ValueError(f"{n['guess']} must be in [0, 1), got {guess!r}")
    if guess + lapse >= 1.0:
        raise ValueError(f"{n['guess']} + {n['lapse']} must be < 1, got {guess!r} + {lapse!r}")


@dataclass(frozen=True)
class ObserverParams:
    """A simulated observer's psychometric function (contract parametrisation, :mod:`psychophysics.psychometric`).

    Attributes
    ----------
    threshold : float
        ``alpha``: intensity where the sigmoid is 0.5 (the protocol's unit).
    slope : float
        ``beta``.
    lapse : float
        ``lambda``, in [0, 0.5) (default 0.02).
    guess : float
        ``gamma``, in [0, 1) (default 0.5: two-alternative forced choice).
    function : str
        ``"logistic"``, ``"normal"`` or ``"weibull"`` (default).
    """

    threshold: float
    slope: float = 3.5
    lapse: float = 0.02
    guess: float = 0.5
    function: str = "weibull"

    def __post_init__(self):
        check_observer(self.threshold, self.slope, self.lapse, self.guess, self.function)

    def p_correct(self, x):
        """Probability of a correct response at intensity ``x`` (float or ndarray)."""
        return psi(x, self.threshold, self.slope, self.guess, self.lapse, self.function)

    def intensity_at(self, p_correct: float) -> float:
        """The intensity where this observer is correct with probability ``p_correct``."""
        return float(intensity_at(p_correct, self.threshold, self.slope, self.guess, self.lapse, self.function))


class SimulatedObserver:
    """An observer that answers with probability ``params.p_correct(x)``, from its own seeded generator.

    Parameters
    ----------
    params : ObserverParams
    seed : int or numpy.random.Generator
        The generator (or its seed): the same seed and the same intensities give the same answers.
    """

    def __init__(self, params: ObserverParams, seed=0):
        self.params = params
        self.rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)

    def respond(self, intensity: float) -> bool:
        """One trial at ``intensity``: True when correct (one uniform draw from the generator)."""
        return bool(self.rng.random() < float(self.params.p_correct(intensity)))
