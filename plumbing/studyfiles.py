"""The study's files, defined once: what ``study`` writes and ``analysis`` reads (format: docs/study.md).

One folder per subject::

    DATA/<subject>/session.json            subject details and settings (read_session_json)
    DATA/<subject>/trials.csv              the rating study: one row per attempt (RATING);
                                           a forced-choice session: one row per trial (FORCED_CHOICE);
                                           method of adjustment and magnitude estimation: one row per trial
                                           (ADJUSTMENT, MAGNITUDE)
    DATA/<subject>/schedule.jsonl          planned orders, redraws, invalid attempts, resumes (a JSON object
                                           per line)
    DATA/<subject>/staircase_state.jsonl   an adaptive forced-choice session: each trial's staircase state
    DATA/<subject>/traces/<phase>_t<trial:03d>_a<attempt:02d>.npz

and the counterbalancing design a lab writes before the sessions (``python -m study design``): ``design.csv``
(DESIGN_COLUMNS: the order of conditions each participant gets).

Here are the columns and their types, the subject details' choices, the row formats (a row's values as
written and read back, every value checked) and the readers of ``session.json`` and of a ``trials.csv``'s
text. Light on purpose (the standard library only): ``python -m study run --help`` lists the choices.
"""

from __future__ import annotations

import csv
import datetime as _dt
import io
import json
import math
import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from .textsafe import csv_text, read_cell

SESSION_JSON = "session.json"
TRIALS_CSV = "trials.csv"
SCHEDULE_JSONL = "schedule.jsonl"
STATE_JSONL = "staircase_state.jsonl"
TRACES_DIR = "traces"

# -- subject details (section 4.5.3's form) ------------------------------------------------------------------
GENDERS = ("female", "male", "other", "unspecified")
HANDEDNESS = ("right", "left", "ambidextrous", "unspecified")
#: prior haptic experience: never, a few times, regularly
EXPERIENCE = ("none", "few", "regular")
#: spellings of the form accepted for the stored codes
EXPERIENCE_ALIASES = {"never": "none", "a few times": "few", "regularly": "regular"}

# -- the rating study's trials.csv -------------------------------------------------------------------------
PHASES = ("familiarization", "demonstration", "testing")
KINDS = ("real", "virtual")
RATING_MIN, RATING_MAX = 1, 7
RATING_COLUMNS = (
    "subject", "phase", "trial", "attempt", "sample", "kind", "rating", "rejected", "saturated", "overpowered",
    "valid", "n_taps", "incoming_velocity_mean_m_s", "penetration_mean_m", "incoming_velocities_m_s",
    "penetration_depths_m", "started_at", "duration_s", "ends_familiarization",
)
#: every column but ``ends_familiarization``: what every rating trials.csv holds (the whole header of the
#: sessions recorded before the flag existed; their familiarization's end is in schedule.jsonl)
RATING_CORE_COLUMNS = RATING_COLUMNS[:-1]
BOOL_COLUMNS = ("rejected", "saturated", "overpowered", "valid")
INT_COLUMNS = ("trial", "attempt", "n_taps")
FLOAT_COLUMNS = ("incoming_velocity_mean_m_s", "penetration_mean_m", "duration_s")
#: ';'-joined lists, one value per tap
LIST_COLUMNS = ("incoming_velocities_m_s", "penetration_depths_m")

# -- a forced-choice session's trials.csv -----------------------------------------------------------------
FORCED_CHOICE_COLUMNS = (
    "subject", "trial", "attempt", "condition", "staircase", "intensity", "intensity_physical", "correct",
    "is_catch", "response", "target_interval", "sample_1", "sample_2", "n_taps_1", "n_taps_2",
    "incoming_velocity_mean_1_m_s", "incoming_velocity_mean_2_m_s", "penetration_mean_1_m", "penetration_mean_2_m",
    "sim_percept_1", "sim_percept_2", "started_at", "duration_s",
)
FORCED_CHOICE_INT_COLUMNS = ("trial", "attempt", "correct", "is_catch", "target_interval", "n_taps_1", "n_taps_2")
FORCED_CHOICE_FLOAT_COLUMNS = ("intensity", "intensity_physical", "incoming_velocity_mean_1_m_s",
                               "incoming_velocity_mean_2_m_s", "penetration_mean_1_m", "penetration_mean_2_m",
                               "sim_percept_1", "sim_percept_2", "duration_s")
