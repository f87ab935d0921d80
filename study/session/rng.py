"""The session's random numbers: one seeded generator for every random choice (schedule, participant, plan).

Every random choice of a session comes from a generator seeded by the session's seed, its subject id and the
choice's own words (a phase, a trial, an attempt, a purpose) through :class:`numpy.random.SeedSequence`.
Nothing random is stored: a resumed session draws exactly what an uninterrupted one would have, and different
subjects get different draws even when an experimenter reuses a seed. The words of each use are part of the
recorded sessions' meaning (a resumed session replans from them): they never change.
"""

from __future__ import annotations

import zlib

import numpy as np

from plumbing.studyfiles import PHASES

#: a phase's word in the seeds (familiarization 1, demonstration 2, testing 3)
PHASE_CODES = {name: i + 1 for i, name in enumerate(PHASES)}


def stable_code(text: str) -> int:
    """A process-independent 32-bit code of a string (Python's hash() is salted per process)."""
    return zlib.crc32(text.encode("utf-8"))


def seed_sequence(seed: int, subject: str, *words: int) -> np.random.SeedSequence:
    """``SeedSequence((seed mod 2**32, crc32(subject), *words))``: the entropy of one random choice."""
    return np.random.SeedSequence([int(seed) & 0xFFFFFFFF, stable_code(subject), *(int(w) for w in words)])


def session_rng(seed: int, subject: str, *words: int) -> np.random.Generator:
    """The generator of one random choice of a session (module docstring).

    Parameters
    ----------
    seed : int
        The session's seed.
    subject : str
        The subject id.
    *words : int
        What the choice is: e.g. ``(PHASE_CODES[phase], draw index)`` for the rating study's schedule.
    """
    return np.random.default_rng(seed_sequence(seed, subject, *words))
