"""The attempt loop every experiment kind runs: one confirm, one pause, one present, one ask, one record.

:class:`SessionLoop` runs a session's attempts to the end (or until the operator aborts or the process is
killed). Per attempt it asks the kind (:class:`study.session.kind.ExperimentKind`) for the next one, lets the
kind compose it from the loop's steps, and writes what the kind says it holds:

* **present** (:meth:`SessionLoop.present`): the stylus is homed above the stand; the operator view says what
  to place (the real sample, or placeholder A/B alternating for a rendering, so an item is moved for every
  presentation whatever is presented, section 4.5.3) and the operator confirms (through any pause: the
  stylus is held meanwhile); the simulated hand gets its taps; the subject is told to tap (text and the
  spoken cue); the servo loop renders the sample for the window from the first impact (a low tone at the
  amplifier limit); the stylus is homed again (a tap now overpowered the homing);
* **ask** (:meth:`SessionLoop.ask`): the question on the subject's page, the spoken question after any cue
  still playing, then the answer: the simulated participant's, or the subject's key while the homing holds
  the stylus (a tap meanwhile overpowered it);
* **record**: the attempt's trace files, then its row in trials.csv (fsynced), then what follows from it
  (schedule events, a staircase's state), each durable before the next step (:mod:`study.session.store`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .store import utc_now
from .uistate import Aborted

#: when the stylus is homed after a tapping window: always, only if there was a tap, or not (the question
#: comes first: :meth:`SessionLoop.ask` with ``home_after_cue``)
HOME_AFTER = ("always", "tapped", "no")


class Placement:
    """What the operator puts on the stand: real samples as such, virtual ones on placeholder A/B.

    Placeholders alternate so that an item is removed and placed every presentation, whether the sample is
    real or virtual (section 4.5.3).
    """

    def __init__(self) -> None:
        self.on_stand: str | None = None

    def next(self, sample: str, kind: str) -> str:
        """What the operator places on the stand for this sample (real sample, or the other placeholder);
        returns the text to show."""
        if kind == "real":
            item = sample
            text = f"real sample '{sample}'" + (" (lift it and place it again)" if self.on_stand == sample else "")
        else:
            item = "placeholder B" if self.on_stand == "placeholder A" else "placeholder A"
            text = item
        self.on_stand = item
        return text


@dataclass
class Outcome:
    """What the loop writes for one attempt, in this order: its traces, then its row (if it counts).

    Attributes
    ----------
    traces : list of (str, int, int, dict)
        ``(phase, trial, attempt, arrays)`` of each trace file (``traces/<phase>_t<trial>_a<attempt>.npz``).
    row : dict or None
        The trials.csv row in the kind's :attr:`ExperimentKind.rows` format, or None (the attempt is logged,
        not recorded as a row).
    """

    traces: list = field(default_factory=list)
    row: dict | None = None


@dataclass
class Event:
    """A ``schedule.jsonl`` event to log (the loop adds its time)."""

    event: dict


@dataclass
class JsonLine:
    """A line of another JSON-lines file of the subject's folder (e.g. ``staircase_state.jsonl``), written durably
    with ``label`` as its step's name (the kill tests' ``crash_point``)."""

    name: str
    line: dict
    label: str


@dataclass
class Presented:
    """One presentation: the sample, what its tapping window measured, the surface contacts of the homing
    after it, and (``timed``) when it started (UTC, and on the device's clock, s)."""

    sample: str
    tap: object
    contacts: int
    started_at: str | None = None
    t0_s: float | None = None

    @property
    def n_taps(self) -> int:
        """Impacts detected in the window."""
        return len(self.tap.velocities)


class SessionLoop:
    """Runs one session's attempts (module docstring).

    Parameters
    ----------
    store : study.session.store.SessionStore
    kind : study.session.kind.ExperimentKind
    apparatus : study.session.apparatus.Apparatus or study.session.isolated.IsolatedApparatus
    participant : study.session.participants.SimulatedParticipant or a keyboard participant (``kind``
        "keyboard", ``ui`` its views)
    audio : study.session.audio.MaskingAudio or SilentAudio
    ui : study.session.uistate.UiState or None
    protocol : study.session.config.ProtocolConfig
    """

    def __init__(self, *, store, kind, apparatus, participant, audio, ui, protocol, markers=None) -> None:
        #: the Lab Streaming Layer's publisher of the session's events (plumbing.lsl), or None
        self.markers = markers
        self.store = store
        self.kind = kind
        self.apparatus = apparatus
        self.participant = participant
        self.audio = audio
        self.ui = ui
        self.protocol = protocol

    @property
    def simulated(self) -> bool:
        """True when the simulated participant answers (no person, no key to wait for)."""
        return self.participant.kind == "simulated"

    # -- the views -------------------------------------------------------------------------------------------
    def say(self, text: str, prompt: str = "wait", trial_id: str | None = None) -> None:
        """Show ``text`` on the subject's page with ``prompt`` (``trial_id``: the presentation a key answers)."""
        if self.ui is not None:
            if trial_id is None:
                self.ui.set_subject(text, prompt)
            else:
                self.ui.set_subject(text, prompt, trial_id)

    def operator(self, fields: dict) -> None:
        """Show ``fields`` on the operator page, with the masking audio's cue source and the device link's
        health (every kind's page shows them)."""
        if self.ui is not None:
            audio = getattr(self.audio, "cue_source", None) or type(self.audio).__name__
            # on a 3-DOF device: the samples on the table and where the hand is (study.session.apparatus3)
            view = getattr(self.apparatus, "table_view", None)
            if callable(view):
                fields = {**fields, "table": view()}
            self.ui.set_operator(**fields, audio=audio, link=self.apparatus.link_status())

    # -- the one confirm and pause ----------------------------------------------------------------------------
    def confirm(self, place: str, status) -> None:
        """The operator's turn before a tapping window: show ``status()``, ask to place ``place`` and wait for
        the confirmation, then through any pause (the apparatus holds the stylus meanwhile). A simulated
        participant's session shows the placement without waiting."""
        ui = self.ui
        if ui is None:
            return
        self.operator(status())
        if self.simulated:
            ui.set_operator(place=place, awaiting_confirm=False)
            return
        ui.request_confirm(place)
        self.apparatus.hold(until=ui.confirmed)
        while ui.snapshot("operator")["paused"]:
            self.say(self.kind.texts["paused"])
            self.apparatus.hold(until=lambda: not ui.snapshot("operator")["paused"])

    # -- the one present --------------------------------------------------------------------------------------
    def present(self, sample: str, window_s: float, *, status, text: str, prompt: str = "wait",
                trial_id: str | None = None, hand=None, prepare: bool = True, place: bool = True,
                timed: bool = False, home_after: str = "tapped") -> Presented:
        """Present ``sample`` for a tapping window of ``window_s`` s from the first impact (module docstring).

        Parameters
        ----------
        sample : str
            Catalog name.
        window_s : float
            Tapping time from the first impact (s).
        status : callable
            ``status()``: the operator page's fields while the operator places the sample.
        text, prompt, trial_id
            What the subject's page shows during the window (:meth:`say`).
        hand : study.session.participants.TapPlan or None
            The simulated hand's taps (sim devices).
        prepare, place : bool
            Tell the subject the sample is being prepared; ask the operator to place it.
        timed : bool
            Record when the window started (UTC and the device's clock, read after the hand got its plan).
        home_after : {"always", "tapped", "no"}
            Home the stylus after the window (counting overpowering taps) always, only after a tap, or not.
        """
        if prepare:
            self.say(self.kind.texts["prepare"])
        self.apparatus.set_sample(sample)
        self.apparatus.home(self.protocol.homing_before_max_s)
        if place:
            self.confirm(self.kind.placement.next(sample, self.kind.sample_kinds[sample]), status)
        if hand is not None:
            self.apparatus.start_hand(hand, window_s)
        started_at = t0 = None
        if timed:
            started_at, t0 = utc_now(), self.apparatus.now_s()
        self.say(text, prompt, trial_id)
        self.audio.cue_tap()
        self.mark({"event": "tap_cue", "sample": sample})
        tap = self.apparatus.tap_window(window_s, self.protocol.first_tap_timeout_s, on_clip=self.audio.cue_low_tone)
        contacts = 0
        if home_after == "always" or (home_after == "tapped" and tap.velocities):
            contacts = self.apparatus.after_window(self.protocol.homing_after_s)
        return Presented(sample, tap, contacts, started_at, t0)

    def now_s(self) -> float:
        """The device's clock (s)."""
        return self.apparatus.now_s()

    # -- the one ask ------------------------------------------------------------------------------------------
    def ask(self, text: str, prompt: str, trial_id: str | None = None, *, simulated=None,
            home_after_cue: bool = False) -> tuple[object, int]:
        """Ask the subject: the question, the spoken cue, then the answer.

        "Stop. Please rate." (or "Which one?") never talks over "Tap now.": a person's window (1 s) outlasts
        the tap cue (~0.7 s), but a simulated participant's window runs faster than real time, so the cue
        waits for the one before it.

        Parameters
        ----------
        text, prompt, trial_id
            The question on the subject's page (``prompt`` "rate" or "choice" takes a key).
        simulated : callable
            ``simulated()``: the simulated participant's answer (called instead of waiting for a key).
        home_after_cue : bool
            Home the stylus after the spoken question, counting overpowering taps (the rating study's order).

        Returns
        -------
        (object, int)
            The subject's key (``"1"``.. or ``"x"``), or what ``simulated()`` returned; the surface contacts
            meanwhile (the homing after the cue, and while a person answered).
        """
        self.say(text, prompt, trial_id)
        self.audio.wait_cues(2.0)
        self.audio.cue_rate()
        self.mark({"event": "question", "prompt": prompt})
        contacts = self.apparatus.after_window(self.protocol.homing_after_s) if home_after_cue else 0
        if self.simulated:
            answer = simulated()
        else:
            contacts += self.apparatus.hold(until=lambda: self.ui.rating() is not None)
            answer = self.ui.rating()
        self.mark({"event": "answer", "answer": answer if isinstance(answer, str) else
                   (answer[0] if isinstance(answer, tuple) and answer and isinstance(answer[0], str) else str(answer))})
        return answer, contacts

    def mark(self, event: dict) -> None:
        """Publish a session event to the Lab Streaming Layer's marker stream (when the session streams)."""
        if self.markers is not None:
            self.markers.marker(event)

    # -- the session ------------------------------------------------------------------------------------------
    def run(self) -> None:
        """Run attempts until the kind has none left; :class:`study.session.uistate.Aborted` when the operator
        aborts."""
        kind, store = self.kind, self.store
        while True:
            if self.ui is not None and self.ui.snapshot("operator")["aborted"]:
                raise Aborted("the operator aborted the session")
            nxt = kind.next_attempt()
            if nxt is None:
                break
            trial, attempt = nxt
            self.mark({"event": "attempt_start", "trial": getattr(trial, "trial", None) if not isinstance(trial, tuple)
                       else getattr(trial[0], "trial", None), "attempt": attempt})
            result = kind.run_attempt(self, trial, attempt)
            out = kind.outcome(trial, attempt, result, store.subject)
            for phase, number, tried, arrays in out.traces:
                store.write_trace(phase, number, tried, arrays)
            if out.row is not None:
                store.append_trial(out.row)
            self.mark({"event": "recorded", "row": out.row is not None, "attempt": attempt})
            for item in kind.recorded(trial, attempt, result, out.row):
                if isinstance(item, Event):
                    store.log_event(item.event)
                elif isinstance(item, JsonLine):
                    store.append_json_line(item.name, item.line, item.label)
                else:
                    raise TypeError(f"{type(kind).__name__}.recorded returned {item!r}, not an Event or JsonLine")
            if self.ui is not None:
                self.operator(kind.status(result, out.row))
        self.say(kind.texts["done"])
        if self.ui is not None:
            self.operator(kind.done_status())
