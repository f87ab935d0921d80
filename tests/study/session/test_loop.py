"""The attempt loop (study.session.loop) on its own, with a minimal experiment kind on the real sim apparatus: the
order of what it writes, the placements, a person's key, the operator's abort. The kind here is the skeleton
of docs/architecture.md ("A new experiment kind"): one presentation per trial and a yes/no question."""

import threading
from types import SimpleNamespace

import numpy as np
import pytest

from devices.sim import SimDevice
from plumbing.studyfiles import RowFormat
from stimuli import load_catalog
from study.session.apparatus import Apparatus
from study.session.audio import SilentAudio
from study.session.config import ProtocolConfig
from study.session.kind import ExperimentKind
from study.session.loop import Event, Outcome, SessionLoop
from study.session.participants import SimParticipantConfig, SimulatedParticipant
from study.session.store import SessionStore
from study.session.uistate import Aborted, UiState

COLUMNS = ("subject", "trial", "attempt", "sample", "response", "n_taps")


def _parse(raw: dict, where: str) -> dict:
    try:
        return {**raw, "trial": int(raw["trial"]), "attempt": int(raw["attempt"]), "n_taps": int(raw["n_taps"])}
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{where}: bad value ({exc})") from None


CLICK_ROWS = RowFormat("click session", COLUMNS, (COLUMNS,), lambda row: {k: str(row[k]) for k in COLUMNS},
                       _parse, lambda row, where, state: None)


class Clicks(ExperimentKind):
    """Yes/no: one sample per trial, "Did it click?"; the samples alternate."""

    names = ("clicks",)
    rows = CLICK_ROWS
    familiarization = False
    texts = {"prepare": "Please wait.", "paused": "Short pause.", "no_tap": "No tap.", "done": "Done, thank you.",
             "tap": "Tap now.", "ask": "Did it click? Press 1 (no) or 2 (yes)."}

    @classmethod
    def samples(cls, config, load, where):
        return load(True)

    def __init__(self, plan, apparatus, order=("firm", "wood", "firm")):
        super().__init__(plan, apparatus)
        self.order, self.done, self.asked = list(order), 0, []

    def plan(self):
        return {"clicks": list(self.order)}, [{"event": "plan", "order": list(self.order)}]

    def restore(self, store, rows, events):
        self.done = len(rows)
        return None

    def next_attempt(self):
        if self.done >= len(self.order):
            return None
        return (self.done + 1, self.order[self.done]), 1

    def run_attempt(self, loop, trial, attempt):
        number, sample = trial
        shown = loop.present(sample, 0.5, status=lambda: {"trial": number}, text=self.texts["tap"],
                             hand=self.apparatus.sim_participant.plan("testing", number, attempt, 0.5))
        answer, contacts = loop.ask(self.texts["ask"], "choice", simulated=lambda: "2")
        self.asked.append(answer)
        return shown, answer, contacts

    def outcome(self, trial, attempt, result, subject):
        shown, answer, _ = result
        row = {"subject": subject, "trial": trial[0], "attempt": attempt, "sample": trial[1], "response": answer,
               "n_taps": shown.n_taps}
        return Outcome(traces=[("clicks", trial[0], attempt, shown.tap.trace)], row=row)

    def recorded(self, trial, attempt, result, row):
        self.done += 1
        return [Event({"event": "answered", "trial": trial[0]})]

    def status(self, result=None, row=None):
        return {"phase": "clicks", "trials_valid": self.done, "last_attempt": row}

    def done_status(self):
        return {"phase": "done", "awaiting_confirm": False, "message": "session complete"}

    def summary(self, rows, store, say):
        say(f"{len(rows)} trials")


@pytest.fixture(scope="module")
def apparatus():
    catalog = [s for s in load_catalog() if s.name in ("wood", "firm")]
    protocol = ProtocolConfig(tap_window_s=0.5, homing_after_s=0.2, homing_before_max_s=0.1)
    sp = SimulatedParticipant("L1", "few", 3, SimParticipantConfig(p_reject=0.0, p_overpower=0.0, p_hard_tap=0.0))
    app = Apparatus(SimDevice(seed=3).open(), catalog, protocol, sim_participant=sp)
    return SimpleNamespace(app=app, catalog=catalog, protocol=protocol)


