"""The blind realism rating study (thesis section 4.5) as an experiment kind: what differs from every session.

Phases (:mod:`study.ratings.schedule`): familiarization on the real wood sample, demonstration (each sample
once), testing (each sample ``repetitions`` times); an invalid attempt's trial goes back into the pool.
One attempt (section 4.5.3), through the session's attempt loop (:mod:`study.session.loop`):

1. the stylus is homed above the sample; the operator view says what to place
   (the real sample, or placeholder A/B alternating for virtual samples);
2. after the operator confirms, the subject is told to tap (text + cue);
3. the servo loop renders the sample for ``tap_window_s`` from the first impact;
   a low tone plays when the amplifier limit is hit;
4. "Stop. Please rate."; the stylus is homed again; a tap on the surface now means the subject
   overpowered the homing;
5. the subject rates 1-7 or rejects with x;
6. the attempt's trace file and CSV row are written (fsynced); an invalid
   attempt (saturated, rejected, overpowered, no tap) goes back into the pool.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from plumbing.studyfiles import RATING

from ..session.kind import ExperimentKind
from ..session.loop import Event, Outcome
from .schedule import Schedule, Trial, reason_of

SUBJECT_TEXT = {
    "familiarization": "Tap on the wooden sample as often as you like to learn how it feels.\n"
                       "Press Enter when you are done.",
    "prepare": "Please wait while the next sample is prepared.",
    "tap": "Tap now.",
    "rate": "How well did this sample represent tapping on the real wood?\n"
            "Press 1 (not at all) to 7 (exactly like it), or x to reject the trial.",
    "done": "The study is complete. Thank you!",
    "paused": "Short pause. Please wait.",
    "no_tap": "No tap was detected. This sample will come again later.",
}


@dataclass
class AttemptRecord:
    """Everything known about one finished attempt (before it becomes a CSV row)."""

    trial: Trial
    attempt: int
    kind: str
    rating: int | None
    rejected: bool
    saturated: bool
    overpowered: bool
    no_tap: bool
    velocities: list
    penetrations: list
    started_at: str
    duration_s: float
    end_familiarization: bool = False
    trace: dict | None = None

    @property
    def valid(self) -> bool:
        """True when the attempt counts (section 4.5.3): rated, not rejected, not saturated or overpowered, tapped."""
        if self.trial.phase == "familiarization":
            return not (self.saturated or self.overpowered)
        return not (self.rejected or self.saturated or self.overpowered or self.no_tap) and self.rating is not None

    @property
    def reason(self) -> str:
        """Why the attempt does not count ("" when valid)."""
        return reason_of({"valid": self.valid, "rejected": self.rejected, "saturated": self.saturated,
                          "overpowered": self.overpowered, "n_taps": len(self.velocities)})

    def row(self, subject: str) -> dict:
        """The attempt as one trials.csv row for ``subject`` (lists ';'-joined)."""
        v = [float(x) for x in self.velocities]
        p = [float(x) for x in self.penetrations]
        return {
            "subject": subject, "phase": self.trial.phase, "trial": self.trial.trial, "attempt": self.attempt,
            "sample": self.trial.sample, "kind": self.kind, "rating": self.rating, "rejected": self.rejected,
            "saturated": self.saturated, "overpowered": self.overpowered, "valid": self.valid,
            "n_taps": len(v),
            "incoming_velocity_mean_m_s": float(np.mean(v)) if v else math.nan,
            "penetration_mean_m": float(np.mean(p)) if p else math.nan,
            "incoming_velocities_m_s": v, "penetration_depths_m": p,
            "started_at": self.started_at, "duration_s": self.duration_s,
            "ends_familiarization": bool(self.end_familiarization and self.trial.phase == "familiarization"),
        }


class Ratings(ExperimentKind):
    """The rating study (module docstring): the default kind, run when a protocol has no ``[experiment]``."""

    names = ()
    rows = RATING
    phrases = None      # the masking audio's own cues: "Tap now.", "Stop. Please rate."
    familiarization = True
    texts = SUBJECT_TEXT

    @classmethod
    def samples(cls, config, load, where: str) -> list:
        """The catalog samples ``--samples`` picks (all by default), with the familiarization sample."""
        return load(True)

    def __init__(self, plan, apparatus) -> None:
        super().__init__(plan, apparatus)
        self.schedule = Schedule([s.name for s in plan.catalog], self.protocol.repetitions, plan.seed,
                                 self.protocol.familiarization_sample or None, plan.subject,
                                 self.max_attempts)
        self.subject = plan.subject
        self.fam_taps = 0
        self.attempts_run = 0
        self._attempts_at_start = 0
        self._t_start = time.monotonic()
        self.last_rating = None

    # -- what trials exist -------------------------------------------------------------------------------
    def plan(self) -> tuple[dict, list]:
        """``session.json``'s ``planned_order`` and one ``plan`` event per phase."""
        phases = self.schedule.phases.items()
        entries = {"planned_order": {k: v.summary()["planned"] for k, v in phases}}
        events = [{"event": "plan", "phase": name, "order": phase.summary()["planned"],
                   "trials": phase.summary()["planned_trials"]} for name, phase in phases]
        return entries, events

    def restore(self, store, rows: list, events: list) -> str | None:
        """Replay the recorded attempts through the schedule (``--resume``)."""
        if store.legacy_columns:  # written before rows carried ends_familiarization
            fam_ended = any(e.get("event") == "familiarization_ended" for e in events)
        else:  # the transition is in the row itself (same durable step as the attempt)
            fam_ended = any(r["ends_familiarization"] for r in rows)
        if not rows:
            return None
        self.schedule.replay(rows, fam_ended)
        # a trial the replay closes as not renderable whose event a kill lost (between the last attempt's row and
        # the event): logged now, as it would have been
        logged = {(e.get("phase"), e.get("trial")) for e in events if e.get("event") == "not_renderable"}
        for sched in self.schedule.phases.values():
            for record in sched.abandoned:
                if (record["phase"], record["trial"]) not in logged:
                    store.log_event({"event": "not_renderable",
                                     **{k: v for k, v in record.items() if k != "not_renderable"}})
        for row in rows:
            if row["phase"] == "familiarization":
                self.fam_taps += row["n_taps"]
            self.placement.on_stand = None if row["phase"] == "familiarization" else (
                row["sample"] if row["kind"] == "real" else self.placement.on_stand)
        self.attempts_run = self._attempts_at_start = len(rows)
        rated = [r for r in rows if r["phase"] != "familiarization"]
        if rated:
            self.last_rating = "x" if rated[-1]["rejected"] else rated[-1]["rating"]
        return f"resuming {self.subject}: {len(rows)} attempts on disk, next: {self.schedule.phase}"

    def next_attempt(self):
        """The schedule's next ``(trial, attempt)``, or None when the session is over."""
        return self.schedule.next()

    # -- one attempt -----------------------------------------------------------------------------------------
    def run_attempt(self, loop, trial: Trial, attempt: int) -> AttemptRecord:
        """Place the sample, cue, tap window, homing, rating; returns the record (written by the loop)."""
        kind = self.sample_kinds[trial.sample]
        fam = trial.phase == "familiarization"
        plan = self.sim_plan(trial, attempt) if self.apparatus.simulated_hand else None
        first = not fam or trial.trial == 1
        window = self.protocol.familiarization_window_s if fam else self.protocol.tap_window_s
        trial_id = f"{trial.phase}:{trial.trial}:{attempt}"
        shown = loop.present(trial.sample, window, status=lambda: self._placing(trial, attempt),
                             text=SUBJECT_TEXT["familiarization" if fam else "tap"],
                             prompt="familiarization" if fam else "wait", trial_id=trial_id if fam else None,
                             hand=plan, prepare=first, place=first, timed=True,
                             home_after="always" if fam else "no")
        tap = shown.tap
        rating, rejected, end_fam = None, False, False
        contacts = shown.contacts
        if fam:
            end_fam = plan.end_familiarization if loop.simulated else loop.ui.familiarization_ended()
        elif not tap.velocities:
            # nobody tapped within first_tap_timeout_s: nothing to rate, the trial is repeated later
            loop.say(SUBJECT_TEXT["no_tap"])
        else:
            answer, contacts = loop.ask(SUBJECT_TEXT["rate"], "rate", trial_id, home_after_cue=True,
                                        simulated=lambda: self.simulated_rating(trial, attempt, plan, tap))
            if loop.simulated:
                rating, rejected = answer
            elif answer == "x":
                rating, rejected = None, True
            else:
                rating, rejected = int(answer), False
        if fam and trial.trial >= self.protocol.familiarization_max_windows:
            end_fam = True
        record = AttemptRecord(trial=trial, attempt=attempt, kind=kind, rating=rating, rejected=rejected,
                               saturated=tap.saturated, overpowered=contacts > 0, no_tap=not tap.velocities,
                               velocities=tap.velocities, penetrations=tap.penetrations,
                               started_at=shown.started_at, duration_s=loop.now_s() - shown.t0_s)
        record.end_familiarization = end_fam
        record.trace = tap.trace
        return record

    def sim_plan(self, trial: Trial, attempt: int):
        """The simulated participant's tapping plan for this attempt."""
        sim = self.apparatus.sim_participant
        return sim.plan(trial.phase, trial.trial, attempt,
                        self.protocol.familiarization_window_s if trial.phase == "familiarization"
                        else self.protocol.tap_window_s, self.fam_taps)

    def simulated_rating(self, trial: Trial, attempt: int, plan, tap) -> tuple[int | None, bool]:
        """``(rating, rejected)`` of the simulated participant (the synthetic rater, :mod:`study.session.rater`)."""
        features = self.apparatus.features(tap)
        rating, rejected, _ = self.apparatus.sim_participant.rate(trial.phase, trial.trial, attempt, plan, features,
                                                                  tap.velocities, tap.penetrations,
                                                                  self.apparatus.reference)
        return rating, rejected

    # -- what a row holds --------------------------------------------------------------------------------------
    def outcome(self, trial: Trial, attempt: int, result: AttemptRecord, subject: str) -> Outcome:
        """The attempt's trace and its row (every attempt is a row, valid or not)."""
        return Outcome(traces=[(trial.phase, trial.trial, attempt, result.trace)], row=result.row(subject))

    def recorded(self, trial: Trial, attempt: int, result: AttemptRecord, row: dict | None) -> list:
        """The schedule moves on (an invalid attempt's trial is redrawn); the end of familiarization and a redraw
        are logged."""
        self.attempts_run += 1
        fam = trial.phase == "familiarization"
        if fam:
            self.fam_taps += len(result.velocities)
        redraw = self.schedule.record(trial, attempt, result.valid, result.reason,
                                      end_familiarization=result.end_familiarization)
        events = []
        if fam and self.schedule.phase != "familiarization":
            events.append(Event({"event": "familiarization_ended", "windows": trial.trial, "taps": self.fam_taps}))
        if redraw is not None and redraw.get("not_renderable"):   # max_attempts reached: the session goes on
            events.append(Event({"event": "not_renderable", **{k: v for k, v in redraw.items()
                                                                 if k != "not_renderable"}}))
        elif redraw is not None:
            events.append(Event({"event": "redraw", **redraw}))
        if not fam and not result.no_tap:
            self.last_rating = "x" if result.rejected else result.rating
        return events

    # -- the views and the end -----------------------------------------------------------------------------------
    def _progress(self) -> dict:
        out = {}
        for name, sched in self.schedule.phases.items():
            total = len(sched.slots)
            attempts = len(sched.run_order)
            out[name] = {"total": total, "attempts": attempts,
                         "valid": attempts - len(sched.redraws) - len(sched.abandoned)}
        return out

    def _status(self) -> dict:
        """What the operator page shows: subject, trial n of N, estimated time left, last rating (the loop adds
        the audio and the link)."""
        phases = list(self.schedule.phases.values())
        total = sum(len(s.slots) for s in phases)
        valid = sum(len(s.run_order) - len(s.redraws) - len(s.abandoned) for s in phases)
        remaining = max(0, total - valid)
        done = self.attempts_run - self._attempts_at_start
        per_attempt = (time.monotonic() - self._t_start) / done if done else None
        return {"subject": self.subject, "trials_valid": valid, "trials_total": total,
                "trial_n": min(total, valid + 1) if self.schedule.phase not in (None, "familiarization") else None,
                "time_left_s": None if per_attempt is None else per_attempt * remaining,
                "last_rating": self.last_rating, "finished": self.schedule.phase is None}

    def _placing(self, trial: Trial, attempt: int) -> dict:
        return {"phase": trial.phase, "trial": trial.trial, "attempt": attempt, "progress": self._progress(),
                **self._status()}

    def status(self, result=None, row: dict | None = None) -> dict:
        """The operator page after an attempt: its row, the progress, the redraws so far."""
        return {"last_attempt": dict(row), "progress": self._progress(),
                "redraws": [r for s in self.schedule.phases.values() for r in s.redraws], **self._status()}

    def done_status(self) -> dict:
        """The operator page at the end: "session complete"."""
        return {"phase": "done", "awaiting_confirm": False, "place": "", "message": "session complete",
                **self._status()}

    def reference(self, apparatus) -> dict:
        """The simulated rater's reference: the real wood-on-foam's own taps, motor off."""
        ref = apparatus.record_reference()
        return {"event": "rater_reference", "a": ref.a, "b": ref.b, "centroid_hz": ref.centroid_hz}

    def progress(self) -> tuple[int, int, str]:
        """(attempts finished, attempts planned) over demonstration and testing (redrawn trials add attempts), and
        the phase."""
        phases = [self.schedule.phases["demonstration"], self.schedule.phases["testing"]]
        left = sum(len(p.pool) + (p.current is not None) for p in phases)
        total = sum(len(p.planned) + len(p.redraws) for p in phases)
        return total - left, total, self.schedule.phase or "done"

    def finish(self, session: dict) -> None:
        """``session.json``'s ``order``: the plan and what ran, per phase."""
        session["order"] = self.schedule.summary()

    def summary(self, rows: list, store, say) -> None:
        """Attempts, valid, saturated, rejected and overpowered ones per phase."""
        by_phase = {}
        for r in rows:
            d = by_phase.setdefault(r["phase"], {"attempts": 0, "valid": 0, "saturated": 0, "rejected": 0,
                                                 "overpowered": 0})
            d["attempts"] += 1
            for key in ("valid", "saturated", "rejected", "overpowered"):
                d[key] += bool(r[key])
        print(f"session {store.subject} complete: {store.dir}")
        for phase, d in by_phase.items():
            print(f"  {phase:15s} attempts {d['attempts']:3d}  valid {d['valid']:3d}  saturated {d['saturated']:2d}  "
                  f"rejected {d['rejected']:2d}  overpowered {d['overpowered']:2d}")
        for sched in self.schedule.phases.values():
            for a in sched.abandoned:
                print(f"  {a['phase']} trial {a['trial']} ({a['sample']}) not renderable: {a['attempts']} attempts, "
                      f"none valid (max_attempts = {sched.max_attempts})")
