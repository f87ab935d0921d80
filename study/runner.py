"""The session runner: protocol, apparatus, participant, audio, views and data, tied together.

One attempt (section 4.5.3):

1. the stylus is homed above the sample; the operator view says what to place
   (the real sample, or placeholder A/B alternating for virtual samples);
2. after the operator confirms, the subject is told to tap (text + cue);
3. the servo loop renders the sample for ``tap_window_s`` from the first impact;
   a low tone plays when the amplifier limit is hit;
4. the stylus is homed again; a tap on the surface now means the subject
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

from .data import SessionStore, utc_now
from .protocol import Schedule, Trial, reason_of
from .uistate import Aborted

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


def operator_places(ui, apparatus, place: str, simulated: bool, on_pause) -> None:
    """The operator's turn before a tap window: ask to place ``place`` and wait for the confirmation, then
    through any pause (the apparatus holds the stylus meanwhile). A simulated participant's session shows
    the placement without waiting. ``on_pause()`` tells the subject's page the session is paused."""
    if simulated:
        ui.set_operator(place=place, awaiting_confirm=False)
        return
    ui.request_confirm(place)
    apparatus.hold(until=ui.confirmed)
    while ui.snapshot("operator")["paused"]:
        on_pause()
        apparatus.hold(until=lambda: not ui.snapshot("operator")["paused"])


class Placement:
    """What the operator puts on the stand: real samples as such, virtual ones on placeholder A/B.

    Placeholders alternate so that an item is removed and placed every trial,
    whether the sample is real or virtual (section 4.5.3).
    """

    def __init__(self) -> None:
        self.on_stand: str | None = None

    def next(self, sample: str, kind: str) -> str:
        """What the operator places on the stand for this sample (real sample, or the other placeholder); returns the text to show."""
        if kind == "real":
            item = sample
            text = f"real sample '{sample}'" + (" (lift it and place it again)" if self.on_stand == sample else "")
        else:
            item = "placeholder B" if self.on_stand == "placeholder A" else "placeholder A"
            text = item
        self.on_stand = item
        return text


