"""A psychophysics session (issue 34): 2-interval forced-choice trials in the study runner.

Each trial of the plan (:func:`study.experiment.plan_trials`) has two intervals. Per interval, as in the
realism study's attempt (:mod:`study.runner`): the stylus is homed above the stand; the operator view says
what to place (the real sample, or placeholder A/B alternating for a rendering, so an item is moved for every
interval whatever is presented) and the operator confirms; the subject is told to tap ("Interval N: tap now."
and the spoken "Tap now."); the servo loop renders the interval's sample for ``tap_window_s`` from the first
impact; the stylus is homed again (a tap now overpowered the homing). After the second interval the subject
answers the question with 1 or 2 (or x to reject the trial); "Stop. Which one?" is spoken (the audio's
``rate`` cue of :data:`study.audio.CHOICE_PHRASES`) and the screen asks the question. The masking noise runs
for the whole session.

Adaptive methods (``method`` ``updown``, ``weighted``, ``quest+``, ``psi``): the interleaved staircases
(:class:`psychophysics.multistair.Interleaved`, seeded from the session's seed and subject) choose each trial's
intensity; its stimulus is derived from the experiment's sample at that value and its servo loop made when
first needed. After each valid trial its row, then the staircase's state after the update
(``staircase_state.jsonl``), are on disk before the next trial starts; ``--resume`` replays the rows through
fresh staircases (refusing a row they would not have asked for) and writes any state line the kill lost.

An attempt is invalid -- logged in ``schedule.jsonl`` as ``invalid_attempt`` with its reason, its traces kept,
and the same trial run again at once -- when an interval had no tap, was saturated or overpowered, or the
subject rejected it. A valid attempt becomes the trial's one row in ``trials.csv`` (fsynced before the next
trial starts). ``--resume`` replans the same trials from the seed, skips the rows on disk and continues with
the next trial (its attempt number counted from the logged invalid attempts).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass

import numpy as np

from .data import utc_now
from .experiment import QUESTIONS, ExperimentConfig, PlannedTrial, adaptive_trial, derive_sample, intensity_of
from .perception import choose, measured
from .protocol import PHASE_CODES
from .psydata import append_psy_trial, append_state, repair_states, read_psy_trials
from .runner import Placement, operator_places
from .uistate import Aborted

TEXT = {
    "prepare": "Please wait while the next sample is prepared.",
    "interval": "Interval {n} of 2: tap now.",
    "choice": "{question}\nPress 1 for the first interval, 2 for the second, or x to reject the trial.",
    "done": "The study is complete. Thank you!",
    "paused": "Short pause. Please wait.",
    "no_tap": "No tap was detected. This trial will be repeated.",
}
INVALID_REASONS = ("rejected", "saturated", "overpowered", "no_tap")


@dataclass
class Interval:
    """One interval of an attempt: the sample presented and what the tapping window measured."""

    sample: str
    tap: object
    contacts: int

    @property
    def n_taps(self) -> int:
        """Impacts detected in the window."""
        return len(self.tap.velocities)


def _mean(values) -> float:
    return float(np.mean(values)) if len(values) else math.nan


class ForcedChoiceRunner:
    """Runs a psychophysics session's trials to the end (or until aborted/killed); see the module doc.

    Parameters
    ----------
    store : study.data.SessionStore
    exp : study.experiment.ExperimentConfig
    trials : list of study.experiment.PlannedTrial
    apparatus : study.apparatus.Apparatus or study.isolated.IsolatedApparatus
    participant : study.participants.SimulatedParticipant or a keyboard participant (``kind`` "keyboard")
    audio : study.audio.MaskingAudio or SilentAudio
    ui : study.uistate.UiState or None
    protocol : study.config.ProtocolConfig
    kinds : dict
        Catalog name -> "real" | "virtual".
    force_per_amp_N_A : float
        The device's force per ampere (the simulated participant's stiffness percept).
    handler : psychophysics.multistair.Interleaved or None
        The adaptive method's staircases (``trials`` is then empty).
    base : stimuli.CatalogSample or None
        The varied sample, from which an adaptive trial's stimuli are derived.
    seed : int
        The session's seed (an adaptive trial's target interval).
    """

    def __init__(self, *, store, exp: ExperimentConfig, trials: list, apparatus, participant, audio, ui, protocol,
                 kinds: dict, force_per_amp_N_A: float, handler=None, base=None, seed: int = 0) -> None:
        self.store = store
        self.exp = exp
        self.trials = trials
        self.handler = handler
        self.base = base
        self.seed = int(seed)
        self.apparatus = apparatus
        self.participant = participant
        self.audio = audio
        self.ui = ui
        self.protocol = protocol
        self.kinds = kinds
        self.force_per_amp_N_A = float(force_per_amp_N_A)
        self.placement = Placement()
        self.done = 0
        self.next_attempt = 1
        self.invalid: list = []

    # -- resume ----------------------------------------------------------------
    def restore(self, rows: list, events: list) -> None:
        """Continue after the ``rows`` on disk; the next trial's attempt number follows its logged invalid ones.

        Raises
        ------
        ValueError
            A row that is not the planned trial (another seed, an edited file).
        """
        if self.handler is not None:
            self._replay(rows)
        for i, row in enumerate(rows if self.handler is None else ()):
            if i >= len(self.trials):
                raise ValueError(f"{self.store.trials_path} line {i + 2}: the plan has only {len(self.trials)} "
                                 "trials")
            pt = self.trials[i]
            got = (row["condition"], row["target_interval"], row["sample_1"], row["sample_2"])
            want = (pt.condition, pt.target_interval, *pt.samples)
            if got != want:
                raise ValueError(f"{self.store.trials_path} line {i + 2}: trial {i + 1} is {got}, but this seed "
                                 f"plans {want}; the file does not belong to this session")
        self.done = len(rows)
        self.invalid = [e for e in events if e.get("event") == "invalid_attempt"]
        self.next_attempt = 1 + sum(1 for e in self.invalid if e.get("trial") == self.done + 1)

    def _replay(self, rows: list) -> None:
        """Feed the recorded trials to fresh staircases; write the state lines a kill lost."""
        have = repair_states(self.store)
        for i, row in enumerate(rows):
            trial = self.handler.next_trial()
            want = (trial.label, trial.intensity, int(trial.is_catch))
            got = (row["staircase"], row["intensity_physical"], row["is_catch"])
            if got != want:
                raise ValueError(f"{self.store.trials_path} line {i + 2}: trial {i + 1} is (staircase, intensity, "
                                 f"catch) {got}, but the staircases of this session ask for {want}; the file does "
                                 "not belong to this session")
            self.handler.update(trial, bool(row["correct"]))
            if i + 1 > have:
                append_state(self.store, self._state_line(trial, bool(row["correct"])))

    def _state_line(self, trial, correct: bool) -> dict:
        method = self.handler.methods[trial.label]
        return {"trial": trial.number, "staircase": trial.label, "is_catch": bool(trial.is_catch),
                "intensity_physical": trial.intensity, "correct": int(correct), "state": method.state(),
                "estimate": method.estimate(), "finished": self.handler.finished}

    @property
    def finished(self) -> bool:
        """True when the plan is done (constant stimuli) or every staircase has finished."""
        if self.handler is not None:
            return self.handler.finished
        return self.done >= len(self.trials)

    @property
    def total(self) -> int | None:
        """Trials planned (constant stimuli), or the staircases' ``max_trials`` summed (None when a staircase
        stops by reversals only)."""
        if self.handler is None:
            return len(self.trials)
        caps = [m.max_trials for m in self.handler.methods.values()]
        return None if None in caps else sum(caps)

    def next_trial(self) -> tuple[PlannedTrial, int, object]:
        """The next trial to run: ``(planned trial, is_catch, the staircases' trial or None)``; an adaptive
        trial's stimuli get their servo loops here."""
        if self.handler is None:
            return self.trials[self.done], 0, None
        trial = self.handler.next_trial()
        pt = adaptive_trial(self.exp, trial.number, trial.label, trial.intensity, self.seed, self.store.subject)
        for value in (trial.intensity, self.exp.reference if self.exp.kind == "discrimination" else None):
            sample = derive_sample(self.base, self.exp, value)
            self.apparatus.add_sample(sample)
            self.kinds[sample.name] = sample.kind
        return pt, int(trial.is_catch), trial

    # -- views -----------------------------------------------------------------
    def _subject(self, key: str, prompt: str = "wait", **fmt) -> None:
        if self.ui is not None:
            self.ui.set_subject(TEXT[key].format(**fmt), prompt)

    def _status(self, **extra) -> dict:
        total = self.total
        return {"subject": self.store.subject, "phase": self.exp.kind, "trials_valid": self.done,
                "trials_total": total, "trial_n": self.done + 1 if total is None else min(total, self.done + 1),
                "progress": {"trials": {"total": "?" if total is None else total,
                                        "attempts": self.done + len(self.invalid), "valid": self.done}},
                "link": self.apparatus.link_status(), "finished": self.finished, **extra}

    def _wait_operator(self, place: str, pt: PlannedTrial, attempt: int, interval: int) -> None:
        if self.ui is None:
            return
        self.ui.set_operator(trial=pt.trial, attempt=attempt, **self._status(interval=interval))
        operator_places(self.ui, self.apparatus, place, simulated=self.participant.kind == "simulated",
                        on_pause=lambda: self._subject("paused"))

    # -- one attempt -------------------------------------------------------------
    def run_interval(self, pt: PlannedTrial, attempt: int, interval: int) -> Interval:
        """Present interval ``interval`` (1 or 2) of a trial: place, cue, tap window, homing."""
        sample = pt.samples[interval - 1]
        plan = None
        if self.apparatus.simulated_hand:
            # the hand's taps of interval k of attempt a: the participant's stream (trial, 2 (a - 1) + k)
            plan = self.apparatus.sim_participant.plan("testing", pt.trial, 2 * (attempt - 1) + interval,
                                                       self.protocol.tap_window_s)
        self._subject("prepare")
        self.apparatus.set_sample(sample)
        self.apparatus.home(self.protocol.homing_before_max_s)
        self._wait_operator(self.placement.next(sample, self.kinds[sample]), pt, attempt, interval)
        if plan is not None:
            self.apparatus.start_hand(plan, self.protocol.tap_window_s)
        self._subject("interval", n=interval)
        self.audio.cue_tap()
        tap = self.apparatus.tap_window(self.protocol.tap_window_s, self.protocol.first_tap_timeout_s,
                                        on_clip=self.audio.cue_low_tone)
        contacts = self.apparatus.after_window(self.protocol.homing_after_s) if tap.velocities else 0
        return Interval(sample, tap, contacts)

    def answer(self, pt: PlannedTrial, attempt: int, intervals: list) -> tuple[str, tuple, int]:
        """The subject's answer ("1", "2" or "x"), the simulated participant's percepts (NaN for a person) and
        the surface contacts while a person answered (the homing holds the stylus: a tap overpowered it)."""
        self._subject("choice", "choice", question=QUESTIONS[self.exp.kind])
        self.audio.wait_cues(2.0)  # "Stop. Which one?" never talks over "Tap now." (docs/study.md)
        self.audio.cue_rate()
        if self.participant.kind == "simulated":
            sim = self.participant
            tap_plan = sim.plan("testing", pt.trial, 2 * (attempt - 1) + 2, self.protocol.tap_window_s)
            if tap_plan.reject:
                return "x", (math.nan, math.nan), 0
            values = tuple(measured(self.exp.kind, self.exp.vary, iv.tap.trace, self.force_per_amp_N_A,
                                    self.apparatus.reference) for iv in intervals)
            rng = sim._rng(PHASE_CODES["testing"], pt.trial, attempt, 34)
            choice, percepts = choose(self.exp.kind, self.exp.vary, values, sim.config, rng)
            return str(choice), percepts, 0
        contacts = self.apparatus.hold(until=lambda: self.ui.rating() is not None)
        return self.ui.rating(), (math.nan, math.nan), contacts

    def run_attempt(self, pt: PlannedTrial, attempt: int) -> tuple[list, str, tuple, str]:
        """Both intervals and the answer: ``(intervals, response, percepts, invalid reason or "")``."""
        intervals = []
        for k in (1, 2):
            iv = self.run_interval(pt, attempt, k)
            intervals.append(iv)
            if iv.n_taps == 0:
                self._subject("no_tap")
                return intervals, "", (math.nan, math.nan), "no_tap"
        response, percepts, contacts = self.answer(pt, attempt, intervals)
        if any(iv.tap.saturated for iv in intervals):
            reason = "saturated"
        elif contacts > 0 or any(iv.contacts > 0 for iv in intervals):
            reason = "overpowered"
        else:
            reason = ""
        if response == "x" and not reason:
            reason = "rejected"
        return intervals, response, percepts, reason

    def row(self, pt: PlannedTrial, attempt: int, intervals: list, response: str, percepts: tuple,
            started_at: str, duration_s: float, is_catch: int = 0) -> dict:
        """The trial's trials.csv row (docs/study.md, "Psychophysics sessions")."""
        out = {"subject": self.store.subject, "trial": pt.trial, "attempt": attempt, "condition": pt.condition,
               "staircase": pt.staircase, "intensity": intensity_of(self.exp, pt.intensity_physical),
               "intensity_physical": pt.intensity_physical, "correct": int(response == str(pt.target_interval)),
               "is_catch": is_catch, "response": response, "target_interval": pt.target_interval,
               "started_at": started_at, "duration_s": duration_s}
        for k, iv in enumerate(intervals, start=1):
            out[f"sample_{k}"] = iv.sample
            out[f"n_taps_{k}"] = iv.n_taps
            out[f"incoming_velocity_mean_{k}_m_s"] = _mean(iv.tap.velocities)
            out[f"penetration_mean_{k}_m"] = _mean(iv.tap.penetrations)
            out[f"sim_percept_{k}"] = percepts[k - 1]
        return out

    # -- the session ---------------------------------------------------------------
    def run(self) -> None:
        """Run trials until the plan is done; :class:`study.uistate.Aborted` when the operator aborts."""
        while not self.finished:
            if self.ui is not None and self.ui.snapshot("operator")["aborted"]:
                raise Aborted("the operator aborted the session")
            (pt, is_catch, trial), attempt = self.next_trial(), self.next_attempt
            started_at, t0 = utc_now(), time.monotonic()
            intervals, response, percepts, reason = self.run_attempt(pt, attempt)
            for k, iv in enumerate(intervals, start=1):
                self.store.write_trace(f"interval{k}", pt.trial, attempt, iv.tap.trace)
            if reason:
                event = {"event": "invalid_attempt", "trial": pt.trial, "attempt": attempt, "reason": reason,
                         "response": response, "n_taps": [iv.n_taps for iv in intervals],
                         "samples": [iv.sample for iv in intervals]}
                self.store.log_event(event)
                self.invalid.append(event)
                self.next_attempt += 1
            else:
                row = self.row(pt, attempt, intervals, response, percepts, started_at, time.monotonic() - t0,
                               is_catch)
                append_psy_trial(self.store, row)
                if trial is not None:   # the staircase's state after this trial, before the next one starts
                    self.handler.update(trial, bool(row["correct"]))
                    append_state(self.store, self._state_line(trial, bool(row["correct"])))
                self.done += 1
                self.next_attempt = 1
            if self.ui is not None:
                self.ui.set_operator(last_attempt=operator_view(intervals, response, reason), **self._status())
        self._subject("done")
        if self.ui is not None:
            self.ui.set_operator(awaiting_confirm=False, **{**self._status(), "phase": "done"})


def operator_view(intervals: list, response: str, reason: str) -> dict:
    """The operator page's "last attempt" (the realism study's fields): both intervals' samples, taps,
    velocities and depths, saturation, overpowering and the answer."""
    return {"sample": " | ".join(iv.sample for iv in intervals), "kind": f"{len(intervals)} intervals",
            "n_taps": sum(iv.n_taps for iv in intervals),
            "incoming_velocities_m_s": [v for iv in intervals for v in iv.tap.velocities],
            "penetration_depths_m": [p for iv in intervals for p in iv.tap.penetrations],
            "saturated": reason == "saturated", "overpowered": reason == "overpowered",
            "rejected": reason == "rejected", "rating": response or None, "reason": reason}


def plan_events(trials: list) -> list:
    """The ``plan`` event of schedule.jsonl: every planned trial (condition, intensity, target, samples)."""
    return [{"event": "plan", "phase": "trials", "trials": [asdict(t) for t in trials]}]


def summary(store, exp: ExperimentConfig, say, handler=None) -> None:
    """Print the finished session's proportion correct per condition and level, and each staircase's
    threshold estimate (adaptive methods)."""
    rows = read_psy_trials(store)
    print(f"session {store.subject} complete ({exp.kind}): {store.dir}")
    cells = {}
    for r in rows:
        cells.setdefault((r["condition"], float(f"{r['intensity_physical']:.4g}")), []).append(r["correct"])
    label = "comparison harder" if exp.kind == "discrimination" else "correct"
    for (cond, x), c in sorted(cells.items()):
        say(f"  {cond:24s} {x:10.4g} {exp.unit:6s} trials {len(c):3d}  {label} {np.mean(c):.2f}")
    for name, method in (handler.methods.items() if handler is not None else ()):
        est = method.estimate()
        say(f"  staircase {name}: {method.trials} trials, threshold estimate {est['threshold']:.4g} {exp.unit}")