def _session(tmp_path, apparatus, participant, ui):
    plan = SimpleNamespace(protocol=apparatus.protocol, catalog=apparatus.catalog)
    kind = Clicks(plan, apparatus.app)
    store = SessionStore(tmp_path, "L1")
    store.rows = kind.rows
    store.check()
    entries, events = kind.plan()
    store.create({"subject": "L1", "finished_at": None, **entries}, events=events)
    store.hold_trials()
    loop = SessionLoop(store=store, kind=kind, apparatus=apparatus.app, participant=participant, audio=SilentAudio(),
                       ui=ui, protocol=apparatus.protocol)
    return kind, store, loop


def test_every_attempt_is_written_in_order_traces_row_then_what_follows(tmp_path, apparatus, monkeypatch):
    ui = UiState()
    places, steps = [], []
    original = ui.set_operator
    monkeypatch.setattr(ui, "set_operator", lambda **f: (places.append(f["place"]) if "place" in f else None,
                                                           original(**f))[1])
    kind, store, loop = _session(tmp_path, apparatus, apparatus.app.sim_participant, ui)
    for name in ("write_trace", "append_trial", "log_event"):
        method = getattr(store, name)
        monkeypatch.setattr(store, name, lambda *a, _m=method, _n=name, **k: (steps.append(_n), _m(*a, **k))[1])
    loop.run()
    assert steps == ["write_trace", "append_trial", "log_event"] * 3
    rows = store.read_trials()
    assert [(r["trial"], r["sample"], r["response"]) for r in rows] == [(1, "firm", "2"), (2, "wood", "2"),
                                                                        (3, "firm", "2")]
    assert all(r["n_taps"] >= 1 for r in rows)
    assert sorted(p.name for p in store.traces_dir.iterdir()) == [f"clicks_t00{k}_a01.npz" for k in (1, 2, 3)]
    trace = np.load(store.traces_dir / "clicks_t002_a01.npz")
    assert str(trace["sample"]) == "wood" and len(trace["event_t_s"]) == rows[1]["n_taps"]
    assert [e["event"] for e in store.read_events()] == ["plan", "answered", "answered", "answered"]
    # a rendering goes on a placeholder, alternating; a real sample is placed as itself
    assert places == ["placeholder A", "real sample 'wood'", "placeholder A"]
    final = ui.snapshot("operator")
    assert final["message"] == "session complete" and final["link"] == "sim (no link)"
    assert final["audio"] == "none (sim session runs silently)"      # the silent audio's cue source
    assert ui.snapshot("subject")["message"] == "Done, thank you."
    store.release()


def test_a_persons_key_answers_while_the_stylus_is_held(tmp_path, apparatus):
    ui = UiState()
    person = SimpleNamespace(kind="keyboard", ui=ui)
    kind, store, loop = _session(tmp_path, apparatus, person, ui)
    answered = threading.Event()

    def operator_and_subject():
        for _ in range(3):
            ui.wait(lambda: ui.operator["awaiting_confirm"], 30)
            ui.operator_action("confirm")
            ui.wait(lambda: ui.subject["prompt"] == "choice", 30)
            subject = ui.snapshot("subject")
            assert ui.subject_key("1", subject["trial_id"])["accepted"]
        answered.set()

    helper = threading.Thread(target=operator_and_subject, daemon=True)
    helper.start()
    kind.order = ["firm"] * 3
    loop.run()
    helper.join(10)
    assert answered.is_set() and kind.asked == ["1", "1", "1"]
    assert [r["response"] for r in store.read_trials()] == ["1", "1", "1"]
    store.release()


def test_an_abort_stops_before_the_next_attempt_writing_nothing(tmp_path, apparatus):
    ui = UiState()
    kind, store, loop = _session(tmp_path, apparatus, apparatus.app.sim_participant, ui)
    ui.operator_action("abort")
    with pytest.raises(Aborted):
        loop.run()
    assert store.read_trials() == [] and not list(store.traces_dir.iterdir())
    store.release()
