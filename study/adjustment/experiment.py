"""The method of adjustment's ``[experiment]`` table and trial plan.

A trial: the participant feels the reference, then the comparison at its start value, and adjusts the
comparison's ``vary`` (stiffness, a transient's amplitude or gain, any number of the sample) with keys -- up or
down by a fine step, or by a coarse one -- feeling it again after each change (and the reference again when
asked), until both feel the same; the comparison's value then is the trial's match. Half of a condition's
trials start above the reference and half below (an odd one out on a seeded side), at a seeded log-uniform
factor within ``start_factors``: the classic control for the direction of adjustment (Jones & Tan 2013,
*IEEE ToH* 6(3), the method of adjustment).

The comparison's values lie on a grid of fine steps around the reference, ``reference * (1 + step)^k`` (a
coarse step is a whole number of fine ones), within ``range_factor`` of it: the same value is the same stimulus
(one servo loop) whenever it recurs, and the values recorded are exact.

Conditions are the reference values (``references``: the comparison's sample at each value) or reference
samples as they are in the catalog (``reference_samples``: e.g. a wall with a transient matched by the
comparison's stiffness alone). Trials run in blocks of one condition, the blocks in the participant's order
(:func:`study.design.blocks.block_order`: a fixed ``order``, a counterbalancing ``design``, or seeded).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from plumbing.validation import require_int, require_number

from ..session.config import experiment_config
from ..session.rng import session_rng

KIND = "adjustment"
#: the adjustment's word in the session's seeds (:mod:`study.session.rng`); never changed
ADJUST_STREAM = 51


@dataclass(frozen=True)
class AdjustmentConfig:
    """The ``[experiment]`` table of a method-of-adjustment protocol (module docstring).

    Attributes
    ----------
    kind : str
        ``"adjustment"``.
    sample : str
        The comparison: a virtual catalog sample whose ``vary`` the participant adjusts.
    vary : str
        The adjusted parameter (``stiffness_N_m``, ``gain``, or a number of the sample's transient).
    references : list of float
        Conditions: the reference is ``reference_sample`` with ``vary`` at each value (physical units).
    reference_sample : str
        The references' sample (default: ``sample``).
    reference_samples : list of str
        Conditions instead of ``references``: catalog samples presented as they are.
    trials_per_reference : int
        Trials per condition (half start above the reference, half below).
    start_factors : list of float
        ``[low, high]``: a trial starts at the reference times (above) or over (below) a factor drawn
        log-uniformly between them (> 1).
    step, coarse_step : float
        The fine and coarse steps as fractions (0.02: 2 % per key).
    range_factor : float
        The comparison stays within the reference over / times this factor.
    max_comparisons : int
        A trial without a match after this many comparisons ends unmatched (``matched`` 0).
    order : list of str
        The conditions' block order for every participant (default: ``design``'s or a seeded order).
    design : str
        A design.csv of ``python -m study design`` (relative to the protocol file).
    """

    kind: str = KIND
    sample: str = ""
    vary: str = "stiffness_N_m"
    references: tuple = ()
    reference_sample: str = ""
    reference_samples: tuple = ()
    trials_per_reference: int = 6
    start_factors: tuple = (1.2, 1.6)
    step: float = 0.02
    coarse_step: float = 0.15
    range_factor: float = 4.0
    max_comparisons: int = 40
    order: tuple = ()
    design: str = ""

    def __post_init__(self) -> None:
        if self.kind != KIND:
            raise ValueError(f"kind must be {KIND!r}, got {self.kind!r}")
        if not isinstance(self.sample, str) or not self.sample:
            raise ValueError("sample must name the virtual catalog sample the participant adjusts")
        for key in ("references", "start_factors"):
            value = getattr(self, key)
            if isinstance(value, str) or not isinstance(value, (list, tuple)) or not all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0
                    for v in value):
                raise ValueError(f"{key} must be a list of numbers > 0, got {value!r}")
            object.__setattr__(self, key, tuple(float(v) for v in value))
        for key in ("reference_samples", "order"):
            value = getattr(self, key)
            if isinstance(value, str) or not isinstance(value, (list, tuple)) or not all(
                    isinstance(v, str) and v for v in value):
                raise ValueError(f"{key} must be a list of names, got {value!r}")
            object.__setattr__(self, key, tuple(value))
        if bool(self.references) == bool(self.reference_samples):
            raise ValueError("give the conditions as references (values of vary) or as reference_samples "
                             "(catalog samples), one of the two")
        if self.reference_samples and self.reference_sample:
            raise ValueError("reference_sample is for references (values); reference_samples are presented as they are")
        if len(set(self.conditions)) != len(self.conditions):
            raise ValueError(f"a condition is listed twice: {self.conditions}")
        require_int("trials_per_reference", self.trials_per_reference, minimum=1, maximum=100)
        require_int("max_comparisons", self.max_comparisons, minimum=2, maximum=90)
        if len(self.start_factors) != 2 or not 1.0 < self.start_factors[0] <= self.start_factors[1]:
            raise ValueError(f"start_factors must be [low, high] with 1 < low <= high, got {list(self.start_factors)}")
        require_number("step", self.step, minimum=0.001, maximum=0.5)
        require_number("coarse_step", self.coarse_step, minimum=self.step, maximum=4.0)
        require_number("range_factor", self.range_factor, minimum=self.start_factors[1] * (1 + self.coarse_step),
                       maximum=100.0)
        if not isinstance(self.design, str):
            raise ValueError(f"design must be the path of a design.csv, got {self.design!r}")
        if self.order and self.design:
            raise ValueError("order and design both set the block order: give one")

    @property
    def conditions(self) -> list[str]:
        """The conditions' names: each reference value (``%g``) or each reference sample."""
        return [format(v, "g") for v in self.references] or list(self.reference_samples)

    @property
    def fine_per_coarse(self) -> int:
        """Fine steps in a coarse step."""
        return max(1, round(math.log1p(self.coarse_step) / math.log1p(self.step)))

    @property
    def max_steps(self) -> int:
        """The most fine steps from the reference within ``range_factor``."""
        return int(math.floor(math.log(self.range_factor) / math.log1p(self.step) + 1e-9))

    def value(self, reference: float, k: int) -> float:
        """The comparison's value ``k`` fine steps from ``reference`` (bounded by the range)."""
        k = max(-self.max_steps, min(self.max_steps, k))
        return float(reference * (1.0 + self.step) ** k)

    def to_dict(self) -> dict:
        """The table as plain data, re-readable by :func:`config_from_dict`."""
        d = asdict(self)
        for key in ("references", "reference_samples", "start_factors", "order"):
            d[key] = list(d[key])
        return d