#: the columns a psychometric fit reads (``analysis psychometric``; a CSV from any software needs the first two)
FIT_COLUMNS = ("intensity", "correct")
FIT_OPTIONAL_COLUMNS = ("subject", "condition", "staircase", "trial", "is_catch")
#: the columns that hold names from users (subject ids, catalog samples, conditions, staircase labels): written
#: through :func:`plumbing.textsafe.csv_text` (never a spreadsheet formula) and read back with ``read_cell``
NAME_TEXT_COLUMNS = ("subject", "sample", "condition", "staircase", "sample_1", "sample_2")


# -- where study data lives ---------------------------------------------------------------------------------

#: the subject lock's file name (``DATA/<subject>/.lock``)
LOCK_NAME = ".lock"
#: children of a folder looked at to tell whether it is a study folder (a folder of subject folders); a folder
#: with more entries is judged by its first ones (a study folder's first entries are its subjects)
STUDY_SCAN_LIMIT = 5000


def _is_file(path: str) -> bool:
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except (OSError, ValueError):
        return False


def _exists(path: str) -> bool:
    try:
        os.stat(path)
    except (OSError, ValueError):
        return False
    return True


def is_subject_folder(path) -> bool:
    """True when ``path`` is a subject's folder of a study (``session.json`` with ``trials.csv`` or
    ``schedule.jsonl`` beside it, or a subject lock with ``trials.csv``): data no other command may write into."""
    # plain os.stat on strings: every output folder's check asks this of each folder beside its parents
    # (hundreds in a home or a temporary folder), where pathlib's objects cost more than the system calls
    p = os.fspath(path)
    if _is_file(os.path.join(p, SESSION_JSON)):
        return _exists(os.path.join(p, TRIALS_CSV)) or _exists(os.path.join(p, SCHEDULE_JSONL))
    return _is_file(os.path.join(p, LOCK_NAME)) and _is_file(os.path.join(p, TRIALS_CSV))


def is_study_folder(path, limit: int = STUDY_SCAN_LIMIT) -> bool:
    """True when ``path`` holds a subject folder (:func:`is_subject_folder`) among its first ``limit`` entries:
    a study's data folder (``study run --out DATA``)."""
    try:
        with os.scandir(path) as entries:
            for n, entry in enumerate(entries):
                if n >= limit:
                    return False
                try:
                    is_dir = entry.is_dir(follow_symlinks=False)
                except OSError:
                    continue
                if is_dir and not entry.name.startswith(".") and is_subject_folder(entry.path):
                    return True
    except OSError:
        return False
    return False


def study_data_at(path) -> tuple[Path, str] | None:
    """The study data ``path`` is or lies inside: ``(folder, "subject folder" | "study folder")``, or None.

    ``path`` itself, or any folder above it, being a subject folder or a study folder counts: an output written
    there would sit among, or replace, a study's records.
    """
    p = Path(os.path.abspath(path))
    try:
        p = p.resolve()
    except (OSError, RuntimeError):
        pass
    for k, folder in enumerate([p, *p.parents]):
        if k == 0 and not folder.is_dir():
            continue
        if is_subject_folder(folder):
            return folder, "subject folder"
        if is_study_folder(folder):
            return folder, "study folder"
    return None


def study_data_within(path, limit: int = 200_000) -> Path | None:
    """The first subject folder at or below the folder ``path`` (None if there is none among its first
    ``limit`` folders; a folder with more is reported as itself, since it cannot be vouched for)."""
    root = Path(path)
    seen = 0
    for folder, dirs, _files in os.walk(root):
        seen += 1
        if is_subject_folder(folder):
            return Path(folder)
        if seen >= limit:
            return root
    return None


# -- reading session.json ------------------------------------------------------------------------------------

