"""The study protocol of thesis section 4.5.3 as a pure, replayable state machine.

Phases run in order: ``familiarization`` (tapping on the real wood sample until
the subject ends it), ``demonstration`` (each sample once, random order) and
``testing`` (each sample ``repetitions`` times, random order). A trial whose
attempt is invalid (saturated, rejected, overpowered, no tap) goes back into the
pool and is drawn again later at random.

Determinism: every random choice is drawn from a generator seeded by
``(seed, subject, phase, draw index)`` (:func:`study.session.rng.session_rng`), so
the schedule depends only on the seed and on the validity of the attempts run
so far. A crashed session is resumed by replaying its recorded attempts through
a fresh :class:`Schedule` (see :meth:`Schedule.replay`), which reproduces the
exact state, including the redraw positions, without storing any RNG state.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..session.rng import PHASE_CODES, session_rng

REDRAW_REASONS = ("saturated", "rejected", "overpowered", "no_tap")


def reason_of(row: dict) -> str:
    """Why an attempt was invalid, from its recorded flags (priority: rejected, saturated, overpowered, no tap)."""
    if row.get("valid"):
        return ""
    for key in ("rejected", "saturated", "overpowered"):
        if row.get(key):
            return key
    return "no_tap" if not row.get("n_taps") else ""


def phase_rng(seed: int, phase: str, index: int, subject: str = "") -> np.random.Generator:
    """Independent generator for the ``index``-th random choice of a phase (seeded, stateless).

    The subject id is mixed in, so different subjects get different orders even
    when an experimenter reuses a seed.
    """
    return session_rng(seed, subject, PHASE_CODES[phase], index)


@dataclass(frozen=True)
class Trial:
    """One planned presentation: ``trial`` is its 1-based number within the phase."""

    phase: str
    trial: int
    sample: str


@dataclass
class _Slot:
    trial: Trial
    attempts: int = 0


@dataclass
class PhaseSchedule:
    """Random draw without replacement from a pool; invalid attempts go back into the pool.

    Parameters
    ----------
    phase : str
        ``demonstration`` or ``testing``.
    samples : sequence of str
        Sample names in catalog order.
    repetitions : int
        Presentations of every sample (1 for demonstration).
    seed : int
        Session seed.
    subject : str
        Subject id (mixed into the seed).
    max_attempts : int or None
        Attempts of one trial: the last one invalid closes the trial as not renderable (recorded in
        :attr:`abandoned`, not drawn again) instead of redrawing it; None: no cap.
    """

    phase: str
    samples: tuple
    repetitions: int
    seed: int
    subject: str = ""
    max_attempts: int | None = None
    planned: list = field(default_factory=list)      # initial order of trial numbers
    pool: list = field(default_factory=list)         # remaining trial numbers, in draw order
    slots: dict = field(default_factory=dict)
    draws: int = 0
    redraws: list = field(default_factory=list)      # dicts: trial, attempt, sample, reason, reinserted_at
    run_order: list = field(default_factory=list)    # (trial, attempt) as actually run
    abandoned: list = field(default_factory=list)    # dicts: trial, attempts, sample, reason (not renderable)
    current: int | None = None

    def __post_init__(self) -> None:
        if self.repetitions < 1:
            raise ValueError(f"repetitions must be >= 1, got {self.repetitions}")
        items = [s for s in self.samples for _ in range(self.repetitions)]
        order = phase_rng(self.seed, self.phase, 0, self.subject).permutation(len(items))
        for number, idx in enumerate(order, start=1):
            self.slots[number] = _Slot(Trial(self.phase, number, items[idx]))
        self.planned = list(self.slots)
        self.pool = list(self.slots)

    @property
    def done(self) -> bool:
        """True when every trial of the phase has a valid attempt."""
        return self.current is None and not self.pool

    def next(self) -> tuple[Trial, int]:
        """Draw the next trial; returns ``(trial, attempt)`` with ``attempt`` 1-based."""
        if self.current is not None:
            slot = self.slots[self.current]
            return slot.trial, slot.attempts + 1
        if not self.pool:
            raise IndexError(f"{self.phase}: no trials left")
        self.current = self.pool.pop(0)
        slot = self.slots[self.current]
        return slot.trial, slot.attempts + 1

    def record(self, valid: bool, reason: str = "") -> dict | None:
        """Close the current attempt. An invalid one is reinserted at a random later position.

        Returns the redraw record (also appended to :attr:`redraws`) or ``None``.
        """
        if self.current is None:
            raise RuntimeError(f"{self.phase}: record() without a drawn trial")
        slot = self.slots[self.current]
        slot.attempts += 1
        self.run_order.append((slot.trial.trial, slot.attempts))
        self.current = None
        if valid:
            return None
        if self.max_attempts is not None and slot.attempts >= self.max_attempts:
            # never valid in max_attempts attempts (a sample the device saturates on every tap): the trial is
            # closed as not renderable and the session goes on
            record = {"phase": self.phase, "trial": slot.trial.trial, "attempts": slot.attempts,
                      "sample": slot.trial.sample, "reason": reason, "not_renderable": True,
                      "attempts_run": len(self.run_order)}
            self.abandoned.append(record)
            return record
        self.draws += 1
        # drawn again "later at random": uniformly among the remaining pool positions
        position = int(phase_rng(self.seed, self.phase, self.draws, self.subject).integers(0, len(self.pool) + 1))
        self.pool.insert(position, slot.trial.trial)
        record = {"phase": self.phase, "trial": slot.trial.trial, "attempt": slot.attempts,
                  "sample": slot.trial.sample, "reason": reason, "reinserted_at": position,
                  "attempts_run": len(self.run_order)}
        self.redraws.append(record)
        return record

    def summary(self) -> dict:
        """The phase's plan and what ran: planned samples, run order (trial, attempt, sample), redraws, and the
        trials not renderable (when any)."""
        out = {"planned": [self.slots[n].trial.sample for n in self.planned],
               "planned_trials": list(self.planned),
               "run": [{"trial": t, "attempt": a, "sample": self.slots[t].trial.sample} for t, a in self.run_order],
               "redraws": list(self.redraws)}
        if self.abandoned:
            out["not_renderable"] = list(self.abandoned)
        return out


class Schedule:
    """The whole session: familiarization, then demonstration, then testing.

    Familiarization is a sequence of tapping windows on the real wood sample
    (trial = window number, attempt = 1) that ends when the subject says so.
    """

    def __init__(self, samples, repetitions: int, seed: int, familiarization_sample: str | None,
                 subject: str = "", max_attempts: int | None = None) -> None:
        self.samples = tuple(samples)
        if not self.samples:
            raise ValueError("the catalog has no samples")
        if len(set(self.samples)) != len(self.samples):
            raise ValueError(f"duplicate sample names in the catalog: {self.samples}")
        self.seed = int(seed)
        self.familiarization_sample = familiarization_sample
        self.familiarization_windows = 0
        self.familiarization_done = familiarization_sample is None
        self.phases = {
            "demonstration": PhaseSchedule("demonstration", self.samples, 1, self.seed, subject, max_attempts),
            "testing": PhaseSchedule("testing", self.samples, int(repetitions), self.seed, subject, max_attempts),
        }

    @property
    def phase(self) -> str | None:
        """The current phase (familiarization, demonstration, testing), or None when the session is over."""
        if not self.familiarization_done:
            return "familiarization"
        for name in ("demonstration", "testing"):
            if not self.phases[name].done:
                return name
        return None

    def next(self) -> tuple[Trial, int] | None:
        """The next ``(trial, attempt)`` (attempt 1-based) of the current phase, or None when the session is over."""
        phase = self.phase
        if phase is None:
            return None
        if phase == "familiarization":
            return Trial(phase, self.familiarization_windows + 1, self.familiarization_sample), 1
        return self.phases[phase].next()

    def record(self, trial: Trial, attempt: int, valid: bool, reason: str = "", end_familiarization=False):
        """Close the attempt ``(trial, attempt)`` returned by :meth:`next`; returns a redraw record or None."""
        phase = self.phase
        if trial.phase != phase:
            raise RuntimeError(f"record for phase {trial.phase} while in {phase}")
        if phase == "familiarization":
            self.familiarization_windows += 1
            if end_familiarization:
                self.familiarization_done = True
            return None
        current = self.phases[phase].next()
        if current != (trial, attempt):
            raise RuntimeError(f"record for {trial}/{attempt} but the current trial is {current}")
        return self.phases[phase].record(valid, reason)

    def end_familiarization(self) -> None:
        """End familiarization after the current window (the subject pressed Enter)."""
        self.familiarization_done = True

    def replay(self, rows, familiarization_ended: bool = False) -> None:
        """Advance through recorded attempts (dicts with phase, trial, attempt, sample, valid, reason).

        ``familiarization_ended`` says the subject ended familiarization after
        the last recorded window (logged in ``schedule.jsonl``).

        Raises
        ------
        ValueError
            If a recorded attempt is not the one this seed and history would run
            (wrong seed, edited file or changed catalog).
        """
        rows = list(rows)
        for i, row in enumerate(rows):
            expected = self.next()
            if expected is None:
                raise ValueError(f"trials.csv row {i + 2}: session already complete, extra attempt {row}")
            trial, attempt = expected
            if row["phase"] == "familiarization" or trial.phase == "familiarization":
                if row["phase"] != "familiarization" and trial.phase == "familiarization":
                    self.end_familiarization()
                    trial, attempt = self.next()
                if (row["phase"], int(row["trial"]), row["sample"]) != (trial.phase, trial.trial, trial.sample):
                    raise ValueError(f"trials.csv row {i + 2}: expected {trial.phase} trial {trial.trial} "
                                     f"({trial.sample}), found {row['phase']} trial {row['trial']} ({row['sample']})")
                if trial.phase == "familiarization":
                    self.record(trial, attempt, True)
                    continue
            got = (row["phase"], int(row["trial"]), int(row["attempt"]), row["sample"])
            if got != (trial.phase, trial.trial, attempt, trial.sample):
                raise ValueError(f"trials.csv row {i + 2}: expected {trial.phase} trial {trial.trial} attempt "
                                 f"{attempt} ({trial.sample}) for this seed, found {got}")
            self.record(trial, attempt, bool(row["valid"]), row.get("reason") or reason_of(row))
        if familiarization_ended and self.phase == "familiarization":
            self.end_familiarization()

    def summary(self) -> dict:
        """The plan and what ran, per phase (recorded in session.json)."""
        out = {"familiarization": {"windows": self.familiarization_windows, "sample": self.familiarization_sample}}
        for name, sched in self.phases.items():
            out[name] = sched.summary()
        return out