def config_from_dict(data, where: str) -> AdjustmentConfig:
    """An :class:`AdjustmentConfig` from a table; unknown keys and bad values name ``where`` and the key; a
    relative ``design`` is taken from the protocol file's folder."""
    return experiment_config(AdjustmentConfig, data, where)


@dataclass(frozen=True)
class PlannedTrial:
    """One adjustment trial: its number, block, condition, the reference's value, the start (grid steps from
    the reference, > 0 above) and the side."""

    trial: int
    block: int
    condition: str
    start_k: int
    side: str


def plan_trials(exp: AdjustmentConfig, order: list[str], seed: int, subject: str) -> list[PlannedTrial]:
    """Every trial of the session: the blocks in ``order``, within each the start sides balanced (half above,
    half below, an odd one seeded) in a seeded random order, each start a seeded log-uniform factor.

    Every draw comes from ``session_rng(seed, subject, ADJUST_STREAM, block)``, so a resumed session replans the
    same trials."""
    trials, number = [], 1
    lo, hi = (math.log(f) for f in exp.start_factors)
    for b, condition in enumerate(order, start=1):
        rng = session_rng(seed, subject, ADJUST_STREAM, b)
        n = exp.trials_per_reference
        sides = ["above"] * (n // 2) + ["below"] * (n // 2)
        if n % 2:
            sides.append("above" if rng.random() < 0.5 else "below")
        sides = [sides[i] for i in rng.permutation(n)]
        for side in sides:
            k = max(1, round(rng.uniform(lo, hi) / math.log1p(exp.step)))
            trials.append(PlannedTrial(number, b, condition, k if side == "above" else -k, side))
            number += 1
    return trials
