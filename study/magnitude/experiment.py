"""Magnitude estimation's ``[experiment]`` table and trial plan.

Each trial presents one stimulus -- a condition's catalog sample with ``vary`` at one of the ``levels`` -- and the
participant types a number for its magnitude on the subject page (any number > 0; Stevens 1957). With a
``modulus`` the standard (the condition's sample at ``vary = modulus``) is presented first and called
``modulus_number`` ("This one is 10"), at the start of each block and again every ``modulus_every`` trials;
without one the participant chooses their own numbers (free modulus), which the analysis normalises (the
geometric mean of each participant's numbers). Each level comes ``repetitions`` times per condition, in a
seeded random order within the condition's block; the blocks run in the participant's order
(:func:`study.design.blocks.block_order`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from plumbing.validation import require_int, require_number

from ..session.config import experiment_config
from ..session.rng import session_rng

KIND = "magnitude"
#: magnitude estimation's word in the session's seeds (:mod:`study.session.rng`); never changed
MAGNITUDE_STREAM = 52


@dataclass(frozen=True)
class MagnitudeConfig:
    """The ``[experiment]`` table of a magnitude-estimation protocol (module docstring).

    Attributes
    ----------
    kind : str
        ``"magnitude"``.
    samples : list of str
        The conditions: virtual catalog samples, each presented with ``vary`` at every level.
    vary : str
        The varied parameter (``stiffness_N_m``, ``gain``, or a number of the samples' transient).
    levels : list of float
        Its values (physical units, > 0, at least 3; a power law is fitted over them).
    repetitions : int
        Presentations of each level per condition.
    modulus : float or None
        The standard's value of ``vary``, or None: a free modulus.
    modulus_number : float
        The number the standard is given (10).
    modulus_every : int
        Present the standard again every this many trials of a block (0: only at the block's start).
    order, design : list of str, str
        The block order (as :class:`study.adjustment.experiment.AdjustmentConfig`).
    """

    kind: str = KIND
    samples: tuple = ()
    vary: str = "stiffness_N_m"
    levels: tuple = ()
    repetitions: int = 4
    modulus: float | None = None
    modulus_number: float = 10.0
    modulus_every: int = 0
    order: tuple = ()
    design: str = ""

    def __post_init__(self) -> None:
        if self.kind != KIND:
            raise ValueError(f"kind must be {KIND!r}, got {self.kind!r}")
        for key in ("samples", "order"):
            value = getattr(self, key)
            if isinstance(value, str) or not isinstance(value, (list, tuple)) or not all(
                    isinstance(v, str) and v for v in value):
                raise ValueError(f"{key} must be a list of names, got {value!r}")
            object.__setattr__(self, key, tuple(value))
        if not self.samples or len(set(self.samples)) != len(self.samples):
            raise ValueError(f"samples must list the virtual catalog samples to scale, each once, got {list(self.samples)}")
        lv = self.levels
        if isinstance(lv, str) or not isinstance(lv, (list, tuple)) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0 for v in lv):
            raise ValueError(f"levels must be a list of numbers > 0, got {lv!r}")
        object.__setattr__(self, "levels", tuple(float(v) for v in lv))
        if len(set(self.levels)) < 3 or len(set(self.levels)) != len(self.levels):
            raise ValueError(f"levels must list at least 3 different values (each once), got {list(self.levels)}")
        require_int("repetitions", self.repetitions, minimum=1, maximum=100)
        if self.modulus is not None:
            object.__setattr__(self, "modulus", require_number("modulus", self.modulus, minimum=0.0, strict=True))
        require_number("modulus_number", self.modulus_number, minimum=0.0, strict=True, maximum=1e6)
        require_int("modulus_every", self.modulus_every, minimum=0, maximum=1000)
        if self.modulus is None and self.modulus_every:
            raise ValueError("modulus_every is for a session with a modulus (set modulus)")
        if not isinstance(self.design, str):
            raise ValueError(f"design must be the path of a design.csv, got {self.design!r}")
        if self.order and self.design:
            raise ValueError("order and design both set the block order: give one")

    @property
    def conditions(self) -> list[str]:
        """The conditions' names: the samples."""
        return list(self.samples)

    def to_dict(self) -> dict:
        """The table as plain data, re-readable by :func:`config_from_dict`."""
        d = asdict(self)
        for key in ("samples", "levels", "order"):
            d[key] = list(d[key])
        return d


def config_from_dict(data, where: str) -> MagnitudeConfig:
    """A :class:`MagnitudeConfig` from a table; unknown keys and bad values name ``where`` and the key."""
    return experiment_config(MagnitudeConfig, data, where)


@dataclass(frozen=True)
class PlannedTrial:
    """One trial: its number, block, condition (sample), level, and whether the standard comes first."""

    trial: int
    block: int
    condition: str
    level: float
    modulus_shown: int


def plan_trials(exp: MagnitudeConfig, order: list[str], seed: int, subject: str) -> list[PlannedTrial]:
    """Every trial: the blocks in ``order``, each level ``repetitions`` times in a seeded random order within a
    block (``session_rng(seed, subject, MAGNITUDE_STREAM, block)``: a resumed session replans the same)."""
    trials, number = [], 1
    for b, condition in enumerate(order, start=1):
        rng = session_rng(seed, subject, MAGNITUDE_STREAM, b)
        levels = [x for x in exp.levels for _ in range(exp.repetitions)]
        for j, i in enumerate(rng.permutation(len(levels))):
            shown = exp.modulus is not None and (j == 0 or (exp.modulus_every and j % exp.modulus_every == 0))
            trials.append(PlannedTrial(number, b, condition, levels[i], int(bool(shown))))
            number += 1
    return trials