def read_file_text(path, encoding: str = "utf-8") -> str:
    """The text of a subject's file; a missing file, a directory in its place, an unreadable or non-UTF-8 file
    give one error naming the file (and the line of a bad byte).

    Raises
    ------
    FileNotFoundError
        ``"<path> is missing (every subject folder needs session.json and trials.csv)"``.
    ValueError
        ``"<path>: is a directory, expected a file"``, ``"<path>: cannot be read (...)"``,
        ``"<path>:<line>: not UTF-8 text (<reason> at byte <n>)"``.
    """
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except FileNotFoundError:
        raise FileNotFoundError(f"{path} is missing (every subject folder needs {SESSION_JSON} and "
                                f"{TRIALS_CSV})") from None
    except IsADirectoryError:
        raise ValueError(f"{path}: is a directory, expected a file") from None
    except OSError as exc:
        raise ValueError(f"{path}: cannot be read ({exc.strerror})") from None
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise ValueError(f"{path}:{line}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def read_session_json(path) -> dict:
    """Read one ``session.json`` (the one reader: the study on ``--resume``, the analysis' loaders).

    Returns
    -------
    dict
        The JSON object as written (the readers check the keys they use).

    Raises
    ------
    FileNotFoundError, ValueError
        One line naming the file and, where there is one, the line: not UTF-8, empty, truncated or not valid
        JSON, not an object.
    """
    text = read_file_text(path)
    if not text.strip():
        raise ValueError(f"{path}: empty file; {SESSION_JSON} is damaged")
    try:
        raw = json.loads(text)
    except RecursionError:   # nested 10^5 deep: one line, not a traceback
        raise ValueError(f"{path}: not valid JSON here (nested too deeply); {SESSION_JSON} is damaged") from None
    except json.JSONDecodeError as exc:
        if exc.pos >= len(text.rstrip()):
            raise ValueError(f"{path}:{exc.lineno}: truncated JSON ({exc.msg}, column {exc.colno}); "
                             f"{SESSION_JSON} is damaged") from None
        raise ValueError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg}, column {exc.colno})") from None
    if not isinstance(raw, dict):
        raise ValueError(f"{path}:1: {SESSION_JSON} must hold a JSON object, found {type(raw).__name__}")
    return raw


# -- the row formats ---------------------------------------------------------------------------------------

def _fmt_bool(value: bool) -> str:
    return "true" if value else "false"


def _fmt_float(value) -> str:
    return "" if value is None or value != value else repr(float(value))


def format_rating_row(row: dict) -> dict:
    """A rating study's attempt as CSV strings (lists ';'-joined, booleans true|false, rating empty if None)."""
    out = {}
    for key in RATING_COLUMNS:
        value = row.get(key) if key == "ends_familiarization" else row[key]
        if key in BOOL_COLUMNS:
            out[key] = _fmt_bool(value)
        elif key in LIST_COLUMNS:
            out[key] = ";".join(repr(float(v)) for v in value)
        elif key in FLOAT_COLUMNS:
            out[key] = _fmt_float(value)
        elif key == "rating":
            out[key] = "" if value is None else str(int(value))
        elif key == "ends_familiarization":
            out[key] = _fmt_bool(bool(row.get(key, False)))
        elif key in NAME_TEXT_COLUMNS:
            out[key] = csv_text(str(value))
        else:
            out[key] = str(value)
    return out


def _number(text: str, key: str, empty_ok: bool) -> float | None:
    """A finite number >= 0 written by :func:`format_rating_row` (``None`` for an empty cell when ``empty_ok``)."""
    if text == "" and empty_ok:
        return None
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{key}={text!r} is not a number") from None
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{key}={text!r} must be a finite number >= 0")
    return value


