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
trial starts). After the protocol's ``max_attempts`` invalid attempts the trial is recorded as not renderable
(``not_renderable`` in schedule.jsonl, no row) and the session goes on with the next trial; an adaptive
staircase whose intensity the device cannot render (refused before its first attempt, or never valid) stops
there, the others go on. ``--resume`` replans the same trials from the seed and checks every row against it
(the intensities, samples and target of the plan or of the staircases' replay, the attempt numbers against the
logged invalid attempts, ``session.json``'s experiment against its settings), checks ``schedule.jsonl`` and
``staircase_state.jsonl`` against ``trials.csv`` (a duplicated or foreign line is refused, a lost or torn last
state line written again), then continues with the next trial, its attempt number after the logged invalid
attempts (an attempt the kill cut short, or whose event it tore, runs again under its number; its traces are
kept aside in ``traces/interrupted/``, never overwritten).
"""

from __future__ import annotations

import json
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
from .experiment import (KINDS, QUESTIONS, ExperimentConfig, PlannedTrial, adaptive_trial, base_sample, check_levels,
                         derive_sample, experiment_from_dict, handler_seed, intensity_of, levels_asked, plan_trials,
                         stimulus_catalog, unrenderable)
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
#: the reason of a trial whose stimulus the device refused before its first attempt (an adaptive level)
DEVICE_REASON = "device"
#: where a damaged file's repair is described
REPAIR_NOTE = 'docs/study.md, "A damaged trials.csv"'
#: the simulated participant's answer's word in its seeds (:meth:`study.session.participants.SimulatedParticipant.rng`);
#: part of the recorded sessions' meaning, never changed
ANSWER_STREAM = 34


@dataclass
class Attempt:
    """One attempt of a trial: its intervals (:class:`study.session.loop.Presented`), the answer, the simulated
    participant's percepts (NaN for a person), why it does not count ("" when it does), when it started, and
    why the device refused its stimulus ("" when it did not: then there is no interval)."""

    trial: PlannedTrial
    is_catch: int
    staircase_trial: object
    intervals: list
    response: str
    percepts: tuple
    reason: str
    started_at: str
    t0: float
    refused: str = ""


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
        info = plan.device_info
        if exp.adaptive:
            self.handler = exp.handler(handler_seed(plan.seed, plan.subject))
            self.base = base_sample(load_catalog(plan.catalog_file, library_dir=plan.library_dir), exp)
        else:
            self.trials = plan_trials(exp, plan.seed, plan.subject)
        # a level the device cannot render is refused now, before the subject folder is made
        check_levels(levels_asked(exp, plan.catalog, self.base, self.handler), info)
        self.device = info
        # eq. 3.17, as DeviceInfo.force_per_amp_N_A: the simulated participant's stiffness percept
        self.force_per_amp_N_A = float(info["gear_ratio"] * info["torque_constant_Nm_A"] / info["handle_length_m"])
        if self.max_attempts is None:   # a session begun without the cap (ExperimentKind): no cap
            self.max_attempts = math.inf
        self.done = 0              # rows on disk (valid trials)
        self.position = 0          # trials settled: a row, or recorded as not renderable
        self.skipped: list = []    # the not_renderable events
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
        """Continue after the ``rows`` on disk, every one checked against this session's plan (or its staircases'
        replay) and ``schedule.jsonl``'s events; the next trial's attempt number follows its logged invalid
        attempts (traces of an attempt that has neither a row nor an event are kept aside when it runs again:
        :meth:`study.session.store.SessionStore.write_trace`).

        Raises
        ------
        ValueError
            A row this session would not have recorded (another seed, subject or scale, an edited intensity,
            sample or attempt), ``session.json``'s experiment edited, or a duplicated or foreign line in
            schedule.jsonl or staircase_state.jsonl; each naming the file and line.
        """
        self._check_session(store)
        skips = self._check_events(store, rows, events)
        if self.handler is not None:
            self._replay(store, rows, skips)
        else:
            self._restore_plan(store, rows, skips)
        self.done = len(rows)
        self.skipped = [skips[n] for n in sorted(skips)]
        self.invalid = [e for e in events if e.get("event") == "invalid_attempt"]
        current = self.position + 1
        logged = [int(e["attempt"]) for e in self.invalid if e.get("trial") == current]
        self.next_number = 1 + max([0, *logged])
        if self.next_number > self.max_attempts and not self.finished:
            # killed after the trial's last attempt, before it was recorded as not renderable: record it now
            if self.handler is None:
                pt, trial = self.trials[self.position], None
            else:
                trial = self.handler.next_trial()
                pt = adaptive_trial(self.exp, current, trial.label, trial.intensity, self.seed, self.subject)
            skip = self._skip(pt, trial.is_catch if trial is not None else 0, trial)
            store.log_event(skip)
        note = f"resuming {self.subject}: {len(rows)} trials on disk"
        if self.skipped:
            note += f", {len(self.skipped)} recorded as not renderable"
        return note

    def _check_session(self, store) -> None:
        """``session.json["experiment"]`` says what its settings say (an edited ``intensity_scale`` would give one
        file with two scales)."""
        recorded = (store.session or {}).get("experiment")
        if not isinstance(recorded, dict):
            return
        for key, value in self.exp.to_session().items():
            if key != "config" and key in recorded and recorded[key] != value:
                raise ValueError(f"{store.session_path}: experiment.{key} is {recorded[key]!r} but the session's "
                                 f"settings (experiment.config) give {value!r}; session.json was edited: restore "
                                 "it (a session keeps one scale and one design from its first trial to its last)")

    def _check_events(self, store, rows: list, events: list) -> dict:
        """schedule.jsonl against this session and trials.csv: the plan first and this session's; each invalid
        attempt and each trial not renderable once, for a trial trials.csv does not record past it, within the
        attempt cap. Returns the not_renderable events by trial."""
        path = store.schedule_path
        want = self.plan()[1][0]
        first = dict(events[0]) if events else None
        if first is not None:
            first.pop("at", None)
        if first != json.loads(json.dumps(want)):
            raise ValueError(f"{path} line 1: not this session's plan (another seed, subject or design, or an "
                             "edited file); the file does not belong to this session")
        rows_at = {r["trial"]: r for r in rows}
        seen, skips = set(), {}
        for number, e in enumerate(events, start=1):
            kind = e.get("event")
            if kind not in ("invalid_attempt", "not_renderable"):
                continue
            trial, attempts = e.get("trial"), e.get("attempt", e.get("attempts"))
            where = f"{path} line {number}"
            if not (isinstance(trial, int) and isinstance(attempts, int)) or trial < 1 or attempts < 0:
                raise ValueError(f"{where}: {kind} without its trial and attempt numbers; the file is damaged")
            if attempts > self.max_attempts:
                raise ValueError(f"{where}: {kind} of trial {trial} attempt {attempts}, beyond max_attempts = "
                                 f"{self.max_attempts}; the file does not belong to this session")
            if kind == "invalid_attempt":
                if e.get("reason") not in INVALID_REASONS:
                    raise ValueError(f"{where}: invalid attempt with reason {e.get('reason')!r}, not one of "
                                     f"{list(INVALID_REASONS)}; the file is damaged")
                if (trial, attempts) in seen:
                    raise ValueError(f"{where}: trial {trial} attempt {attempts} is logged twice (a duplicated line)")
                seen.add((trial, attempts))
                row = rows_at.get(trial)
                if row is not None and attempts >= row["attempt"]:
                    raise ValueError(f"{where}: invalid attempt {attempts} of trial {trial}, but trials.csv records "
                                     f"its attempt {row['attempt']} as the valid one")
            else:
                if trial in rows_at or trial in skips:
                    raise ValueError(f"{where}: trial {trial} recorded as not renderable, but it is "
                                     + ("in trials.csv" if trial in rows_at else "logged so twice"))
                skips[trial] = e
        settled_n = len(rows_at) + len(skips)
        for number, e in enumerate(events, start=1):
            if e.get("event") == "invalid_attempt" and e["trial"] > settled_n + 1:
                raise ValueError(f"{path} line {number}: an attempt of trial {e['trial']}, but trials.csv and the "
                                 f"trials not renderable end at trial {settled_n}: a line from another session")
        for r in rows:
            if r["attempt"] > self.max_attempts:
                raise ValueError(f"{store.trials_path}: trial {r['trial']} attempt {r['attempt']}, beyond "
                                 f"max_attempts = {self.max_attempts}; the file does not belong to this session")
        settled = sorted([*rows_at, *skips])
        if settled != list(range(1, len(settled) + 1)):
            gap = next(n for n, got in enumerate(settled, start=1) if got != n)
            raise ValueError(f"{store.trials_path}: trial {gap} is neither in it nor recorded as not renderable in "
                             f"{path}; the files do not go together ({REPAIR_NOTE})")
        return skips

    def _check_row(self, store, line: int, row: dict, pt: PlannedTrial, is_catch: int) -> None:
        """One row against the trial this session plans (or its staircases ask for)."""
        got = {"condition": row["condition"], "staircase": row["staircase"],
               "intensity_physical": row["intensity_physical"], "intensity": row["intensity"],
               "is_catch": row["is_catch"], "target_interval": row["target_interval"],
               "sample_1": row["sample_1"], "sample_2": row["sample_2"]}
        want = {"condition": pt.condition, "staircase": pt.staircase, "intensity_physical": pt.intensity_physical,
                "intensity": intensity_of(self.exp, pt.intensity_physical), "is_catch": int(is_catch),
                "target_interval": pt.target_interval, "sample_1": pt.samples[0], "sample_2": pt.samples[1]}
        diff = [k for k in got if got[k] != want[k]]
        if diff:
            shown = ", ".join(f"{k} {got[k]!r} (this session: {want[k]!r})" for k in diff)
            raise ValueError(f"{store.trials_path} line {line}: trial {row['trial']} has {shown}; the row was "
                             f"edited or does not belong to this session ({REPAIR_NOTE})")

    def _restore_plan(self, store, rows: list, skips: dict) -> None:
        """Constant stimuli: each row is its planned trial."""
        for i, row in enumerate(rows):
            n = row["trial"]
            if n > len(self.trials):
                raise ValueError(f"{store.trials_path} line {i + 2}: trial {n}, but the plan has only "
                                 f"{len(self.trials)} trials")
            self._check_row(store, i + 2, row, self.trials[n - 1], 0)
        self.position = len(rows) + len(skips)

    def _replay(self, store, rows: list, skips: dict) -> None:
        """Feed the recorded trials (and those not renderable) to fresh staircases, checking every row against
        what they ask for and every state line against the replay; write the state lines a kill lost (a torn
        last one is kept aside by the store)."""
        path = store.dir / STATE_JSONL
        lines = store.read_json_lines(STATE_JSONL, then="it will be written again from trials.csv; kept it in")
        store.hold_file(STATE_JSONL)   # held from here on, like trials.csv: a truncation mid-session stops it
        by_trial = {r["trial"]: (i, r) for i, r in enumerate(rows)}
        expected = []
        for n in range(1, len(rows) + len(skips) + 1):
            trial = self.handler.next_trial()
            if n in skips:
                e = skips[n]
                if (e.get("staircase"), e.get("intensity_physical"), bool(e.get("is_catch"))) != \
                        (trial.label, trial.intensity, bool(trial.is_catch)):
                    raise ValueError(f"{store.schedule_path}: trial {n} recorded as not renderable is (staircase, "
                                     f"intensity, catch) {(e.get('staircase'), e.get('intensity_physical'), e.get('is_catch'))}, "
                                     f"but the staircases of this session ask for "
                                     f"{(trial.label, trial.intensity, bool(trial.is_catch))}; the file does not "
                                     "belong to this session")
                self.handler.drop(trial)
                continue
            i, row = by_trial[n]
            pt = adaptive_trial(self.exp, n, trial.label, trial.intensity, self.seed, self.subject)
            self._check_row(store, i + 2, row, pt, int(trial.is_catch))
            self.handler.update(trial, bool(row["correct"]))
            expected.append(self._state_line(trial, bool(row["correct"]), n))
        self.position = len(rows) + len(skips)
        for k, line in enumerate(lines):
            if k >= len(expected):
                raise ValueError(f"{path} line {k + 1}: a staircase state for trial {line.get('trial')!r}, which "
                                 f"trials.csv does not record (it has {len(rows)} trials): a duplicated line or "
                                 "one from another session; restore the file (its lines are written again from "
                                 "trials.csv if it is moved away)")
            if line != json.loads(json.dumps(expected[k].line)):
                raise ValueError(f"{path} line {k + 1}: the staircase state of trial {line.get('trial')!r} is not "
                                 "what trials.csv replays to: an edited line or one from another session; restore "
                                 "the file (its lines are written again from trials.csv if it is moved away)")
        for item in expected[len(lines):]:
            store.append_json_line(item.name, item.line, item.label)
        if len(expected) - len(lines) > 1:
            print(f"note: {path} had {len(lines)} staircase states for {len(expected)} trials; wrote the "
                  f"{len(expected) - len(lines)} missing ones again from trials.csv")

    def _skip(self, pt: PlannedTrial, is_catch, staircase_trial, refused: str = "") -> dict:
        """Record the trial ``pt`` as not renderable and move on (an adaptive trial's staircase stops); returns
        the ``not_renderable`` event to log."""
        reasons = [e["reason"] for e in self.invalid if e["trial"] == pt.trial]
        attempts = max([0, *(e["attempt"] for e in self.invalid if e["trial"] == pt.trial)])
        skip = {"event": "not_renderable", "trial": pt.trial, "attempts": attempts,
                "reasons": reasons or [DEVICE_REASON], "staircase": pt.staircase,
                "intensity_physical": pt.intensity_physical, "is_catch": bool(is_catch), "samples": list(pt.samples),
                "why": refused or f"{attempts} attempts, none valid (max_attempts = {self.max_attempts})"}
        if staircase_trial is not None:
            self.handler.drop(staircase_trial)
        self.skipped.append(skip)
        self.position += 1
        self.next_number = 1
        return skip

    def _state_line(self, trial, correct: bool, number: int | None = None) -> JsonLine:
        method = self.handler.methods[trial.label]
        line = {"trial": trial.number if number is None else number, "staircase": trial.label,
                "is_catch": bool(trial.is_catch), "intensity_physical": trial.intensity, "correct": int(correct),
                "state": method.state(), "estimate": method.estimate(), "finished": self.handler.finished}
        return JsonLine(STATE_JSONL, line, f"staircase state written: trial {line['trial']}")

    @property
    def finished(self) -> bool:
        """True when the plan is done (constant stimuli) or every staircase has finished."""
        if self.handler is not None:
            return self.handler.finished
        return self.position >= len(self.trials)

    @property
    def total(self) -> int | None:
        """Trials planned (constant stimuli), or the staircases' ``max_trials`` summed (None when a staircase
        stops by reversals only)."""
        if self.handler is None:
            return len(self.trials)
        caps = [m.max_trials for m in self.handler.methods.values()]
        return None if None in caps else sum(caps)

    def next_attempt(self):
        """``((planned trial, is_catch, the staircases' trial or None, why not renderable), attempt)``, or None
        when finished; an adaptive trial's stimuli get their servo loops here (a level the device cannot render
        gets none: its trial is recorded as not renderable without an attempt)."""
        if self.finished:
            return None
        number = self.position + 1
        if self.handler is None:
            return (self.trials[self.position], 0, None, ""), self.next_number
        trial = self.handler.next_trial()
        pt = adaptive_trial(self.exp, number, trial.label, trial.intensity, self.seed, self.subject)
        refused = ""
        for value in (trial.intensity, self.exp.reference if self.exp.kind == "discrimination" else None):
            sample = derive_sample(self.base, self.exp, value)
            refused = unrenderable(sample, self.device) or ""
            if not refused:
                try:
                    self.apparatus.add_sample(sample)
                except ValueError as exc:   # the servo loop refuses it (devices.limits): never presented
                    refused = str(exc)
            if refused:
                break
            self.sample_kinds[sample.name] = sample.kind
        return (pt, int(trial.is_catch), trial, refused), self.next_number

    # -- one attempt -------------------------------------------------------------------------------------------
    def _status(self, **extra) -> dict:
        total = self.total
        return {"subject": self.subject, "phase": self.exp.kind, "trials_valid": self.done,
                "trials_total": total,
                "trial_n": self.position + 1 if total is None else min(total, self.position + 1),
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
        """Both intervals and the answer (none for a stimulus the device refused: :meth:`next_attempt`)."""
        pt, is_catch, staircase_trial, refused = trial
        started_at, t0 = utc_now(), time.monotonic()
        if refused:
            return Attempt(pt, is_catch, staircase_trial, [], "", (math.nan, math.nan), DEVICE_REASON, started_at,
                           t0, refused)
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
        """An invalid attempt is logged and the same trial runs again, until the protocol's ``max_attempts``:
        then (or at once for a stimulus the device refused) the trial is recorded as not renderable and the
        session goes on (an adaptive trial's staircase stops). A valid one's staircase takes the answer and its
        state is written before the next trial."""
        pt = result.trial
        if row is None:
            out = []
            if result.reason != DEVICE_REASON:
                event = {"event": "invalid_attempt", "trial": pt.trial, "attempt": attempt, "reason": result.reason,
                         "response": result.response, "n_taps": [iv.n_taps for iv in result.intervals],
                         "samples": [iv.sample for iv in result.intervals]}
                self.invalid.append(event)
                self.next_number += 1
                out.append(Event(event))
                if attempt < self.max_attempts:
                    return out
            return out + [Event(self._skip(pt, result.is_catch, result.staircase_trial, result.refused))]
        out = []
        if result.staircase_trial is not None:   # the staircase's state after this trial, before the next one starts
            self.handler.update(result.staircase_trial, bool(row["correct"]))
            out.append(self._state_line(result.staircase_trial, bool(row["correct"]), pt.trial))
        self.done += 1
        self.position += 1
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
            stopped = " (stopped: a level the device cannot render)" if name in self.handler.stopped else ""
            say(f"  staircase {name}: {method.trials} trials, threshold estimate {est['threshold']:.4g} {exp.unit}"
                f"{stopped}")
        for skip in self.skipped:
            say(f"  trial {skip['trial']} not renderable ({skip['intensity_physical']:.4g} {exp.unit}): {skip['why']}")


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
