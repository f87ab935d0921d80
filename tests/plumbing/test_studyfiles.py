"""plumbing.studyfiles: the study's files defined once (rows written and read back, the readers' errors)."""

import csv
import math

import pytest

from plumbing.studyfiles import (FORCED_CHOICE, FORCED_CHOICE_COLUMNS, RATING, RATING_COLUMNS, RATING_CORE_COLUMNS,
                                 DamagedRow, is_study_folder, is_subject_folder, parse_trials, read_session_json,
                                 study_data_at)

RATING_ROW = {"subject": "S01", "phase": "testing", "trial": 1, "attempt": 1, "sample": "firm", "kind": "virtual",
              "rating": 6, "rejected": False, "saturated": False, "overpowered": False, "valid": True, "n_taps": 2,
              "incoming_velocity_mean_m_s": 0.1, "penetration_mean_m": 0.002, "incoming_velocities_m_s": [0.09, 0.11],
              "penetration_depths_m": [0.0015, 0.0025], "started_at": "2026-01-01T00:00:00.000Z", "duration_s": 6.1}
FC_ROW = {"subject": "S01", "trial": 1, "attempt": 2, "condition": "firm", "staircase": "A", "intensity": 2.5,
          "intensity_physical": 316.2, "correct": 1, "is_catch": 0, "response": "2", "target_interval": 2,
          "sample_1": "a", "sample_2": "b", "n_taps_1": 3, "n_taps_2": 2, "incoming_velocity_mean_1_m_s": 0.1,
          "incoming_velocity_mean_2_m_s": 0.12, "penetration_mean_1_m": 0.001, "penetration_mean_2_m": math.nan,
          "sim_percept_1": math.nan, "sim_percept_2": 1.5, "started_at": "2026-01-01T00:00:00.000Z",
          "duration_s": 9.0}


@pytest.mark.parametrize("fmt, row", [(RATING, RATING_ROW), (FORCED_CHOICE, FC_ROW)])
def test_a_row_written_reads_back_the_same(fmt, row):
    data = (fmt.header_line() + fmt.line(row)).encode()
    rows, header = parse_trials(fmt, data, "t.csv", "S01")
    assert header == fmt.columns and len(rows) == 1
    back = rows[0]
    typed = ("subject", "phase", "trial", "attempt", "sample", "kind", "rating", "rejected", "saturated",
             "overpowered", "valid", "n_taps")     # the rating format checks the others and keeps them as written
    for key, value in row.items():
        if fmt is RATING and key not in typed:
            assert back[key] == fmt.format(row)[key], key
            continue
        if isinstance(value, float) and math.isnan(value):
            assert math.isnan(back[key]), key
        elif key in ("response", "staircase"):
            assert back[key] == str(value)
        else:
            assert back[key] == value, key
    assert fmt.whole_last_row(fmt.header_line().encode(), fmt.line(row).rstrip("\n").encode(), "t.csv line 2")
    assert not fmt.whole_last_row(fmt.header_line().encode(), fmt.line(row)[:40].encode(), "t.csv line 2")


def test_older_rating_files_without_the_familiarization_flag_are_read():
    data = (",".join(RATING_CORE_COLUMNS) + "\n" + RATING.line(RATING_ROW, RATING_CORE_COLUMNS)).encode()
    rows, header = parse_trials(RATING, data, "t.csv")
    assert header == RATING_CORE_COLUMNS and rows[0]["ends_familiarization"] is None
    assert RATING_COLUMNS[:-1] == RATING_CORE_COLUMNS


@pytest.mark.parametrize("tail, says", [
    ("S01,2," + "x" * 200_000 + "\n", "line 3: not CSV (field larger than field limit (131072))"),
    ("S01,3,1" + ",0" * (len(FORCED_CHOICE_COLUMNS) - 3) + "\n", "line 3: bad value"),
    (FORCED_CHOICE.line({**FC_ROW, "trial": 1}), "line 3: trial 1 after trial 1 (trials are in order, one row each)"),
    (FORCED_CHOICE.line({**FC_ROW, "trial": 2, "subject": "S02"}), "line 3: subject='S02', but the session is 'S01'"),
])
def test_a_damaged_row_is_one_error_naming_the_line(tail, says):
    data = (FORCED_CHOICE.header_line() + FORCED_CHOICE.line(FC_ROW) + tail).encode()
    with pytest.raises(DamagedRow) as exc:
        parse_trials(FORCED_CHOICE, data, "t.csv", "S01")
    assert str(exc.value).startswith("t.csv line 3: ") and says in str(exc.value)