def _check_rating_values(raw: dict, row: dict) -> None:
    """Ranges and consistency of one parsed row (what :func:`format_rating_row` can write); ValueError otherwise."""
    if row["phase"] not in PHASES:
        raise ValueError(f"phase={raw['phase']!r} is not one of {'|'.join(PHASES)}")
    if row["kind"] not in KINDS:
        raise ValueError(f"kind={raw['kind']!r} is not one of {'|'.join(KINDS)}")
    if not row["sample"]:
        raise ValueError("sample is empty")
    for key, low in (("trial", 1), ("attempt", 1), ("n_taps", 0)):
        if row[key] < low:
            raise ValueError(f"{key}={raw[key]!r} must be >= {low}")
    rating = row["rating"]
    if rating is not None and not RATING_MIN <= rating <= RATING_MAX:
        raise ValueError(f"rating={raw['rating']!r} is not {RATING_MIN}-{RATING_MAX} (or empty)")
    if rating is not None and (row["rejected"] or row["phase"] == "familiarization"):
        raise ValueError(f"rating={raw['rating']!r} on a {'rejected' if row['rejected'] else 'familiarization'} "
                         "attempt, which has none")
    if row["valid"] and (row["saturated"] or row["overpowered"] or row["rejected"]):
        raise ValueError("valid=true on an attempt marked rejected, saturated or overpowered")
    if row["valid"] and row["phase"] != "familiarization" and (rating is None or not row["n_taps"]):
        raise ValueError("valid=true on a rated phase's attempt without a rating or without taps")
    if row["ends_familiarization"] and row["phase"] != "familiarization":
        raise ValueError(f"ends_familiarization=true on a {row['phase']} attempt")
    for key in ("incoming_velocity_mean_m_s", "penetration_mean_m", "duration_s"):
        _number(raw[key], key, empty_ok=True)
    for key in LIST_COLUMNS:
        values = [_number(x, key, empty_ok=False) for x in raw[key].split(";")] if raw[key] else []
        if len(values) != row["n_taps"]:
            raise ValueError(f"{key} lists {len(values)} values but n_taps={row['n_taps']}")
    try:
        _dt.datetime.fromisoformat(raw["started_at"])
    except (TypeError, ValueError):
        raise ValueError(f"started_at={raw['started_at']!r} is not an ISO 8601 time") from None


def _names_read(raw: dict) -> dict:
    """``raw`` with its name columns as they were named (the quote :func:`csv_text` may have put first, dropped)."""
    row = dict(raw)
    for key in NAME_TEXT_COLUMNS:
        if isinstance(row.get(key), str):
            row[key] = read_cell(row[key])
    return row


def _check_field_count(raw: dict, where: str) -> None:
    if None in raw:  # csv.DictReader puts the fields beyond the header under the key None
        raise ValueError(f"{where}: {len(raw) - 1 + len(raw[None])} fields, the header has {len(raw) - 1}")
    if any(value is None for value in raw.values()):  # ... and fills a short row's missing fields with None
        n = sum(value is not None for value in raw.values())
        raise ValueError(f"{where}: {n} fields, the header has {len(raw)}")


def parse_rating_row(raw: dict, where: str) -> dict:
    """Inverse of :func:`format_rating_row`, checking every field (count, type, range, consistency: what the
    runner can write); errors name ``where`` (file and line)."""
    _check_field_count(raw, where)
    row = _names_read(raw)
    row.setdefault("ends_familiarization", None)  # an older file: the transition is in schedule.jsonl
    try:
        if row["ends_familiarization"] is not None:
            if raw["ends_familiarization"] not in ("true", "false"):
                raise ValueError(f"ends_familiarization={raw['ends_familiarization']!r} is not true|false")
            row["ends_familiarization"] = raw["ends_familiarization"] == "true"
        for key in BOOL_COLUMNS:
            if raw[key] not in ("true", "false"):
                raise ValueError(f"{key}={raw[key]!r} is not true|false")
            row[key] = raw[key] == "true"
        row["trial"] = int(raw["trial"])
        row["attempt"] = int(raw["attempt"])
        row["rating"] = int(raw["rating"]) if raw["rating"] else None
        row["n_taps"] = int(raw["n_taps"])
        _check_rating_values(raw, row)
    except (KeyError, ValueError) as exc:
        raise ValueError(f"{where}: bad value ({exc})") from None
    return row


def _rating_sequence(row: dict, where: str, state: dict) -> None:
    """The row continues the file's sequence: phases in order (familiarization, demonstration, testing),
    each ``(phase, trial, attempt)`` once, and a trial's attempts numbered 1, 2, ... as they were run."""
    seen, attempts = state.setdefault("seen", set()), state.setdefault("attempts", {})
    phase_at = state.get("phase_at", 0)
    key = (row["phase"], row["trial"], row["attempt"])
    if key in seen:
        raise ValueError(f"{where}: {row['phase']} trial {row['trial']} attempt {row['attempt']} is recorded twice")
    if PHASES.index(row["phase"]) < phase_at:
        raise ValueError(f"{where}: a {row['phase']} attempt after the {PHASES[phase_at]} phase began")
    expected = attempts.get(key[:2], 0) + 1
    if row["attempt"] != expected:
        raise ValueError(f"{where}: {row['phase']} trial {row['trial']} attempt {row['attempt']}, expected attempt "
                         f"{expected} (attempts are numbered 1, 2, ... as they run)")
    seen.add(key)
    attempts[key[:2]] = expected
    state["phase_at"] = PHASES.index(row["phase"])


