"""Forced-choice psychophysics as an experiment kind: 2-interval trials in the session's attempt loop.

Each trial of the plan (:func:`study.forcedchoice.experiment.plan_trials`) has two intervals. Per interval,
the loop's one presentation (:meth:`study.session.loop.SessionLoop.present`): the stylus is homed above the
stand; the operator view says what to place (the real sample, or placeholder A/B alternating for a rendering, so an item is moved for every
interval whatever is presented) and the operator confirms; the subject is told to tap ("Interval N: tap now."
and the spoken "Tap now."); the servo loop renders the interval's sample for ``tap_window_s`` from the first
impact; the stylus is homed again (a tap now overpowered the homing). After the second interval the subject
answers the question with 1 or 2 (or x to reject the trial); "Stop. Which one?" is spoken (the audio's
``rate`` cue of :data:`study.session.audio.CHOICE_PHRASES`) and the screen asks the question. The masking noise runs
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

from plumbing.studyfiles import FORCED_CHOICE, STATE_JSONL
from stimuli import load_catalog

from ..session.audio import CHOICE_PHRASES
from ..session.kind import ExperimentKind
from ..session.loop import Event, JsonLine, Outcome
from ..session.store import utc_now
from .experiment import (KINDS, QUESTIONS, ExperimentConfig, PlannedTrial, adaptive_trial, base_sample, derive_sample,
                         experiment_from_dict, handler_seed, intensity_of, plan_trials, stimulus_catalog)
from .perception import choose, measured

TEXT = {
    "prepare": "Please wait while the next sample is prepared.",
    "interval": "Interval {n} of 2: tap now.",
    "choice": "{question}\nPress 1 for the first interval, 2 for the second, or x to reject the trial.",
    "done": "The study is complete. Thank you!",
    "paused": "Short pause. Please wait.",
    "no_tap": "No tap was detected. This trial will be repeated.",
}
INVALID_REASONS = ("rejected", "saturated", "overpowered", "no_tap")
#: the simulated participant's answer's word in its seeds (:meth:`study.session.participants.SimulatedParticipant.rng`);
#: part of the recorded sessions' meaning, never changed
ANSWER_STREAM = 34


@dataclass
class Attempt:
    """One attempt of a trial: its intervals (:class:`study.session.loop.Presented`), the answer, the simulated
    participant's percepts (NaN for a person), why it does not count ("" when it does), when it started."""

    trial: PlannedTrial
    is_catch: int
    staircase_trial: object
    intervals: list
    response: str
    percepts: tuple
    reason: str
    started_at: str
    t0: float


def _mean(values) -> float:
    return float(np.mean(values)) if len(values) else math.nan