def test_a_header_of_the_other_kind_is_refused():
    with pytest.raises(ValueError, match=r"t.csv: header \[.*\] is not the forced-choice session's"):
        parse_trials(FORCED_CHOICE, RATING.header_line().encode(), "t.csv")


@pytest.mark.parametrize("content, says", [
    (b"\xff\xfe\x00binary", ":1: not UTF-8 text (invalid start byte at byte 0)"),
    (b'{"subject": "B01", "seed": ', ":1: truncated JSON (Expecting value, column 28); session.json is damaged"),
    (b'{"subject": "B01",\n "seed" 3}', ":2: not valid JSON (Expecting ':' delimiter, column 9)"),
    (b"  \n", ": empty file; session.json is damaged"),
    (b"[1, 2]", ":1: session.json must hold a JSON object, found list"),
])
def test_session_json_errors_name_the_file_and_line(tmp_path, content, says):
    path = tmp_path / "session.json"
    path.write_bytes(content)
    with pytest.raises(ValueError) as exc:
        read_session_json(path)
    assert str(exc.value) == f"{path}{says}"


def test_a_missing_or_folder_session_json(tmp_path):
    with pytest.raises(FileNotFoundError, match="session.json is missing"):
        read_session_json(tmp_path / "session.json")
    (tmp_path / "session.json").mkdir()
    with pytest.raises(ValueError, match="is a directory, expected a file"):
        read_session_json(tmp_path / "session.json")
    assert read_session_json(_write(tmp_path / "ok.json", '{"subject": "S"}')) == {"subject": "S"}


def _write(path, text):
    path.write_text(text)
    return path


@pytest.mark.parametrize("fmt, row, names", [
    (RATING, RATING_ROW, {"sample": "=HYPERLINK(\"http://e.example\")"}),
    (FORCED_CHOICE, FC_ROW, {"condition": "+cond", "staircase": "@A", "sample_1": "-x", "sample_2": "'quoted"}),
])
def test_names_a_spreadsheet_would_run_are_quoted_and_read_back(fmt, row, names):
    """A name beginning with = + - @ (or a quote) is written with a quote first, and read back as named."""
    row = {**row, **names}
    line = fmt.line(row)
    cells = next(csv.reader([line]))
    assert all(cells[fmt.columns.index(k)] == "'" + v for k, v in names.items())
    rows, _ = parse_trials(fmt, (fmt.header_line() + line).encode(), "t.csv", "S01")
    assert all(rows[0][k] == v for k, v in names.items())


# -- where study data lives -------------------------------------------------------------------------------------

@pytest.mark.parametrize("files, subject", [
    (("session.json", "trials.csv"), True),
    (("session.json", "schedule.jsonl"), True),
    ((".lock", "trials.csv"), True),
    (("session.json",), False),            # a folder that merely holds a session.json
    (("trials.csv",), False),
    ((".lock",), False),
    ((), False),
])
def test_a_subject_folder_is_told_by_its_files(tmp_path, files, subject):
    # one level down: tmp_path's parent holds every test's folder, and must not become a study folder
    folder = tmp_path / "study" / "S01"
    folder.mkdir(parents=True)
    for name in files:
        (folder / name).write_text("x", encoding="utf-8")
    assert is_subject_folder(folder) is subject
    assert is_subject_folder(str(folder)) is subject
    assert is_study_folder(folder.parent) is subject


def test_a_folder_named_like_the_files_is_not_a_subject(tmp_path):
    folder = tmp_path / "S01"
    (folder / "session.json").mkdir(parents=True)
    (folder / "trials.csv").write_text("x", encoding="utf-8")
    assert not is_subject_folder(folder)
    (folder / ".lock").mkdir()
    assert not is_subject_folder(folder)


def test_a_study_folder_is_found_among_many_folders_and_up_the_tree(tmp_path):
    study = tmp_path / "study"
    for k in range(300):                     # many other folders beside the one subject
        (study / f"other{k:03d}").mkdir(parents=True)
    (study / ".hidden").mkdir()
    (study / ".hidden" / "session.json").write_text("{}", encoding="utf-8")
    (study / ".hidden" / "trials.csv").write_text("", encoding="utf-8")
    assert not is_study_folder(study)       # hidden folders are not subjects
    subject = study / "S07"
    subject.mkdir()
    (subject / "session.json").write_text("{}", encoding="utf-8")
    (subject / "trials.csv").write_text("", encoding="utf-8")
    assert is_study_folder(study)
    assert not is_study_folder(study, limit=0)
    assert not is_study_folder(tmp_path / "missing")
    assert study_data_at(study / "S07" / "figures") == (subject, "subject folder")
    assert study_data_at(study / "new-run") == (study, "study folder")
    assert study_data_at(tmp_path / "elsewhere" / "run") is None