def format_forced_choice_row(row: dict) -> dict:
    """A forced-choice trial as CSV strings (floats by repr, NaN/None as empty, ints as ints)."""
    out = {}
    for key in FORCED_CHOICE_COLUMNS:
        value = row[key]
        if key in FORCED_CHOICE_FLOAT_COLUMNS:
            out[key] = "" if value is None or (isinstance(value, float) and math.isnan(value)) else repr(float(value))
        elif key in FORCED_CHOICE_INT_COLUMNS:
            out[key] = str(int(value))
        elif key in NAME_TEXT_COLUMNS:
            out[key] = csv_text(str(value))
        else:
            out[key] = str(value)
    return out


#: what a forced-choice row's answer may be: the interval chosen (an answer "x" rejects the trial: no row)
RESPONSES = ("1", "2")


def _finite(raw: dict, key: str, low: float | None = 0.0, empty_ok: bool = False) -> float:
    """A float column's value: finite (and >= ``low``), or NaN for an empty cell when ``empty_ok``."""
    text = raw[key]
    if text == "" and empty_ok:
        return math.nan
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{key}={text!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"{key}={text!r} must be a finite number")
    if low is not None and value < low:
        raise ValueError(f"{key}={text!r} must be >= {low:g}")
    return value


def parse_forced_choice_row(raw: dict, where: str) -> dict:
    """Inverse of :func:`format_forced_choice_row`, checking every field as the rating study's rows are checked:
    the count, each type and range, finite numbers, and the row's own consistency (``correct`` is whether
    ``response`` names ``target_interval``; both intervals tapped). What only the session's plan can tell
    (intensities, samples, attempts against schedule.jsonl) the experiment kind checks on ``--resume``.

    Raises
    ------
    ValueError
        ``"<where>: bad value (<what>)"``.
    """
    _check_field_count(raw, where)
    row = _names_read(raw)
    try:
        for key in FORCED_CHOICE_INT_COLUMNS:
            text = raw[key]
            if not text.strip().lstrip("+-").isdigit():
                raise ValueError(f"{key}={text!r} is not a whole number")
            row[key] = int(text)
        for key, low in (("trial", 1), ("attempt", 1), ("n_taps_1", 1), ("n_taps_2", 1)):
            if row[key] < low:
                raise ValueError(f"{key}={raw[key]!r} must be >= {low}")
        if row["correct"] not in (0, 1) or row["is_catch"] not in (0, 1) or row["target_interval"] not in (1, 2):
            raise ValueError("correct/is_catch must be 0|1 and target_interval 1|2")
        if raw["response"] not in RESPONSES:
            raise ValueError(f"response={raw['response']!r} is not one of {'|'.join(RESPONSES)}")
        if row["correct"] != int(raw["response"] == str(row["target_interval"])):
            raise ValueError(f"correct={raw['correct']!r} contradicts response={raw['response']!r} with "
                             f"target_interval={raw['target_interval']!r}")
        for key in ("subject", "condition", "sample_1", "sample_2"):
            if not row[key]:
                raise ValueError(f"{key} is empty")
        row["intensity"] = _finite(raw, "intensity", low=None)
        row["intensity_physical"] = _finite(raw, "intensity_physical")
        for key in ("incoming_velocity_mean_1_m_s", "incoming_velocity_mean_2_m_s", "penetration_mean_1_m",
                    "penetration_mean_2_m"):   # empty: not measured
            row[key] = _finite(raw, key, empty_ok=True)
        row["duration_s"] = _finite(raw, "duration_s")
        for key in ("sim_percept_1", "sim_percept_2"):   # empty for a person
            row[key] = _finite(raw, key, low=None, empty_ok=True)
        try:
            _dt.datetime.fromisoformat(raw["started_at"].replace("Z", "+00:00"))
        except (TypeError, ValueError):
            raise ValueError(f"started_at={raw['started_at']!r} is not an ISO 8601 time") from None
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{where}: bad value ({exc})") from None
    return row


