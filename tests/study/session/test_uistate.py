"""The state the session and its views share (study.session.uistate), without the web server: keys bound to the
presentation they answer, the operator's confirm, pause and abort."""

import pytest

from study.session.uistate import CHOICE_HINT, KEY_HINT, Aborted, UiState


def test_a_key_counts_once_and_only_for_the_presentation_it_answers():
    ui = UiState()
    ui.set_subject("Rate it.", "rate", "testing:1:1")
    first = ui.snapshot("subject")["trial_id"]
    assert first.startswith("testing:1:1")
    assert ui.subject_key("9", first) == {**ui.snapshot("subject"), "accepted": False}
    assert ui.snapshot("subject")["hint"] == KEY_HINT and ui.rating() is None
    assert ui.subject_key("5", first)["accepted"] and ui.rating() == "5"
    again = ui.subject_key("6", first)
    assert not again["accepted"] and again["refused"] == "this trial's key was already taken" and ui.rating() == "5"
    ui.set_subject("Which one?", "choice")
    assert ui.rating() is None                                   # a new question clears the last answer
    stale = ui.subject_key("2", first)
    assert stale["refused"] == "not the current trial (a late or replayed key)" and ui.keys_refused == 1
    current = ui.snapshot("subject")["trial_id"]
    assert not ui.subject_key("5", current)["accepted"] and ui.snapshot("subject")["hint"] == CHOICE_HINT
    assert ui.subject_key("2", current)["accepted"] and ui.rating() == "2"


def test_familiarization_ends_with_enter_and_keys_are_refused_while_waiting():
    ui = UiState()
    ui.set_subject("Please wait.", "wait")
    wait_id = ui.snapshot("subject")["trial_id"]
    assert not ui.subject_key("3", wait_id)["accepted"] and ui.snapshot("subject")["hint"].startswith("No key")
    ui.set_subject("Tap on the wood.", "familiarization", "familiarization:1:1")
    assert ui.subject_key("Enter", ui.snapshot("subject")["trial_id"])["accepted"]
    assert ui.familiarization_ended()


def test_confirm_pause_and_abort():
    ui = UiState()
    assert ui.operator_action("confirm") == {"ok": False, "error": "nothing to confirm"}
    ui.request_confirm("placeholder A")
    assert ui.snapshot("operator")["awaiting_confirm"] and not ui.confirmed()
    ui.operator_action("pause")
    assert ui.operator_action("confirm") == {"ok": True}
    assert not ui.confirmed()                                   # confirmed, but paused: not yet
    ui.operator_action("resume")
    assert ui.confirmed() and ui.wait(ui.confirmed, 1.0)
    assert ui.operator_action("dance") == {"ok": False, "error": "unknown action 'dance'"}
    seq = ui.snapshot("operator")["seq"]
    ui.operator_action("abort")
    assert ui.snapshot("operator")["seq"] == seq + 1
    for call in (ui.confirmed, ui.rating, lambda: ui.wait(lambda: False, 1.0)):
        with pytest.raises(Aborted, match="the operator aborted the session"):
            call()


def test_operator_state_is_plain_json():
    ui = UiState()
    ui.set_operator(last_attempt={"incoming_velocity_mean_m_s": float("nan"), "velocities": (0.1, float("inf"))})
    last = ui.snapshot("operator")["last_attempt"]
    assert last == {"incoming_velocity_mean_m_s": None, "velocities": [0.1, None]}
