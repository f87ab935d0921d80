"""The crash-safe store (study.session.store), on its own: rows written and read back, the one torn-line policy
for trials.csv and the JSON-lines files, the held trials.csv, a damaged file refused naming its line."""

import json

import pytest

from plumbing.studyfiles import FORCED_CHOICE, RATING_COLUMNS, STATE_JSONL, format_rating_row
from study.session.store import DataFileChanged, SessionStore


def row(**over):
    base = {"subject": "S", "phase": "testing", "trial": 3, "attempt": 2, "sample": "firm", "kind": "virtual",
            "rating": None, "rejected": True, "saturated": False, "overpowered": False, "valid": False, "n_taps": 2,
            "incoming_velocity_mean_m_s": 0.1, "penetration_mean_m": 0.002, "incoming_velocities_m_s": [0.09, 0.11],
            "penetration_depths_m": [0.0015, 0.0025], "started_at": "2026-01-01T00:00:00.000Z", "duration_s": 6.1}
    base.update(over)
    return base


def test_row_format(tmp_path):
    out = format_rating_row(row())
    assert tuple(out) == RATING_COLUMNS
    assert out["rating"] == "" and out["rejected"] == "true" and out["valid"] == "false"
    assert out["incoming_velocities_m_s"] == "0.09;0.11"
    assert format_rating_row(row(rating=6, rejected=False))["rating"] == "6"


def test_trials_appended_and_torn_last_line_dropped(tmp_path):
    store = SessionStore(tmp_path, "S01")
    store.check()
    store.create({"subject": "S01", "finished_at": None})
    store.append_trial(row(subject="S01", trial=1, attempt=1))
    store.append_trial(row(subject="S01", trial=2, attempt=1, rating=5, rejected=False, valid=True))
    with open(store.trials_path, "a") as fh:                 # a crash in the middle of a write
        fh.write("S01,testing,3,1,fi")
    rows = store.read_trials()
    assert [(r["trial"], r["rating"], r["valid"]) for r in rows] == [(1, None, False), (2, 5, True)]
    assert store.trials_path.read_text().endswith("\n")       # the torn line was truncated away
    store.append_trial(row(subject="S01", trial=3, attempt=1))
    assert len(store.read_trials()) == 3



def test_existing_subject_is_never_overwritten(tmp_path):
    store = SessionStore(tmp_path, "S01")
    store.check()
    store.create({"subject": "S01", "finished_at": None})
    store.append_trial(row())
    before = store.trials_path.read_bytes()
    with pytest.raises(ValueError, match="already has data.*--resume"):
        SessionStore(tmp_path, "S01").check()
    with pytest.raises(FileNotFoundError, match="no session to resume"):
        SessionStore(tmp_path, "S02", resume=True).check()
    assert store.trials_path.read_bytes() == before


def _store(tmp_path, subject="S01", rows=None) -> SessionStore:
    store = SessionStore(tmp_path, subject)
    if rows is not None:
        store.rows = rows
    store.check()
    store.create({"subject": subject, "finished_at": None}, events=[{"event": "plan"}])
    return store


def test_json_lines_are_durable_and_a_torn_last_line_is_kept_aside(tmp_path, capsys):
    store = _store(tmp_path)
    store.log_event({"event": "redraw", "trial": 2})
    store.append_json_line(STATE_JSONL, {"trial": 1}, "state written: trial 1")
    assert [e["event"] for e in store.read_events()] == ["plan", "redraw"]
    path = store.dir / STATE_JSONL
    with open(path, "ab") as fh:                        # a whole line that lost only its newline, then a torn one
        fh.write(b'{"trial": 2}')
    assert store.read_json_lines(STATE_JSONL) == [{"trial": 1}, {"trial": 2}]
    assert path.read_bytes().endswith(b"}\n") and not (store.dir / (STATE_JSONL + ".torn")).exists()
    with open(path, "ab") as fh:
        fh.write(b'{"trial": 3, "sta')
    assert store.read_json_lines(STATE_JSONL, then="it is written again; kept it in") == [{"trial": 1}, {"trial": 2}]
    assert (store.dir / (STATE_JSONL + ".torn")).read_bytes() == b'{"trial": 3, "sta\n'
    note = capsys.readouterr().out
    assert f"{path} line 3 was torn by a crash" in note and "it is written again; kept it in" in note
    store.append_json_line(STATE_JSONL, {"trial": 3}, "state written: trial 3")   # appended after whole lines only
    assert [x["trial"] for x in store.read_json_lines(STATE_JSONL)] == [1, 2, 3]


def test_a_damaged_whole_json_line_is_an_error_naming_it(tmp_path):
    store = _store(tmp_path)
    with open(store.schedule_path, "a") as fh:
        fh.write("not json\n")
    with pytest.raises(ValueError, match=rf"{store.schedule_path} line 2: not a JSON object .*the file is damaged"):
        store.read_events()


def test_nothing_is_written_once_trials_csv_was_replaced(tmp_path):
    store = _store(tmp_path)
    store.hold_trials()
    store.append_trial(row(subject="S01", trial=1, attempt=1))
    other = store.trials_path.with_name("edited.csv")
    other.write_bytes(store.trials_path.read_bytes())
    other.replace(store.trials_path)
    events = store.schedule_path.read_bytes()
    for write in (lambda: store.log_event({"event": "redraw"}), lambda: store.append_trial(row(subject="S01")),
                  lambda: store.write_trace("testing", 1, 1, {"t_s": [0.0]})):
        with pytest.raises(DataFileChanged, match="was replaced by another file while the session ran"):
            write()
    assert store.schedule_path.read_bytes() == events and not list(store.traces_dir.iterdir())
    store.release()


def test_a_forced_choice_store_writes_its_own_rows(tmp_path):
    store = _store(tmp_path, rows=FORCED_CHOICE)
    assert store.trials_path.read_text().splitlines()[0].split(",")[:3] == ["subject", "trial", "attempt"]
    row_ = {"subject": "S01", "trial": 1, "attempt": 1, "condition": "firm", "staircase": "", "intensity": 500.0,
            "intensity_physical": 500.0, "correct": 1, "is_catch": 0, "response": "2", "target_interval": 2,
            "sample_1": "a", "sample_2": "b", "n_taps_1": 2, "n_taps_2": 3, "incoming_velocity_mean_1_m_s": 0.1,
            "incoming_velocity_mean_2_m_s": 0.1, "penetration_mean_1_m": 0.001, "penetration_mean_2_m": 0.001,
            "sim_percept_1": float("nan"), "sim_percept_2": float("nan"), "started_at": "2026-01-01T00:00:00Z",
            "duration_s": 3.0}
    store.append_trial(row_)
    store.append_trial({**row_, "trial": 2})
    assert [(r["trial"], r["correct"]) for r in store.read_trials()] == [(1, 1), (2, 1)]
    with open(store.trials_path, "a") as fh:
        fh.write("S01,3," + "x" * 200_000 + "\n")
    with pytest.raises(ValueError) as exc:
        store.read_trials()
    assert str(exc.value).startswith(f"{store.trials_path} line 4: not CSV (field larger than field limit")
    assert 'Repair (docs/study.md, "A damaged trials.csv")' in str(exc.value)


def test_session_json_rewritten_whole(tmp_path):
    store = _store(tmp_path)
    store.session["note"] = "x" * 10_000
    store.write_session()
    assert json.loads(store.session_path.read_text())["note"] == "x" * 10_000
    store.finish()
    assert store.load_session()["finished_at"]
    assert not list(store.dir.glob("*.tmp"))