def _forced_choice_sequence(row: dict, where: str, state: dict) -> None:
    """Trials in order, one row each (an invalid attempt is in schedule.jsonl, not here; a trial recorded there
    as not renderable has no row, so numbers may skip it: the experiment kind checks the gaps)."""
    last = state.get("trials", 0)
    if row["trial"] <= last:
        raise ValueError(f"{where}: trial {row['trial']} after trial {last} (trials are in order, one row each)")
    state["trials"] = row["trial"]


@dataclass(frozen=True)
class RowFormat:
    """One kind of trials.csv: its columns, the headers a file may have, a row written and read back.

    Attributes
    ----------
    what : str
        What the file records, for messages ("rating study", "forced-choice session").
    columns : tuple of str
        The header a new file gets.
    headers : tuple of tuple
        Every header a file may have (``columns`` and those of older versions).
    format : callable
        ``format(row) -> dict`` of CSV strings (:func:`format_rating_row`, ...).
    parse : callable
        ``parse(raw, where) -> row``, every value checked; ValueError naming ``where``.
    follows : callable
        ``follows(row, where, state)``: the row continues the file (``state``, a dict, carries what came before).
    """

    what: str
    columns: tuple
    headers: tuple
    format: Callable[[dict], dict]
    parse: Callable[[dict, str], dict]
    follows: Callable[[dict, str, dict], None]

    def line(self, row: dict, columns: tuple | None = None) -> str:
        """``row`` as one CSV line (with its newline) under ``columns`` (default: :attr:`columns`)."""
        buf = io.StringIO()
        csv.DictWriter(buf, columns or self.columns, lineterminator="\n", extrasaction="ignore").writerow(
            self.format(row))
        return buf.getvalue()

    def header_line(self) -> str:
        """The header of a new file, with its newline."""
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerow(self.columns)
        return buf.getvalue()

    def whole_last_row(self, head: bytes, last: bytes, where: str) -> bool:
        """Whether ``last`` (a line without its newline, after the lines ``head``) is a complete, valid row
        (or, with nothing before it, a complete header)."""
        try:
            first = head.split(b"\n", 1)[0].decode("utf-8") if head else None
            header = next(csv.reader([first]), None) if first is not None else None
            fields = list(csv.reader(io.StringIO(last.decode("utf-8") + "\n")))
            if header is None:
                return len(fields) == 1 and tuple(fields[0]) in self.headers
            if len(fields) != 1 or len(fields[0]) != len(header):
                return False
            self.parse(dict(zip(header, fields[0])), where)
            return True
        except (UnicodeDecodeError, ValueError, csv.Error):
            return False


RATING = RowFormat("rating study", RATING_COLUMNS, (RATING_COLUMNS, RATING_CORE_COLUMNS), format_rating_row,
                   parse_rating_row, _rating_sequence)
FORCED_CHOICE = RowFormat("forced-choice session", FORCED_CHOICE_COLUMNS, (FORCED_CHOICE_COLUMNS,),
                          format_forced_choice_row, parse_forced_choice_row, _forced_choice_sequence)


# -- typed row formats of the newer kinds (method of adjustment, magnitude estimation) -----------------------

def _typed_format(columns: tuple, ints: tuple, floats: tuple, lists: tuple = ()):
    """``(format, parse)`` of a row whose columns are strings but for ``ints``, ``floats`` (repr; NaN/None
    empty) and ``lists`` (floats, ';'-joined)."""
    def fmt(row: dict) -> dict:
        out = {}
        for key in columns:
            value = row[key]
            if key in floats:
                out[key] = _fmt_float(value)
            elif key in ints:
                out[key] = str(int(value))
            elif key in lists:
                out[key] = ";".join(repr(float(v)) for v in value)
            else:
                out[key] = str(value)
        return out

    def parse(raw: dict, where: str) -> dict:
        _check_field_count(raw, where)
        row = dict(raw)
        try:
            for key in ints:
                row[key] = int(raw[key])
            for key in floats:
                row[key] = float(raw[key]) if raw[key] != "" else math.nan
                if math.isinf(row[key]):
                    raise ValueError(f"{key}={raw[key]!r} is not finite")
            for key in lists:
                row[key] = [float(v) for v in raw[key].split(";")] if raw[key] else []
                if not all(math.isfinite(v) for v in row[key]):
                    raise ValueError(f"{key}={raw[key]!r} holds a value that is not finite")
            if row["trial"] < 1 or row["attempt"] < 1:
                raise ValueError("trial and attempt must be >= 1")
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{where}: bad value ({exc})") from None
        return row
    return fmt, parse