class ForcedChoice(ExperimentKind):
    """Forced-choice trials (module docstring): real vs virtual, discrimination, detection; constant stimuli or an
    adaptive method's staircases."""

    names = KINDS
    rows = FORCED_CHOICE
    phrases = CHOICE_PHRASES
    familiarization = False
    texts = TEXT

    @classmethod
    def configure(cls, table: dict, where: str) -> ExperimentConfig:
        """The ``[experiment]`` table (:class:`study.forcedchoice.experiment.ExperimentConfig`)."""
        return experiment_from_dict(table, where)

    @classmethod
    def samples(cls, config: ExperimentConfig, load, where: str) -> list:
        """The samples it presents, derived from the catalog's (levels of a varied parameter)."""
        try:
            return stimulus_catalog(load(False), config)
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None

    def __init__(self, plan, apparatus) -> None:
        super().__init__(plan, apparatus)
        exp = self.exp = plan.config
        self.subject = plan.subject
        self.seed = int(plan.seed)
        self.trials: list = []
        self.handler = self.base = None
        if exp.adaptive:
            self.handler = exp.handler(handler_seed(plan.seed, plan.subject))
            self.base = base_sample(load_catalog(plan.catalog_file, library_dir=plan.library_dir), exp)
        else:
            self.trials = plan_trials(exp, plan.seed, plan.subject)
        info = plan.device_info
        # eq. 3.17, as DeviceInfo.force_per_amp_N_A: the simulated participant's stiffness percept
        self.force_per_amp_N_A = float(info["gear_ratio"] * info["torque_constant_Nm_A"] / info["handle_length_m"])
        self.done = 0
        self.next_number = 1
        self.invalid: list = []

    # -- what trials exist -------------------------------------------------------------------------------------
    def plan(self) -> tuple[dict, list]:
        """``session.json["experiment"]`` and the plan: every planned trial, or the staircases' first states."""
        if self.handler is not None:
            events = [{"event": "plan", "phase": "trials", "adaptive": self.exp.method,
                       "staircases": {label: m.state() for label, m in self.handler.methods.items()}}]
        else:
            events = plan_events(self.trials)
        return {"experiment": self.exp.to_session()}, events

    def restore(self, store, rows: list, events: list) -> str:
        """Continue after the ``rows`` on disk; the next trial's attempt number follows its logged invalid ones.

        Raises
        ------
        ValueError
            A row that is not the planned trial (another seed, an edited file).
        """
        if self.handler is not None:
            self._replay(store, rows)
        for i, row in enumerate(rows if self.handler is None else ()):
            if i >= len(self.trials):
                raise ValueError(f"{store.trials_path} line {i + 2}: the plan has only {len(self.trials)} trials")
            pt = self.trials[i]
            got = (row["condition"], row["target_interval"], row["sample_1"], row["sample_2"])
            want = (pt.condition, pt.target_interval, *pt.samples)
            if got != want:
                raise ValueError(f"{store.trials_path} line {i + 2}: trial {i + 1} is {got}, but this seed "
                                 f"plans {want}; the file does not belong to this session")
        self.done = len(rows)
        self.invalid = [e for e in events if e.get("event") == "invalid_attempt"]
        self.next_number = 1 + sum(1 for e in self.invalid if e.get("trial") == self.done + 1)
        return f"resuming {self.subject}: {len(rows)} trials on disk"

    def _replay(self, store, rows: list) -> None:
        """Feed the recorded trials to fresh staircases; write the state lines a kill lost (a torn last one is
        kept aside by the store)."""
        have = len(store.read_json_lines(STATE_JSONL, then="it will be written again from trials.csv; kept it in"))
        for i, row in enumerate(rows):
            trial = self.handler.next_trial()
            want = (trial.label, trial.intensity, int(trial.is_catch))
            got = (row["staircase"], row["intensity_physical"], row["is_catch"])
            if got != want:
                raise ValueError(f"{store.trials_path} line {i + 2}: trial {i + 1} is (staircase, intensity, "
                                 f"catch) {got}, but the staircases of this session ask for {want}; the file does "
                                 "not belong to this session")
            self.handler.update(trial, bool(row["correct"]))
            if i + 1 > have:
                item = self._state_line(trial, bool(row["correct"]))
                store.append_json_line(item.name, item.line, item.label)

    def _state_line(self, trial, correct: bool) -> JsonLine:
        method = self.handler.methods[trial.label]
        line = {"trial": trial.number, "staircase": trial.label, "is_catch": bool(trial.is_catch),
                "intensity_physical": trial.intensity, "correct": int(correct), "state": method.state(),
                "estimate": method.estimate(), "finished": self.handler.finished}
        return JsonLine(STATE_JSONL, line, f"staircase state written: trial {line['trial']}")

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

    def next_attempt(self):
        """``((planned trial, is_catch, the staircases' trial or None), attempt)``, or None when finished; an
        adaptive trial's stimuli get their servo loops here."""
        if self.finished:
            return None
        if self.handler is None:
            return (self.trials[self.done], 0, None), self.next_number
        trial = self.handler.next_trial()
        pt = adaptive_trial(self.exp, trial.number, trial.label, trial.intensity, self.seed, self.subject)
        for value in (trial.intensity, self.exp.reference if self.exp.kind == "discrimination" else None):
            sample = derive_sample(self.base, self.exp, value)
            self.apparatus.add_sample(sample)
            self.sample_kinds[sample.name] = sample.kind
        return (pt, int(trial.is_catch), trial), self.next_number

    # -- one attempt -------------------------------------------------------------------------------------------
    def _status(self, **extra) -> dict:
        total = self.total
        return {"subject": self.subject, "phase": self.exp.kind, "trials_valid": self.done,
                "trials_total": total, "trial_n": self.done + 1 if total is None else min(total, self.done + 1),
                "progress": {"trials": {"total": "?" if total is None else total,
                                        "attempts": self.done + len(self.invalid), "valid": self.done}},
                "finished": self.finished, **extra}

    def run_interval(self, loop, pt: PlannedTrial, attempt: int, interval: int):
        """Present interval ``interval`` (1 or 2) of a trial: place, cue, tap window, homing."""
        plan = None
        if self.apparatus.simulated_hand:
            # the hand's taps of interval k of attempt a: the participant's stream (trial, 2 (a - 1) + k)
            plan = self.apparatus.sim_participant.plan("testing", pt.trial, 2 * (attempt - 1) + interval,
                                                       self.protocol.tap_window_s)
        return loop.present(pt.samples[interval - 1], self.protocol.tap_window_s,
                            status=lambda: {"trial": pt.trial, "attempt": attempt, **self._status(interval=interval)},
                            text=TEXT["interval"].format(n=interval), hand=plan, home_after="tapped")

    def simulated_answer(self, pt: PlannedTrial, attempt: int, intervals: list) -> tuple[str, tuple]:
        """The simulated participant's answer and percepts, from what the device rendered in each interval
        (:mod:`study.forcedchoice.perception`)."""
        sim = self.apparatus.sim_participant
        tap_plan = sim.plan("testing", pt.trial, 2 * (attempt - 1) + 2, self.protocol.tap_window_s)
        if tap_plan.reject:
            return "x", (math.nan, math.nan)
        values = tuple(measured(self.exp.kind, self.exp.vary, iv.tap.trace, self.force_per_amp_N_A,
                                self.apparatus.reference) for iv in intervals)
        rng = sim.rng("testing", pt.trial, attempt, ANSWER_STREAM)
        choice, percepts = choose(self.exp.kind, self.exp.vary, values, sim.config, rng)
        return str(choice), percepts

    def run_attempt(self, loop, trial, attempt: int) -> Attempt:
        """Both intervals and the answer."""
        pt, is_catch, staircase_trial = trial
        started_at, t0 = utc_now(), time.monotonic()
        intervals = []
        for k in (1, 2):
            iv = self.run_interval(loop, pt, attempt, k)
            intervals.append(iv)
            if iv.n_taps == 0:
                loop.say(TEXT["no_tap"])
                return Attempt(pt, is_catch, staircase_trial, intervals, "", (math.nan, math.nan), "no_tap",
                               started_at, t0)
        answer, contacts = loop.ask(TEXT["choice"].format(question=QUESTIONS[self.exp.kind]), "choice",
                                    simulated=lambda: self.simulated_answer(pt, attempt, intervals))
        response, percepts = answer if loop.simulated else (answer, (math.nan, math.nan))
        if any(iv.tap.saturated for iv in intervals):
            reason = "saturated"
        elif contacts > 0 or any(iv.contacts > 0 for iv in intervals):
            reason = "overpowered"
        else:
            reason = ""
        if response == "x" and not reason:
            reason = "rejected"
        return Attempt(pt, is_catch, staircase_trial, intervals, response, percepts, reason, started_at, t0)

    # -- what a row holds ----------------------------------------------------------------------------------------
    def row(self, pt: PlannedTrial, attempt: int, intervals: list, response: str, percepts: tuple,
            started_at: str, duration_s: float, is_catch: int = 0) -> dict:
        """The trial's trials.csv row (docs/study.md, "Psychophysics sessions")."""
        out = {"subject": self.subject, "trial": pt.trial, "attempt": attempt, "condition": pt.condition,
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

    def outcome(self, trial, attempt: int, result: Attempt, subject: str) -> Outcome:
        """Both intervals' traces; the trial's row when the attempt counts (an invalid one is only logged)."""
        pt = result.trial
        traces = [(f"interval{k}", pt.trial, attempt, iv.tap.trace) for k, iv in enumerate(result.intervals, start=1)]
        row = None
        if not result.reason:
            row = self.row(pt, attempt, result.intervals, result.response, result.percepts, result.started_at,
                           time.monotonic() - result.t0, result.is_catch)
        return Outcome(traces=traces, row=row)

    def recorded(self, trial, attempt: int, result: Attempt, row: dict | None) -> list:
        """An invalid attempt is logged and the same trial runs again; a valid one's staircase takes the answer
        and its state is written before the next trial."""
        pt = result.trial
        if row is None:
            event = {"event": "invalid_attempt", "trial": pt.trial, "attempt": attempt, "reason": result.reason,
                     "response": result.response, "n_taps": [iv.n_taps for iv in result.intervals],
                     "samples": [iv.sample for iv in result.intervals]}
            self.invalid.append(event)
            self.next_number += 1
            return [Event(event)]
        out = []
        if result.staircase_trial is not None:   # the staircase's state after this trial, before the next one starts
            self.handler.update(result.staircase_trial, bool(row["correct"]))
            out.append(self._state_line(result.staircase_trial, bool(row["correct"])))
        self.done += 1
        self.next_number = 1
        return out

    # -- the views and the end -----------------------------------------------------------------------------------
    def status(self, result: Attempt = None, row: dict | None = None) -> dict:
        """The operator page after an attempt: its intervals and answer (:func:`operator_view`)."""
        return {"last_attempt": operator_view(result.intervals, result.response, result.reason), **self._status()}

    def done_status(self) -> dict:
        """The operator page at the end: "session complete"."""
        return {"awaiting_confirm": False, **self._status(), "phase": "done", "place": "",
                "message": "session complete"}

    def reference(self, apparatus) -> dict | None:
        """real-virtual-2afc: the simulated participant knows the real sample's own taps (motor off), as the
        rater knows wood on foam."""
        if self.exp.kind != "real-virtual-2afc":
            return None
        real = next(s for s in self.session_plan.catalog if s.name == self.exp.real_sample)
        ref = apparatus.record_reference(real.real_sample)
        return {"event": "rater_reference", "sample": real.real_sample, "a": ref.a, "b": ref.b,
                "centroid_hz": ref.centroid_hz}

    def summary(self, rows: list, store, say) -> None:
        """The proportion correct per condition and level, and each staircase's threshold estimate."""
        exp = self.exp
        print(f"session {store.subject} complete ({exp.kind}): {store.dir}")
        cells = {}
        for r in rows:
            cells.setdefault((r["condition"], float(f"{r['intensity_physical']:.4g}")), []).append(r["correct"])
        label = "comparison harder" if exp.kind == "discrimination" else "correct"
        for (cond, x), c in sorted(cells.items()):
            # real vs virtual varies no intensity (its intensity_physical is 1 by the contract): print none
            level = "" if exp.kind == "real-virtual-2afc" else f" {x:10.4g} {exp.unit:6s}"
            say(f"  {cond:24s}{level} trials {len(c):3d}  {label} {np.mean(c):.2f}")
        for name, method in (self.handler.methods.items() if self.handler is not None else ()):
            est = method.estimate()
            say(f"  staircase {name}: {method.trials} trials, threshold estimate {est['threshold']:.4g} {exp.unit}")


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