class StudyRunner:
    """Runs a session to the end (or until aborted/killed), writing every attempt as it ends."""

    def __init__(self, *, store: SessionStore, schedule: Schedule, apparatus, participant, audio, ui,
                 protocol, kinds: dict, log=print) -> None:
        self.store = store
        self.schedule = schedule
        self.apparatus = apparatus
        self.participant = participant
        self.audio = audio
        self.ui = ui
        self.protocol = protocol
        self.kinds = kinds
        self.placement = Placement()
        self.log = log
        self.fam_taps = 0
        self.counts = {}
        self.attempts_run = 0
        self._attempts_at_start = 0
        self._t_start = time.monotonic()
        self.last_rating = None

    # -- helpers -------------------------------------------------------------
    def _subject(self, key: str, prompt: str = "wait", trial: Trial | None = None, attempt: int = 0) -> None:
        if self.ui is not None:
            self.ui.set_subject(SUBJECT_TEXT[key], prompt,
                                None if trial is None else f"{trial.phase}:{trial.trial}:{attempt}")

    def _progress(self) -> dict:
        out = {}
        for name, sched in self.schedule.phases.items():
            total = len(sched.slots)
            attempts = len(sched.run_order)
            out[name] = {"total": total, "attempts": attempts, "valid": attempts - len(sched.redraws)}
        return out

    def _status(self) -> dict:
        """What the operator page shows: subject, trial n of N, estimated time left, last rating, audio/link."""
        phases = [s for n, s in self.schedule.phases.items()]
        total = sum(len(s.slots) for s in phases)
        valid = sum(len(s.run_order) - len(s.redraws) for s in phases)
        remaining = max(0, total - valid)
        done = self.attempts_run - self._attempts_at_start
        per_attempt = (time.monotonic() - self._t_start) / done if done else None
        last = self.last_rating
        return {"subject": self.store.subject, "trials_valid": valid, "trials_total": total,
                "trial_n": min(total, valid + 1) if self.schedule.phase not in (None, "familiarization") else None,
                "time_left_s": None if per_attempt is None else per_attempt * remaining,
                "last_rating": last, "audio": getattr(self.audio, "cue_source", None) or type(self.audio).__name__,
                "link": self.apparatus.link_status(),
                "finished": self.schedule.phase is None}

    def restore(self, rows: list[dict], familiarization_ended: bool) -> None:
        """Replay recorded attempts (``--resume``)."""
        self.schedule.replay(rows, familiarization_ended)
        for row in rows:
            if row["phase"] == "familiarization":
                self.fam_taps += row["n_taps"]
            self.placement.on_stand = None if row["phase"] == "familiarization" else (
                row["sample"] if row["kind"] == "real" else self.placement.on_stand)
        self.attempts_run = self._attempts_at_start = len(rows)
        rated = [r for r in rows if r["phase"] != "familiarization"]
        if rated:
            self.last_rating = "x" if rated[-1]["rejected"] else rated[-1]["rating"]

    def _wait_operator(self, place: str, trial: Trial, attempt: int) -> None:
        if self.ui is None:
            return
        self.ui.set_operator(phase=trial.phase, trial=trial.trial, attempt=attempt, progress=self._progress(),
                             **self._status())
        operator_places(self.ui, self.apparatus, place, simulated=self.participant.kind == "simulated",
                        on_pause=lambda: self._subject("paused"))

    # -- one attempt ---------------------------------------------------------
    def run_attempt(self, trial: Trial, attempt: int) -> AttemptRecord:
        """Run one attempt: place the sample, cue, tap window, homing, rating; returns the record (written by the caller)."""
        kind = self.kinds[trial.sample]
        fam = trial.phase == "familiarization"
        plan = None
        if self.apparatus.simulated_hand:
            plan = self.sim_plan(trial, attempt)
        if not fam or trial.trial == 1:
            self._subject("prepare")
        self.apparatus.set_sample(trial.sample)
        self.apparatus.home(self.protocol.homing_before_max_s)
        if not fam or trial.trial == 1:
            place = self.placement.next(trial.sample, kind)
            self._wait_operator(place, trial, attempt)
        window = self.protocol.familiarization_window_s if fam else self.protocol.tap_window_s
        if plan is not None:
            self.apparatus.start_hand(plan, window)
        started_at = utc_now()
        t0 = self.apparatus.now_s()
        if fam:
            self._subject("familiarization", "familiarization", trial, attempt)
        else:
            self._subject("tap")
        self.audio.cue_tap()
        tap = self.apparatus.tap_window(window, self.protocol.first_tap_timeout_s, on_clip=self.audio.cue_low_tone)
        # homing after the window; taps on the surface now overpowered the homing
        rating, rejected, end_fam = None, False, False
        if fam:
            contacts = self.apparatus.after_window(self.protocol.homing_after_s)
            if self.participant.kind == "simulated":
                end_fam = plan.end_familiarization
            else:
                end_fam = self.ui.familiarization_ended()
        elif not tap.velocities:
            # nobody tapped within first_tap_timeout_s: nothing to rate, the trial is repeated later
            self._subject("no_tap")
            contacts = 0
        else:
            self._subject("rate", "rate", trial, attempt)
            # "Stop. Please rate." never talks over "Tap now.": a person's window (1 s) outlasts the tap cue
            # (~0.7 s), but a simulated participant's window runs faster than real time
            self.audio.wait_cues(2.0)
            self.audio.cue_rate()
            contacts = self.apparatus.after_window(self.protocol.homing_after_s)
            rating, rejected, contacts_rating = self.get_rating(trial, attempt, plan, tap)
            contacts += contacts_rating
        if fam and trial.trial >= self.protocol.familiarization_max_windows:
            end_fam = True
        record = AttemptRecord(trial=trial, attempt=attempt, kind=kind, rating=rating, rejected=rejected,
                               saturated=tap.saturated, overpowered=contacts > 0, no_tap=not tap.velocities,
                               velocities=tap.velocities, penetrations=tap.penetrations,
                               started_at=started_at, duration_s=self.apparatus.now_s() - t0)
        record.end_familiarization = end_fam
        record.trace = tap.trace
        return record

    def sim_plan(self, trial: Trial, attempt: int):
        """The simulated participant's tapping plan for this attempt."""
        sim = self.apparatus.sim_participant
        return sim.plan(trial.phase, trial.trial, attempt,
                        self.protocol.familiarization_window_s if trial.phase == "familiarization"
                        else self.protocol.tap_window_s, self.fam_taps)

    def get_rating(self, trial: Trial, attempt: int, plan, tap) -> tuple[int | None, bool, int]:
        """``(rating, rejected, contacts)``: from the simulated rater, or the subject's key while homing holds."""
        if self.participant.kind == "simulated":
            features = self.apparatus.features(tap)
            rating, rejected, _ = self.participant.rate(trial.phase, trial.trial, attempt, plan, features,
                                                        tap.velocities, tap.penetrations, self.apparatus.reference)
            return rating, rejected, 0
        contacts = self.apparatus.hold(until=lambda: self.ui.rating() is not None)
        key = self.ui.rating()
        if key == "x":
            return None, True, contacts
        return int(key), False, contacts

    # -- the session ---------------------------------------------------------
    def run(self) -> None:
        """Run attempts until the schedule is done; Aborted when the operator aborts."""
        while True:
            if self.ui is not None and self.ui.snapshot("operator")["aborted"]:
                raise Aborted("the operator aborted the session")
            nxt = self.schedule.next()
            if nxt is None:
                break
            trial, attempt = nxt
            record = self.run_attempt(trial, attempt)
            self.store.write_trace(trial.phase, trial.trial, attempt, record.trace)
            row = record.row(self.store.subject)
            self.store.append_trial(row)
            self.attempts_run += 1
            if trial.phase == "familiarization":
                self.fam_taps += len(record.velocities)
            redraw = self.schedule.record(trial, attempt, record.valid, record.reason,
                                          end_familiarization=record.end_familiarization)
            if trial.phase == "familiarization" and self.schedule.phase != "familiarization":
                self.store.log_event({"event": "familiarization_ended", "windows": trial.trial, "taps": self.fam_taps})
            if redraw is not None:
                self.store.log_event({"event": "redraw", **redraw})
            if trial.phase != "familiarization" and not record.no_tap:
                self.last_rating = "x" if record.rejected else record.rating
            if self.ui is not None:
                last = dict(row)
                self.ui.set_operator(last_attempt=last, progress=self._progress(),
                                     redraws=[r for s in self.schedule.phases.values() for r in s.redraws],
                                     **self._status())
        self._subject("done")
        if self.ui is not None:
            self.ui.set_operator(phase="done", awaiting_confirm=False, place="", message="session complete",
                                 **self._status())