ADJUSTMENT_COLUMNS = (
    "subject", "trial", "attempt", "block", "condition", "sequence", "reference_sample", "reference_value",
    "comparison_sample", "vary", "start_value", "start_side", "final_value", "matched", "n_steps",
    "n_comparisons", "n_references", "values", "sim_percept_reference", "started_at", "duration_s",
)
ADJUSTMENT_INT_COLUMNS = ("trial", "attempt", "block", "matched", "n_steps", "n_comparisons", "n_references")
ADJUSTMENT_FLOAT_COLUMNS = ("reference_value", "start_value", "final_value", "sim_percept_reference", "duration_s")
#: the side of the reference a trial's comparison starts on
START_SIDES = ("above", "below")


def _check_adjustment(row: dict, where: str) -> None:
    if row["start_side"] not in START_SIDES:
        raise ValueError(f"{where}: bad value (start_side={row['start_side']!r} is not above|below)")
    if row["matched"] not in (0, 1):
        raise ValueError(f"{where}: bad value (matched must be 0|1, got {row['matched']})")
    for key in ("reference_value", "start_value", "final_value"):
        if not row[key] > 0:
            raise ValueError(f"{where}: bad value ({key} must be a number > 0, got {row[key]!r})")
    if len(row["values"]) != row["n_comparisons"] or (row["values"] and row["values"][-1] != row["final_value"]):
        raise ValueError(f"{where}: bad value (values must list the {row['n_comparisons']} comparisons presented, "
                         "the last one the final value)")


def _sequence_of_trials(what: str):
    def follows(row: dict, where: str, state: dict) -> None:
        _forced_choice_sequence(row, where, state)
        if what == "adjustment":
            _check_adjustment(row, where)
        elif not (row["number"] > 0 and math.isfinite(row["number"])):
            raise ValueError(f"{where}: bad value (number must be a finite number > 0, got {row['number']!r})")
    return follows


MAGNITUDE_COLUMNS = (
    "subject", "trial", "attempt", "block", "condition", "sequence", "sample", "vary", "level", "modulus",
    "modulus_number", "modulus_shown", "number", "n_taps", "incoming_velocity_mean_m_s", "penetration_mean_m",
    "sim_percept", "started_at", "duration_s",
)
MAGNITUDE_INT_COLUMNS = ("trial", "attempt", "block", "modulus_shown", "n_taps")
MAGNITUDE_FLOAT_COLUMNS = ("level", "modulus", "modulus_number", "number", "incoming_velocity_mean_m_s",
                           "penetration_mean_m", "sim_percept", "duration_s")

ADJUSTMENT = RowFormat("method-of-adjustment session", ADJUSTMENT_COLUMNS, (ADJUSTMENT_COLUMNS,),
                       *_typed_format(ADJUSTMENT_COLUMNS, ADJUSTMENT_INT_COLUMNS, ADJUSTMENT_FLOAT_COLUMNS,
                                      ("values",)), _sequence_of_trials("adjustment"))
MAGNITUDE = RowFormat("magnitude-estimation session", MAGNITUDE_COLUMNS, (MAGNITUDE_COLUMNS,),
                      *_typed_format(MAGNITUDE_COLUMNS, MAGNITUDE_INT_COLUMNS, MAGNITUDE_FLOAT_COLUMNS),
                      _sequence_of_trials("magnitude"))


# -- the counterbalancing design (python -m study design) ---------------------------------------------------

DESIGN_CSV = "design.csv"
DESIGN_COLUMNS = ("participant", "sequence", "order")
#: characters a condition's name may not hold (the order column joins names with ';')
CONDITION_FORBIDDEN = (";", ",", "\n", "\r", '"')


