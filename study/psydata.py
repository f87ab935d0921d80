"""trials.csv of a psychophysics session (issue 34): one row per trial, in the contract's columns.

The subject folder, its lock, ``session.json``, ``schedule.jsonl`` and the trace files are the realism
study's (:class:`study.data.SessionStore`); only trials.csv's columns differ (:data:`PSY_COLUMNS`, docs/study.md
"Psychophysics sessions"). A row is appended, flushed and fsynced before the next trial starts; on ``--resume``
a last line torn by a crash is kept in ``trials.csv.torn`` and truncated away, as for the realism study.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os

from .data import crash_point, cut_torn_tail, mend_last_line

PSY_COLUMNS = (
    "subject", "trial", "attempt", "condition", "staircase", "intensity", "intensity_physical", "correct",
    "is_catch", "response", "target_interval", "sample_1", "sample_2", "n_taps_1", "n_taps_2",
    "incoming_velocity_mean_1_m_s", "incoming_velocity_mean_2_m_s", "penetration_mean_1_m", "penetration_mean_2_m",
    "sim_percept_1", "sim_percept_2", "started_at", "duration_s",
)
_INT = ("trial", "attempt", "correct", "is_catch", "target_interval", "n_taps_1", "n_taps_2")
_FLOAT = ("intensity", "intensity_physical", "incoming_velocity_mean_1_m_s", "incoming_velocity_mean_2_m_s",
          "penetration_mean_1_m", "penetration_mean_2_m", "sim_percept_1", "sim_percept_2", "duration_s")


def format_psy_row(row: dict) -> dict:
    """CSV strings of a trial row (floats by repr, NaN/None as empty, ints as ints)."""
    out = {}
    for key in PSY_COLUMNS:
        value = row[key]
        if key in _FLOAT:
            out[key] = "" if value is None or (isinstance(value, float) and math.isnan(value)) else repr(float(value))
        elif key in _INT:
            out[key] = str(int(value))
        else:
            out[key] = str(value)
    return out


def parse_psy_row(raw: dict, where: str) -> dict:
    """Inverse of :func:`format_psy_row`; a bad value raises ValueError naming ``where`` (file and line)."""
    row = dict(raw)
    try:
        for key in _INT:
            row[key] = int(raw[key])
        for key in _FLOAT:
            row[key] = float(raw[key]) if raw[key] != "" else math.nan
        if row["correct"] not in (0, 1) or row["is_catch"] not in (0, 1) or row["target_interval"] not in (1, 2):
            raise ValueError("correct/is_catch must be 0|1 and target_interval 1|2")
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{where}: bad value ({exc})") from None
    return row


def _whole_psy_row(head: bytes, last: bytes, where: str) -> bool:
    """Whether ``last`` (a line without its newline, after the lines ``head``) is a whole, valid row of a
    psychophysics session's trials.csv (or, with nothing before it, its header)."""
    try:
        header = next(csv.reader([head.split(b"\n", 1)[0].decode("utf-8")]), None) if head else None
        fields = list(csv.reader(io.StringIO(last.decode("utf-8") + "\n")))
        if header is None:
            return len(fields) == 1 and tuple(fields[0]) == PSY_COLUMNS
        if len(fields) != 1 or len(fields[0]) != len(header):
            return False
        parse_psy_row(dict(zip(header, fields[0])), where)
        return True
    except (UnicodeDecodeError, ValueError, csv.Error):
        return False


def read_psy_trials(store) -> list[dict]:
    """The trials on disk, in order (``store``: :class:`study.data.SessionStore` of the subject).

    A last line without its newline is completed when it is a whole, valid row; one that does not parse
    (torn by a crash) is copied to ``trials.csv.torn``, truncated away and named in a note.

    Raises
    ------
    ValueError
        A header that is not :data:`PSY_COLUMNS`, non-UTF-8 bytes or a bad value, naming file and line.
    """
    path = store.trials_path
    data = mend_last_line(path, path.read_bytes(), _whole_psy_row)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise ValueError(f"{path} line {line}: not UTF-8 text (byte {exc.start}); trials.csv is damaged") from None
    reader = csv.DictReader(io.StringIO(text))
    if tuple(reader.fieldnames or ()) != PSY_COLUMNS:
        raise ValueError(f"{path}: header {reader.fieldnames} is not a psychophysics session's "
                         f"{list(PSY_COLUMNS)}")
    rows = [parse_psy_row(raw, f"{path} line {i + 2}") for i, raw in enumerate(reader)]
    for i, row in enumerate(rows):
        if row["trial"] != i + 1:
            raise ValueError(f"{path} line {i + 2}: trial {row['trial']}, expected {i + 1} (trials are consecutive)")
    return rows


def append_psy_trial(store, row: dict) -> None:
    """Append one trial row to the subject's trials.csv, flush and fsync it (on disk when this returns)."""
    buf = io.StringIO()
    csv.DictWriter(buf, PSY_COLUMNS, lineterminator="\n").writerow(format_psy_row(row))
    store.append_trial_text(buf.getvalue())   # through the held file: a moved or replaced file stops the session
    crash_point(f"row written: trial {row['trial']}/{row['attempt']}")


def state_path(store):
    """``DATA/<subject>/staircase_state.jsonl``: one line per trial of an adaptive session."""
    return store.dir / "staircase_state.jsonl"


def append_state(store, line: dict) -> None:
    """Append one trial's staircase state (a JSON line), flush and fsync it."""
    with open(state_path(store), "a", encoding="utf-8") as fh:
        fh.write(json.dumps(line) + "\n")
        fh.flush()
        os.fsync(fh.fileno())
    crash_point(f"staircase state written: trial {line['trial']}")


def repair_states(store) -> int:
    """Count the whole state lines on disk (``--resume``); a last line torn by a crash is moved to
    ``staircase_state.jsonl.torn`` (the resumed session rewrites it from the trials), with a note.

    Returns
    -------
    int
        Whole lines (trials whose state is on disk).
    """
    path = state_path(store)
    if not path.exists():
        return 0
    data = path.read_bytes()
    lines = data.split(b"\n")
    whole = 0
    for line in lines[:-1]:
        try:
            json.loads(line)
        except ValueError:
            break
        whole += 1
    keep = b"".join(ln + b"\n" for ln in lines[:whole])
    if keep != data:
        cut_torn_tail(path, data, len(keep), whole + 1, then="it will be written again from trials.csv; kept it in")
    return whole