def format_design(rows: list[dict]) -> str:
    """design.csv's text: ``participant, sequence (1-based), order`` (the conditions, ';'-joined, first first)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(DESIGN_COLUMNS)
    for r in rows:
        w.writerow((r["participant"], int(r["sequence"]), ";".join(r["order"])))
    return buf.getvalue()


def parse_design(text: str, path) -> list[dict]:
    """Every row of a design.csv (:func:`format_design`), checked: the header, one row per participant, a
    sequence number >= 1 and every order a permutation of the same conditions.

    Raises
    ------
    ValueError
        Naming the file and line.
    """
    reader = csv.reader(io.StringIO(text))
    try:
        header = next(reader, None)
        rows, seen, conditions = [], set(), None
        if header is None or tuple(h.strip() for h in header) != DESIGN_COLUMNS:
            raise ValueError(f"{path}: header {header} is not {list(DESIGN_COLUMNS)} (written by python -m study design)")
        for fields in reader:
            where = f"{path} line {reader.line_num}"
            if not fields:
                continue
            if len(fields) != len(DESIGN_COLUMNS):
                raise ValueError(f"{where}: {len(fields)} fields, the header has {len(DESIGN_COLUMNS)}")
            participant, sequence, order = fields
            if participant in seen:
                raise ValueError(f"{where}: participant {participant!r} is listed twice")
            try:
                number = int(sequence)
            except ValueError:
                raise ValueError(f"{where}: sequence {sequence!r} is not a whole number") from None
            names = order.split(";")
            if number < 1 or not all(names) or len(set(names)) != len(names):
                raise ValueError(f"{where}: sequence must be >= 1 and order a list of distinct conditions, "
                                 f"got {sequence!r}, {order!r}")
            if conditions is None:
                conditions = sorted(names)
            elif sorted(names) != conditions:
                raise ValueError(f"{where}: order {order!r} is not an order of the conditions {conditions}")
            seen.add(participant)
            rows.append({"participant": participant, "sequence": number, "order": names})
    except csv.Error as exc:
        raise ValueError(f"{path} line {reader.line_num}: not CSV ({exc})") from None
    if not rows:
        raise ValueError(f"{path}: no participant rows")
    return rows


class DamagedRow(ValueError):
    """A trials.csv row that does not parse, or does not follow the rows before it (the message names the
    file and line)."""


def parse_trials(fmt: RowFormat, data: bytes, path, subject: str | None = None) -> tuple[list[dict], tuple]:
    """Every row of a trials.csv's bytes, parsed and checked: the one reader of the study's trials files.

    Parameters
    ----------
    fmt : RowFormat
        :data:`RATING` or :data:`FORCED_CHOICE`.
    data : bytes
        The file's content (a last line torn by a crash already dealt with: the study's store mends it).
    path : str or Path
        The file, named in messages.
    subject : str or None
        The session's subject: every row must name it.

    Returns
    -------
    (list of dict, tuple)
        The rows (typed by ``fmt.parse``) and the file's header.

    Raises
    ------
    ValueError
        Not UTF-8, or a header that is none of ``fmt.headers`` (naming the file).
    DamagedRow
        A line that is not CSV, a row with a bad value or out of sequence (naming file and line).
    """
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise ValueError(f"{path} line {line}: not UTF-8 text (byte {exc.start}: {data[exc.start:exc.start + 1]!r}); "
                         f"{TRIALS_CSV} is damaged") from None
    reader = csv.DictReader(io.StringIO(text))
    try:
        header = tuple(reader.fieldnames or ())
    except csv.Error as exc:
        raise DamagedRow(f"{path} line 1: not CSV ({exc})") from None
    if header not in fmt.headers:
        raise ValueError(f"{path}: header {list(header)} is not the {fmt.what}'s {list(fmt.columns)}")
    rows, state = [], {}
    try:
        for raw in reader:
            where = f"{path} line {reader.line_num}"
            try:
                row = fmt.parse(raw, where)
                if subject is not None and row["subject"] != subject:
                    raise ValueError(f"{where}: subject={row['subject']!r}, but the session is {subject!r}")
                fmt.follows(row, where, state)
            except ValueError as exc:
                raise DamagedRow(str(exc)) from None
            rows.append(row)
    except csv.Error as exc:  # the DictReader's own line_num is that of the last row it returned
        raise DamagedRow(f"{path} line {reader.reader.line_num}: not CSV ({exc})") from None
    return rows, header


def trace_name(phase: str, trial: int, attempt: int) -> str:
    """The file name of one attempt's (or interval's) traces: ``<phase>_t<trial:03d>_a<attempt:02d>.npz``."""
    return f"{phase}_t{trial:03d}_a{attempt:02d}.npz"

