"""Load and validate a folder of study sessions (the study's files, docs/study.md).

``DATA/<subject>/session.json`` + ``DATA/<subject>/trials.csv`` per subject.
Plain files (the study runner's format) are read as one buffer by pyarrow's typed CSV
reader and validated column by column with numpy, so ten thousand subject folders
load in about a second; anything else goes through the exact per-file reader (the
``csv`` module), whose errors name the file and line (and the column).
"""

from __future__ import annotations

import csv
import difflib
import io
import os
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pa_csv

from analysis import workers
from analysis.config import check_data_folder
from plumbing.studyfiles import (BOOL_COLUMNS, EXPERIENCE, EXPERIENCE_ALIASES, FLOAT_COLUMNS, INT_COLUMNS, KINDS,
                                 LIST_COLUMNS, PHASES, RATING_CORE_COLUMNS, RATING_MAX, RATING_MIN, read_file_text,
                                 read_session_json)
from plumbing.textsafe import QUOTE, read_cell

# the rating study's columns as every trials.csv holds them (ends_familiarization, the study's own bookkeeping,
# is not read), their types and ranges: plumbing.studyfiles, the definition the study writes with
TRIAL_COLUMNS = RATING_CORE_COLUMNS


class AnalysisWarning(UserWarning):
    """Something was excluded or looks inconsistent; the report repeats every one of these."""


@dataclass(frozen=True)
class Study:
    """All attempts of all subjects, typed and validated.

    Attributes
    ----------
    trials : pandas.DataFrame
        One row per attempt, columns of :data:`TRIAL_COLUMNS` with parsed types (booleans, ints,
        floats in SI units, ``rating`` float with NaN when none; ``subject, phase, sample, kind``
        categorical with sorted categories; ``started_at`` and the lists kept as strings) plus
        ``file`` (path of the trials.csv, categorical) and ``line`` (1-based line number in it).
    subjects : pandas.DataFrame
        One row per subject: ``subject, experience, age, gender, handedness, finished, seed,
        software_version, device, folder`` (seed/version/device as session.json gives them, else None).
    catalog : tuple of str
        Sample names in catalog order (from ``session.json``'s ``catalog``).
    kinds : dict
        Sample name -> ``real`` | ``virtual`` (from the catalog, else from the rows).
    warnings : tuple of str
        Loading warnings (unfinished sessions, catalog differences, list/count mismatches).
    taps : dict
        For ``incoming_velocities_m_s`` and ``penetration_depths_m``: ``(values, row)``, every listed
        value (m/s, m) flattened and the 0-based row of ``trials`` it belongs to.
    labels : dict
        Sample name -> its label in the catalogs the subjects ran (catalog objects with a ``label``); the
        first subject naming a label wins (:func:`catalog_labels`).
    """

    trials: pd.DataFrame
    subjects: pd.DataFrame
    catalog: tuple
    kinds: dict
    warnings: tuple
    taps: dict
    labels: dict = field(default_factory=dict)


def _warn(messages: list, text: str, stacklevel: int = 3) -> None:
    messages.append(text)
    warnings.warn(text, AnalysisWarning, stacklevel=stacklevel)


def _subject_folders(data_dir: Path) -> list[str]:
    """Subject folders (paths as str: no Path object per folder) under ``data_dir``, sorted by name."""
    check_data_folder(data_dir)
    if (data_dir / "session.json").is_file():   # a single subject folder given directly
        return [str(data_dir)]
    with os.scandir(data_dir) as it:     # scandir: no stat per entry for the type, unlike Path.is_dir
        names = sorted(e.name for e in it if e.is_dir() and not e.name.startswith("."))
    root = str(data_dir)
    sessions = [folder for folder in (os.path.join(root, n) for n in names)
                if os.path.exists(os.path.join(folder, "session.json"))
                or os.path.exists(os.path.join(folder, "trials.csv"))]
    if not sessions:
        raise ValueError(f"{data_dir}: no subject folders with session.json and trials.csv found "
                         "(an empty data folder gives no report)")
    return sessions


def _catalog_names(raw, path: Path) -> tuple[list[str], dict]:
    """Sample names, kinds and labels from a session.json ``catalog`` (list of names or of objects with
    ``name``, and optionally ``kind`` and ``label``)."""
    if isinstance(raw, dict):
        raw = raw.get("samples", raw.get("catalog"))
    if not isinstance(raw, list) or not raw:
        raise ValueError(f"{path}: key 'catalog' must be a non-empty list of samples")
    names, kinds, labels = [], {}, {}
    for i, item in enumerate(raw):
        if isinstance(item, str):
            name = item
        elif isinstance(item, dict) and isinstance(item.get("name"), str):
            name = item["name"]
            if item.get("kind") in KINDS:
                kinds[name] = item["kind"]
            if isinstance(item.get("label"), str):
                labels[name] = item["label"]
        else:
            raise ValueError(f"{path}: key 'catalog' item {i} is neither a sample name nor an object with 'name'")
        if name in names:
            raise ValueError(f"{path}: key 'catalog' lists sample {name!r} twice")
        names.append(name)
    return names, kinds, labels


_last_catalog: list = [None, None]


def _catalog_cached(raw, path: Path) -> tuple[list[str], dict, dict]:
    """:func:`_catalog_names`, reusing the previous result when the raw catalog is equal (the usual case)."""
    if _last_catalog[0] is not None and raw == _last_catalog[0]:
        names, kinds, labels = _last_catalog[1]
        return list(names), dict(kinds), dict(labels)
    result = _catalog_names(raw, path)
    _last_catalog[0], _last_catalog[1] = raw, (list(result[0]), dict(result[1]), dict(result[2]))
    return result


def read_session(path) -> dict:
    """Read and check one ``session.json`` (``path``: str or Path); errors name the file, line or key.

    Returns a dict with ``subject, experience, catalog (list), kinds, labels, age, gender, handedness,
    finished, seed, software_version, device, servo_timing`` (:func:`servo_timing_text`).
    """
    raw = read_session_json(path)
    for key in ("subject", "experience", "catalog"):
        if key not in raw:
            raise ValueError(f"{path}: missing key {key!r}")
    subject = raw["subject"]
    if not isinstance(subject, str) or not subject:
        raise ValueError(f"{path}: key 'subject' must be a non-empty string")
    exp = raw["experience"]
    exp = EXPERIENCE_ALIASES.get(exp, exp) if isinstance(exp, str) else exp
    if exp not in EXPERIENCE:
        raise ValueError(f"{path}: key 'experience' is {raw['experience']!r}, expected one of {'|'.join(EXPERIENCE)}")
    names, kinds, labels = _catalog_cached(raw["catalog"], path)
    return {
        "subject": subject, "experience": exp, "catalog": names, "kinds": kinds, "labels": labels,
        "age": raw.get("age"), "gender": raw.get("gender"), "handedness": raw.get("handedness"),
        "finished": raw.get("finished_at") is not None,
        "seed": raw.get("seed"), "software_version": raw.get("software_version"), "device": raw.get("device"),
        "servo_timing": servo_timing_text(raw),
    }


def servo_timing_text(raw: dict) -> str:
    """Whether a session's servo met the timing thresholds, in words, from its session.json.

    Reads ``timing_check`` / ``timing_checks`` (the check before a hardware session, with
    ``accepted_override``) and ``servo_timing`` (its tapping windows' verdicts); written by ``study run``.

    Returns
    -------
    str
        ``"met"``, ``"NOT met (...)"``, or ``"not judged (...)"`` for a simulated session or one recorded
        before the check existed.
    """
    checks = raw.get("timing_checks") or ([raw["timing_check"]] if isinstance(raw.get("timing_check"), dict) else [])
    checks = [c for c in checks if isinstance(c, dict)]
    windows = raw.get("servo_timing") if isinstance(raw.get("servo_timing"), dict) else None
    why = []
    for c in checks:
        v = c.get("verdict") if isinstance(c.get("verdict"), dict) else {}
        if v.get("met") is False:
            why.append("check failed" + (", run with --accept-timing" if c.get("accepted_override") else "")
                       + (f": {'; '.join(map(str, v.get('failed', [])))}" if v.get("failed") else ""))
    judged = windows is not None and windows.get("all_met") is not None
    if judged and not windows["all_met"]:
        why.append(f"{windows.get('windows', 0) - windows.get('met', 0)} of {windows.get('windows', 0)} tapping "
                   "windows missed the thresholds")
    if why:
        return "NOT met (" + "; ".join(why) + ")"
    if not checks and not judged:
        return "not judged (no paced servo timing recorded: a simulated session, or one older than the check)"
    parts = (["check passed"] if checks else []) + ([f"{windows['met']} of {windows['windows']} windows"]
                                                      if judged else [])
    return "met (" + ", ".join(parts) + ")"


def _read_trials_columns(path: Path) -> tuple[list[tuple], list[int], bool]:
    """Columns (in :data:`TRIAL_COLUMNS` order, tuples of str) of one trials.csv and each row's line number.

    The third value is True when a torn last line (a crash mid-write, no final newline, wrong
    number of fields) was left out; the caller warns.
    """
    text = read_file_text(path, "utf-8-sig")  # -sig: tolerate a spreadsheet BOM
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        return _trials_columns(path, text, reader)
    except csv.Error as exc:   # e.g. a field over the csv module's limit (a 50 MB line): one error line
        raise ValueError(f"{path}:{reader.line_num}: not CSV ({exc})") from None


def _trials_columns(path: Path, text: str, reader) -> tuple[list[tuple], list[int], bool]:
    """The body of :func:`_read_trials_columns` (``reader``: the csv reader of ``text``)."""
    header = next(reader, None)
    if header is None:
        raise ValueError(f"{path}:1: empty file, expected a header with columns {', '.join(TRIAL_COLUMNS)}")
    header = [h.strip() for h in header]
    missing = [c for c in TRIAL_COLUMNS if c not in header]
    if missing:
        extra = [h for h in header if h not in TRIAL_COLUMNS]
        hints = []
        for col in missing:
            close = difflib.get_close_matches(col, extra, n=1, cutoff=0.6)
            hints.append(f"{col!r} (found {close[0]!r}: misspelled?)" if close else repr(col))
        raise ValueError(f"{path}:1: missing column(s) {', '.join(hints)}")
    dup = sorted({h for h in header if header.count(h) > 1 and h in TRIAL_COLUMNS})
    if dup:
        raise ValueError(f"{path}:1: column(s) {', '.join(dup)} appear more than once")
    width = len(header)
    torn = False
    if '"' not in text and "\r" not in text and text.endswith("\n"):
        # the runner's plain format: no quoting, one row per line; columns by slicing one flat split
        body = text[:-1].split("\n")[1:]
        b = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
        nl = np.flatnonzero(b == 10)
        commas = np.concatenate([[0], np.cumsum(b == 44)])[nl]       # commas before each newline
        if len(body) == len(nl) - 1 and np.all(np.diff(commas) == width - 1):
            flat = ",".join(body).split(",") if body else []
            order = [header.index(c) for c in TRIAL_COLUMNS]
            return [tuple(flat[j::width]) for j in order], list(range(2, len(body) + 2)), torn
    rows = list(reader)
    n_lines = text.count("\n") + (0 if text.endswith("\n") else 1)
    if n_lines == len(rows) + 1 and all(len(r) == width for r in rows):
        lines = list(range(2, len(rows) + 2))     # one row per line, no blank lines
    else:                                         # blank lines, quoted newlines or a bad row: count exactly
        reader = csv.reader(io.StringIO(text, newline=""))   # (the text read once already: no csv.Error now)
        next(reader)
        all_rows = [(row, reader.line_num) for row in reader]
        rows, lines = [], []
        for k, (row, line) in enumerate(all_rows):
            if not row:
                continue
            if len(row) != width:
                if k == len(all_rows) - 1 and not text.endswith("\n"):
                    torn = True
                    continue
                raise ValueError(f"{path}:{line}: {len(row)} fields, header has {width}")
            rows.append(row)
            lines.append(line)
    if not rows:
        return [() for _ in TRIAL_COLUMNS], lines, torn
    cols = list(zip(*rows))
    return [cols[header.index(c)] for c in TRIAL_COLUMNS], lines, torn


# names repeated on every row: pandas categoricals (sorted categories, the same from both readers), so
# comparisons, grouping and the codes of the tests cost an integer array, not half a million strings
NAME_COLUMNS = ("subject", "phase", "sample", "kind")
# the other text columns: pandas' string dtype with pyarrow storage, so the ;-lists of half a million
# rows stay in Arrow buffers instead of becoming a million Python strings
TEXT_COLUMNS = ("started_at",) + LIST_COLUMNS
STR_DTYPE = pd.StringDtype("pyarrow", na_value=np.nan)
# cells read as NaN in the number columns (the exact reader: empty, nan in any case, x)
_NA_FLOAT = ["", "nan", "NaN", "NAN", "Nan", "x", "X"]
_ARROW_TYPES = {**{c: pa.dictionary(pa.int32(), pa.string()) for c in NAME_COLUMNS},
                **{c: pa.bool_() for c in BOOL_COLUMNS}, **{c: pa.int64() for c in INT_COLUMNS},
                **{c: pa.float64() for c in FLOAT_COLUMNS + ("rating",)}, **{c: pa.string() for c in TEXT_COLUMNS}}
_BOM = b"\xef\xbb\xbf"
# the large Arrow allocations (CSV table, split lists) come from jemalloc, which hands freed blocks back:
# with pyarrow's default pool (mimalloc) the first CSV read of a process was up to twice as slow, with the
# system allocator the peak memory ~100 MB higher at 10,000 subjects
try:
    _POOL = pa.jemalloc_memory_pool()
except NotImplementedError:          # a pyarrow built without jemalloc
    _POOL = pa.system_memory_pool()


def _arrow_options(names: list[str]) -> tuple:
    """pyarrow CSV options for one headerless buffer of plain rows: no quoting, no blank lines, typed columns.

    A value the types do not take (an empty or misspelt boolean, a non-integer count, text in a
    number column, a wrong field count, invalid UTF-8) makes the reader raise; the caller then
    uses the exact reader. Booleans take true/false in three spellings (the exact reader takes any).
    """
    read = pa_csv.ReadOptions(column_names=names, use_threads=True, block_size=4 << 20)
    parse = pa_csv.ParseOptions(delimiter=",", quote_char=False, escape_char=False, newlines_in_values=False,
                                ignore_empty_lines=False)
    convert = pa_csv.ConvertOptions(column_types=_ARROW_TYPES, include_columns=list(TRIAL_COLUMNS),
                                    null_values=_NA_FLOAT, strings_can_be_null=False,
                                    true_values=["true", "True", "TRUE"], false_values=["false", "False", "FALSE"])
    return read, parse, convert


# the files are parsed in batches of about this many bytes (one table each, concatenated without copying):
# the raw text of ten thousand files (200 MB) is never held whole next to its parsed table
_BATCH_BYTES = 32 << 20


def _fast_trials(folders: list) -> tuple[pd.DataFrame, list] | None:
    """All trials.csv files parsed by pyarrow's typed CSV reader, or None if any file is not plain.

    Plain: UTF-8 without BOM, no quotes or carriage returns, ending in a newline, the same header
    in every file, and exactly header-width fields on every line (checked by the parser). Anything
    else (and any value the typed parse cannot read) returns None, and the caller uses the exact
    per-file reader, whose errors name file, line and column. The files are read in order and
    parsed a batch of files at a time (header lines left out). Returns the typed table (columns
    of :data:`TRIAL_COLUMNS`, ``file``, ``line``) and ``[(trials path, rows)]``.
    """
    buf = bytearray()
    header, options, file_of_row, counts, parsed = None, None, [], [], []
    # a batch is parsed in a second thread (pyarrow releases the GIL) while this one reads the next files
    with ThreadPoolExecutor(max_workers=1) as parser:

        def parse() -> bool:
            nonlocal buf
            if b'"' in buf or b"\r" in buf:
                return False
            parsed.append(parser.submit(pa_csv.read_csv, pa.py_buffer(buf), *options, memory_pool=_POOL))
            buf = bytearray()       # a new one: the parser holds the old one
            return True

        for folder in folders:
            path = os.path.join(folder, "trials.csv")
            try:
                with open(path, "rb") as fh:
                    data = fh.read()
            except OSError:
                return None
            first = data.find(b"\n")
            if first < 0 or data[-1:] != b"\n" or data.startswith(_BOM):
                return None
            if header is None:
                header = data[:first]
                try:
                    names = [h.strip() for h in header.decode("utf-8").split(",")]
                except UnicodeDecodeError:
                    return None
                if not set(TRIAL_COLUMNS) <= set(names) or len(set(names)) != len(names):
                    return None
                options = _arrow_options(names)
            elif first != len(header) or not data.startswith(header):
                return None
            n = data.count(b"\n") - 1
            buf += memoryview(data)[first + 1:]
            file_of_row.append((path, n))
            counts.append(n)
            del data
            if len(buf) >= _BATCH_BYTES and not parse():
                return None
        if header is None or (buf and not parse()):
            return None
        del buf
        try:
            tables = [f.result() for f in parsed]
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError, pa.ArrowTypeError):
            return None
        del parsed
    if not tables:                  # header lines only: the exact reader says so
        return None
    table = pa.concat_tables(tables) if len(tables) != 1 else tables[0]
    del tables
    if table.num_rows != sum(counts) or any(table.column(c).null_count for c in BOOL_COLUMNS + INT_COLUMNS):
        return None
    columns = {}
    for col in TRIAL_COLUMNS:
        values = table.column(col)
        if col in NAME_COLUMNS:
            columns[col] = names_categorical(values.to_pandas())
        elif col in TEXT_COLUMNS:
            columns[col] = values.to_pandas(types_mapper={pa.string(): STR_DTYPE}.get)
        else:
            columns[col] = values.to_numpy(zero_copy_only=False)       # float nulls (empty, nan, x) become NaN
    del table, values
    t = pd.DataFrame(columns)
    t["file"] = _file_column(file_of_row)
    t["line"] = _line_numbers(counts)
    return t, file_of_row


def names_categorical(values) -> pd.Categorical:
    """Names (subject, phase, sample, kind) as a categorical whose categories are sorted.

    Parameters
    ----------
    values : array-like of str or pandas Categorical/Series

    Returns
    -------
    pandas.Categorical
        The same values; categories in sorted order with pandas' string dtype, whatever the
        reader (so both readers give equal tables).
    """
    cat = values.array if isinstance(values, pd.Series) else values
    cat = cat if isinstance(cat, pd.Categorical) else pd.Categorical(cat)
    if any(str(c).startswith(QUOTE) for c in cat.categories):
        # a name the study wrote with a quote before it, so that a spreadsheet never runs it as a formula
        # (plumbing.textsafe): read back as named
        names = np.array([read_cell(str(c)) for c in cat.categories] + [None], dtype=object)
        cat = pd.Categorical(names[np.where(cat.codes >= 0, cat.codes, len(names) - 1)])
    return pd.Categorical(cat, categories=pd.Index(sorted(cat.categories), dtype=STR_DTYPE))


def _file_column(file_of_row: list) -> pd.Categorical:
    """The ``file`` column: each row's trials.csv path, a categorical with one category per file (in file order)."""
    paths = [f for f, _ in file_of_row]
    code = np.repeat(np.arange(len(paths), dtype=np.int32), [n for _, n in file_of_row])
    return pd.Categorical.from_codes(code, categories=pd.Index(paths, dtype=STR_DTYPE))


def _line_numbers(counts: list) -> np.ndarray:
    """1-based line numbers 2, 3, ... of the rows of files with ``counts`` rows each (one header line)."""
    counts = np.asarray(counts, dtype=np.int64)
    total = int(counts.sum())
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]) if counts.size else counts
    return np.arange(total, dtype=np.int64) - np.repeat(starts, counts) + 2


def _fail(trials: pd.DataFrame, bad: np.ndarray, column: str, what: str, shown=None) -> None:
    """Raise a ValueError naming file, line, column and value of the first bad row.

    ``shown``: the raw strings of the column, when ``trials`` already holds parsed values.
    """
    i = int(np.flatnonzero(bad)[0])
    n = int(bad.sum())
    more = f" ({n - 1} more row(s) like it)" if n > 1 else ""
    value = shown[i] if shown is not None else trials[column].iat[i]
    if isinstance(value, (bool, np.bool_)):      # show parsed values as they are written in the file
        value = "true" if value else "false"
    elif isinstance(value, np.integer):
        value = int(value)
    elif isinstance(value, np.floating):
        value = float(value)
    raise ValueError(f"{trials['file'].iat[i]}:{trials['line'].iat[i]}: column {column!r}: "
                     f"value {value!r} {what}{more}")


def _to_float(values: np.ndarray) -> np.ndarray:
    """Strings to float; empty or unparsable -> NaN (the caller tells which)."""
    return pd.to_numeric(values, errors="coerce").astype(float, copy=False)


def _parse_columns(t: pd.DataFrame) -> pd.DataFrame:
    """Type the string columns in place of the raw ones; errors name file, line and column."""
    out = {}
    for col in BOOL_COLUMNS:
        raw = t[col].to_numpy(dtype=object)
        is_true = raw == "true"
        bad = ~(is_true | (raw == "false"))
        if bad.any():  # tolerate other capitalisations before failing
            low = np.array([str(v).lower() for v in raw], dtype=object)
            is_true = low == "true"
            bad = ~(is_true | (low == "false"))
            if bad.any():
                _fail(t, bad, col, "is not true|false")
        out[col] = is_true
    for col in INT_COLUMNS:
        num = _to_float(t[col].to_numpy(dtype=object))
        bad = ~np.isfinite(num) | (num != np.round(num))
        if bad.any():
            _fail(t, bad, col, "is not an integer")
        bad = np.abs(num) > 2.0 ** 53  # beyond exact float integers; astype(int64) would wrap it
        if bad.any():
            _fail(t, bad, col, "is out of range (beyond +/-2^53)")
        out[col] = num.astype(np.int64)
    for col in FLOAT_COLUMNS + ("rating",):
        raw = t[col].to_numpy(dtype=object)
        num = _to_float(raw)
        nan = np.isnan(num)
        if nan.any():
            text = np.array([str(v).strip().lower() for v in raw[nan]], dtype=object)
            bad_sub = ~np.isin(text, ["", "nan", "x"])
            if bad_sub.any():
                bad = np.zeros(len(raw), dtype=bool)
                bad[np.flatnonzero(nan)[bad_sub]] = True
                _fail(t, bad, col, "is not a number (leave it empty when there is none)")
        out[col] = num
    for col in ("phase", "kind"):
        allowed = PHASES if col == "phase" else KINDS
        bad = ~t[col].isin(allowed).to_numpy()
        if bad.any():
            _fail(t, bad, col, f"is not one of {'|'.join(allowed)}")
    parsed = t.copy()
    for col, values in out.items():
        parsed[col] = values
    return parsed


def _check_ratings(t: pd.DataFrame, raw: np.ndarray) -> None:
    r = t["rating"].to_numpy()
    valid = t["valid"].to_numpy()
    present = ~np.isnan(r)
    in_range = present & (r >= RATING_MIN) & (r <= RATING_MAX) & (r == np.round(r))
    testing = (t["phase"] == "testing").to_numpy()
    bad = valid & testing & ~in_range
    if bad.any():
        _fail(t, bad, "rating", f"must be an integer {RATING_MIN}-{RATING_MAX} on a valid testing attempt", raw)
    bad = valid & present & ~in_range
    if bad.any():
        _fail(t, bad, "rating", f"is outside {RATING_MIN}-{RATING_MAX} on a valid attempt", raw)


def _check_consistency(t: pd.DataFrame, kinds: dict) -> None:
    """Counters >= their minimum, ``valid`` not true on a flagged attempt, ``kind`` as in the catalog."""
    for col, low in (("trial", 1), ("attempt", 1), ("n_taps", 0)):
        bad = t[col].to_numpy() < low
        if bad.any():
            _fail(t, bad, col, f"must be >= {low}")
    for col in FLOAT_COLUMNS:  # empty (NaN) when there is none; never inf or negative
        v = t[col].to_numpy()
        bad = np.isinf(v) | (v < 0)
        if bad.any():
            _fail(t, bad, col, "is not a finite number >= 0 (leave it empty when there is none)")
    flagged = t["rejected"].to_numpy() | t["saturated"].to_numpy() | t["overpowered"].to_numpy()
    bad = t["valid"].to_numpy() & flagged
    if bad.any():
        _fail(t, bad, "valid", "is true on an attempt marked rejected, saturated or overpowered")
    if kinds:
        # compared as codes: the catalog's kind of each sample category, as a code of the kind column
        # (-1: the catalog gives none; -2: a kind no row has)
        sample, kind = pd.Categorical(t["sample"]), pd.Categorical(t["kind"])
        kind_code = {k: c for c, k in enumerate(kind.categories)}
        lut = np.array([kind_code.get(kinds[s], -2) if s in kinds else -1 for s in sample.categories] + [-1])
        expected = lut[sample.codes]                  # a missing sample (code -1) takes the last entry, -1
        bad = (expected != -1) & (kind.codes != expected)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            name = t["sample"].iat[i]
            _fail(t, bad, "kind", f"differs from the catalog's kind {kinds[name]!r} of sample {name!r}")


def _check_tap_values(numbers: np.ndarray, row: np.ndarray, files, lines, column: str) -> None:
    """Every listed velocity (m/s, a magnitude) and penetration (m) is a finite number >= 0 (so
    inf, nan or a negative value never flows into sample_summary.csv); ValueError names file, line and value."""
    bad = ~(np.isfinite(numbers) & (numbers >= 0))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        r = int(row[i])
        more = int(bad.sum()) - 1
        raise ValueError(f"{files[r]}:{lines[r]}: column {column!r}: value {float(numbers[i])!r} is not a finite "
                         f"number >= 0" + (f" ({more} more like it)" if more else ""))


def _check_duplicates(t: pd.DataFrame) -> None:
    key = ["subject", "phase", "trial", "attempt"]
    dup = t.duplicated(key, keep=False).to_numpy()
    if dup.any():
        i = int(np.flatnonzero(dup)[0])
        same = t.iloc[np.flatnonzero(dup)]
        row = t.iloc[i]
        same = same[(same["subject"] == row["subject"]) & (same["phase"] == row["phase"])
                    & (same["trial"] == row["trial"]) & (same["attempt"] == row["attempt"])]
        where = ", ".join(f"{f}:{ln}" for f, ln in zip(same["file"], same["line"]))
        raise ValueError(f"duplicated attempt (subject={row['subject']}, phase={row['phase']}, trial={row['trial']}, "
                         f"attempt={row['attempt']}) at {where}")


def parse_lists(values, files, lines, column: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All numbers of a semicolon-separated list column, flattened, with the row each came from.

    Parameters
    ----------
    values : sequence of str, shape (n_rows,)
        Cells such as ``"0.11;0.09"`` (empty cell = empty list): a list, an array or a pandas
        column (a pyarrow-backed one is parsed without converting its cells to Python strings).
    files, lines : sequences, shape (n_rows,)
        File and line of each row, for the error message.
    column : str

    Returns
    -------
    numbers : ndarray, shape (n_values,)
    row : ndarray of int, shape (n_values,)
        0-based position in ``values`` of the row of each number.
    counts : ndarray of int, shape (n_rows,)
        List length per row.
    """
    fast = _fast_lists(values)
    if fast is not None:
        return fast
    cells = list(values)
    text = "|".join(cells)
    b = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
    seps = b[(b == ord(";")) | (b == ord("|"))]
    if int(np.count_nonzero(seps == ord("|"))) != max(len(cells) - 1, 0):
        _bad_list_cell(cells, files, lines, column)         # a '|' inside a cell
    token_row = np.concatenate([[0], np.cumsum(seps == ord("|"))]).astype(np.int64)
    tokens = np.array(text.replace("|", ";").split(";"), dtype=object)
    keep = tokens != ""
    numbers = pd.to_numeric(tokens[keep], errors="coerce").astype(float, copy=False)
    if np.isnan(numbers).any() and not all(t.strip().lower() == "nan" for t in tokens[keep][np.isnan(numbers)]):
        _bad_list_cell(cells, files, lines, column)
    row = token_row[keep]
    return numbers, row, np.bincount(row, minlength=len(cells))


def _arrow_strings(cells) -> pa.ChunkedArray | pa.Array | None:
    """The cells as an Arrow string array (no copy for a pyarrow-backed pandas column), or None if one is not a str."""
    if isinstance(cells, pd.Series):
        cells = cells.array
    if isinstance(cells, pd.api.extensions.ExtensionArray):
        try:
            arr = pa.array(cells)
        except (pa.ArrowInvalid, pa.ArrowTypeError, TypeError):
            return None
        return arr if (pa.types.is_string(arr.type) or pa.types.is_large_string(arr.type)) and not arr.null_count \
            else None
    cells = cells if isinstance(cells, list) else list(cells)
    if not all(isinstance(c, str) for c in cells):
        return None
    return pa.array(cells, type=pa.string())


def _n_tokens(chunk: pa.Array) -> int:
    """The number of tokens of a string array's ;-lists when none is empty: one per ';' byte (counted in
    the array's data buffer, in a tenth of the time of pyarrow's count_substring) plus one per non-empty
    cell."""
    wide = pa.types.is_large_string(chunk.type)
    _, off_buf, data_buf = chunk.buffers()
    off = np.frombuffer(off_buf, dtype=np.int64 if wide else np.int32, count=len(chunk) + 1,
                        offset=chunk.offset * (8 if wide else 4))
    data = np.frombuffer(data_buf, dtype=np.uint8)[off[0]:off[-1]] if data_buf is not None \
        else np.zeros(0, dtype=np.uint8)
    return int(np.count_nonzero(data == ord(";"))) + (pc.sum(pc.not_equal(chunk, "")).as_py() or 0)


def _fast_lists(cells) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """:func:`parse_lists` in C (pyarrow: split at ';', cast to float64) for clean cells; None when a cell
    has an empty token, a token that is not a finite number, or is not a str (then the exact parser
    runs and names the cell). The casts are correctly rounded, like ``float()``. Chunk by chunk, so
    the split strings of a chunk are all that is held besides the numbers."""
    arr = _arrow_strings(cells)
    if arr is None:
        return None
    chunks = arr.chunks if isinstance(arr, pa.ChunkedArray) else [arr]
    # the numbers go straight into one array (not into a list of arrays concatenated at the end, which
    # held them twice, 24 MB a column at 10,000 subjects)
    total = sum(_n_tokens(c) for c in chunks)
    numbers, filled, counts = np.empty(total), 0, []
    for chunk in chunks:
        split = pc.split_pattern(chunk, ";", memory_pool=_POOL)
        tokens = split.flatten()
        count = np.array(pc.list_value_length(split).to_numpy(zero_copy_only=False), dtype=np.int64)
        empty_cell = np.asarray(pc.equal(chunk, "").to_numpy(zero_copy_only=False), dtype=bool)
        n_empty_tokens = pc.sum(pc.equal(tokens, "")).as_py() or 0
        if n_empty_tokens != int(empty_cell.sum()):       # an empty token inside a list (';;', a leading ';')
            return None
        if n_empty_tokens:
            count[empty_cell] = 0
            tokens = pc.filter(tokens, pc.not_equal(tokens, ""))
        try:
            values = pc.cast(tokens, pa.float64(), memory_pool=_POOL).to_numpy(zero_copy_only=False)
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
            return None
        if values.size != int(count.sum()) or filled + values.size > total or not np.isfinite(values).all():
            return None
        numbers[filled:filled + values.size] = values
        filled += values.size
        counts.append(count)
    if filled != total:
        return None
    counts = np.concatenate(counts) if counts else np.zeros(0, dtype=np.int64)
    return numbers, np.repeat(np.arange(len(arr), dtype=np.int64), counts), counts


def _bad_list_cell(cells, files, lines, column) -> None:
    for i, v in enumerate(cells):
        try:
            [float(x) for x in v.split(";")] if v.strip() else None
        except ValueError:
            raise ValueError(f"{files[i]}:{lines[i]}: column {column!r}: {v!r} is not a "
                             "semicolon-separated list of numbers") from None
    raise ValueError(f"column {column!r}: a cell is not a semicolon-separated list of numbers")


def _string_trials(folders: list) -> tuple[pd.DataFrame, list] | None:
    """Every trials.csv as text columns (Arrow-backed strings, no Python object per cell), or None.

    The error path of plain files (a 367 MB trials.csv with one bad cell peaked at
    9.3 GB in the exact reader, which holds every cell as a Python string, twice): pyarrow reads the
    cells untyped, so a value the typed read refused is kept as written for the checks and their message,
    at about the file's size in memory. Plain as for :func:`_fast_trials` (a file at a time); anything
    else (quotes, blank or torn lines, a wrong field count, a BOM, another header) returns None: the exact
    reader, whose errors name the line. Returns the table (columns of :data:`TRIAL_COLUMNS` as
    :data:`STR_DTYPE`, ``file``, ``line``) and ``[(trials path, rows)]``.
    """
    tables, file_of_row, counts = [], [], []
    for folder in folders:
        path = os.path.join(folder, "trials.csv")
        try:
            with open(path, "rb") as fh:
                data = fh.read()
        except OSError:
            return None
        first = data.find(b"\n")
        if (first < 0 or data[-1:] != b"\n" or data.startswith(_BOM) or b'"' in data or b"\r" in data
                or b"\n\n" in data):
            return None
        try:
            names = [h.strip() for h in data[:first].decode("utf-8").split(",")]
        except UnicodeDecodeError:
            return None
        if not set(TRIAL_COLUMNS) <= set(names) or len(set(names)) != len(names):
            return None
        read, parse, _ = _arrow_options(names)
        convert = pa_csv.ConvertOptions(column_types={c: pa.string() for c in names},
                                        include_columns=list(TRIAL_COLUMNS), strings_can_be_null=False)
        try:
            table = pa_csv.read_csv(pa.py_buffer(memoryview(data)[first + 1:]), read, parse, convert,
                                    memory_pool=_POOL)
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError, pa.ArrowTypeError):
            return None
        del data
        n = table.num_rows
        tables.append(table)
        file_of_row.append((path, n))
        counts.append(n)
    if not tables or not sum(counts):
        return None
    table = pa.concat_tables(tables) if len(tables) != 1 else tables[0]
    del tables
    t = pd.DataFrame({col: table.column(col).to_pandas(types_mapper={pa.string(): STR_DTYPE}.get)
                      for col in TRIAL_COLUMNS})
    del table
    t["file"] = _file_column(file_of_row)
    t["line"] = _line_numbers(counts)
    return t, file_of_row


def _exact_trials(folders: list, messages: list) -> tuple[pd.DataFrame, list]:
    """Every trials.csv read with the exact per-file reader (quotes, blank lines, torn last lines...)."""
    columns: list[list[str]] = [[] for _ in TRIAL_COLUMNS]
    all_lines, file_of_row = [], []
    for folder in folders:
        trials_path = Path(folder) / "trials.csv"
        cols, lines, torn = _read_trials_columns(trials_path)
        if torn:
            _warn(messages, f"{trials_path}: torn last line (a crash while writing?) left out")
        for acc, col in zip(columns, cols):
            acc.extend(col)
        all_lines.extend(lines)
        file_of_row.append((str(trials_path), len(lines)))
    # object dtype: pandas' own string dtype costs more to build than the checks gain
    trials = pd.DataFrame({c: np.array(columns[i], dtype=object) for i, c in enumerate(TRIAL_COLUMNS)},
                          dtype=object)
    del columns
    trials["file"] = _file_column(file_of_row)
    trials["line"] = np.array(all_lines, dtype=np.int64)
    return trials, file_of_row


def _validate(trials: pd.DataFrame, raw_rating, subjects: pd.DataFrame, file_of_row: list, catalog: list,
              kinds: dict) -> None:
    """Cross-row checks of the typed table; ValueError names file, line and column of the first problem.

    ``raw_rating``: the rating column as written (for the message), or None on the fast path.
    """
    names = subjects["subject"].to_numpy(dtype=object)
    counts = [n for _, n in file_of_row]
    subject = pd.Categorical(trials["subject"])
    # compared as codes: each file's session subject as a code of the subject column (-1: no row has it)
    expected = np.repeat(pd.Index(subject.categories).get_indexer(names), counts)
    bad = (subject.codes != expected) | (subject.codes < 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        _fail(trials, bad, "subject", f"differs from session.json's subject {np.repeat(names, counts)[i]!r}")
    bad = ~trials["phase"].isin(PHASES).to_numpy()
    if bad.any():
        _fail(trials, bad, "phase", f"is not one of {'|'.join(PHASES)}")
    bad = ~trials["kind"].isin(KINDS).to_numpy()
    if bad.any():
        _fail(trials, bad, "kind", f"is not one of {'|'.join(KINDS)}")
    bad = ~trials["sample"].isin(catalog).to_numpy()
    if bad.any():
        _fail(trials, bad, "sample", f"is not in the catalog of session.json ({', '.join(catalog)})")
    _check_consistency(trials, kinds)
    _check_ratings(trials, raw_rating if raw_rating is not None else trials["rating"].to_numpy())
    _check_duplicates(trials)


def _read_sessions(folders: list, messages: list) -> tuple[pd.DataFrame, list, dict, dict]:
    """Every subject's session.json: (subjects table, catalog, kinds, labels); warnings appended to
    ``messages``."""
    catalog: list[str] = []
    kinds: dict = {}
    labels: dict = {}
    subj_rows = []
    seen_subjects: dict = {}
    for folder in folders:
        sess_path = os.path.join(folder, "session.json")
        sess = read_session(sess_path)
        if sess["subject"] in seen_subjects:
            raise ValueError(f"{sess_path}: subject {sess['subject']!r} also in {seen_subjects[sess['subject']]}")
        seen_subjects[sess["subject"]] = sess_path
        if not catalog:
            catalog = list(sess["catalog"])
        elif sess["catalog"] != catalog:
            added = [s for s in sess["catalog"] if s not in catalog]
            _warn(messages, f"{sess_path}: catalog differs from the first session's"
                            + (f" (adds {', '.join(added)})" if added else " (order or subset)"), stacklevel=4)
            catalog.extend(added)
        for name, kind in sess["kinds"].items():
            kinds.setdefault(name, kind)
        for name, label in sess["labels"].items():
            labels.setdefault(name, label)
        if not sess["finished"]:
            _warn(messages, f"session {sess['subject']} is not finished (finished_at is null): "
                            "its attempts are used as far as they go", stacklevel=4)
        subj_rows.append({k: sess[k] for k in ("subject", "experience", "age", "gender", "handedness", "finished",
                                               "seed", "software_version", "device", "servo_timing")}
                         | {"folder": folder, "session_file": sess_path,
                            "trials_file": os.path.join(folder, "trials.csv")})
    return pd.DataFrame(subj_rows), catalog, kinds, labels


def _read_sessions_quietly(folders: list) -> tuple[pd.DataFrame, list, dict, dict, list]:
    """:func:`_read_sessions` in another process: its warnings are returned with the result, not shown
    there (:func:`load_study` issues them again in the calling process, where they are caught)."""
    messages: list[str] = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AnalysisWarning)
        subjects, catalog, kinds, labels = _read_sessions(folders, messages)
    return subjects, catalog, kinds, labels, messages


def submit_sessions(data_dir, executor) -> tuple:
    """Start reading the session files of ``data_dir`` in ``executor``'s process, for :func:`load_study`.

    The report's drawing process has nothing to do until the study is loaded: it reads the session
    files (~0.4 s of JSON at 10,000 subjects) while this process imports the statistics and reads the
    trials files.

    Parameters
    ----------
    data_dir : path
        The folder :func:`load_study` is then given.
    executor : concurrent.futures.Executor or None
        A pool of another process (None: nothing is submitted).

    Returns
    -------
    tuple
        ``(data_dir, subject folders, future or None)``: the ``sessions`` argument of :func:`load_study`
        (None as the future without a pool or when its process is gone: the files are then read there).

    Raises
    ------
    ValueError, FileNotFoundError
        As :func:`load_study` does for a data folder without subject folders.
    """
    folders = _subject_folders(Path(data_dir))
    return Path(data_dir), folders, workers.submit(executor, _read_sessions_quietly, folders)


def _sessions(future, folders: list, messages: list) -> tuple[pd.DataFrame, list, dict, dict]:
    """:func:`_read_sessions`'s result: ``future``'s (of :func:`_read_sessions_quietly`; its warnings are
    issued here) or, without one or when its process died, the session files read here."""
    got = workers.result(future)     # raises the reading's error, if any
    if got is None:
        return _read_sessions(folders, messages)
    subjects, catalog, kinds, labels, found = got
    for text in found:
        _warn(messages, text, stacklevel=4)     # at load_study's caller, as _read_sessions warns
    return subjects, catalog, kinds, labels


def load_study(data_dir, sessions: tuple | None = None) -> Study:
    """Load and validate every subject folder under ``data_dir``.

    Parameters
    ----------
    data_dir : path
        Folder of subject folders (or one subject folder).
    sessions : tuple or None
        What :func:`submit_sessions` returned for ``data_dir``: its session files are being read in
        another process. The study, its warnings and its errors are the same as without.

    Raises
    ------
    FileNotFoundError, ValueError
        With the file and line (and column or key) of the first problem.
    """
    data_dir = Path(data_dir)
    messages: list[str] = []
    if sessions is not None and sessions[0] != data_dir:
        raise ValueError(f"sessions submitted for {sessions[0]}, not for {data_dir}")
    folders, pending = sessions[1:] if sessions is not None else (_subject_folders(data_dir), None)
    # fast path: every trials.csv plain -> typed pyarrow reads, validated below; any problem: the exact
    # reader. The fast reading never raises, so it goes first: its ;-lists are split in two more threads
    # (one per column, ~0.25 s each at 10,000 subjects; pyarrow releases the GIL) while this one reads
    # the session files (or takes them from the process that read them meanwhile, submit_sessions) and
    # validates, and every error still comes in the order of the exact reading (session files, then
    # trials files)
    fast = _fast_trials(folders)
    with ThreadPoolExecutor(max_workers=len(LIST_COLUMNS)) as splitter:
        split = {col: splitter.submit(_fast_lists, fast[0][col]) for col in LIST_COLUMNS} if fast else {}
        subjects, catalog, kinds, labels = _sessions(pending, folders, messages)
        if fast is not None:
            trials, file_of_row = fast
            try:
                _validate(trials, None, subjects, file_of_row, catalog, kinds)
            except ValueError:
                fast, split = None, {}    # read again exactly, so the error names the raw value as written
        if fast is None:
            # plain files as untyped Arrow text (the file's size in memory), others cell by cell
            text = _string_trials(folders)
            trials, file_of_row = text if text is not None else _exact_trials(folders, messages)
            del text
            raw_rating = trials["rating"].to_numpy(dtype=object)
            trials = _parse_columns(trials)
            for col in NAME_COLUMNS:                     # the fast reader's dtypes
                trials[col] = names_categorical(trials[col].to_numpy(dtype=object))
            for col in TEXT_COLUMNS:
                trials[col] = trials[col].astype(STR_DTYPE)
            _validate(trials, raw_rating, subjects, file_of_row, catalog, kinds)
        sample = pd.Categorical(trials["sample"])
        _, first = np.unique(sample.codes, return_index=True)     # first row of each sample, in row order
        for i in np.sort(first):
            kinds.setdefault(trials["sample"].iat[i], trials["kind"].iat[i])

        files, lines = trials["file"].to_numpy(dtype=object), trials["line"].to_numpy()
        n_taps = trials["n_taps"].to_numpy()
        testing_valid = (trials["phase"] == "testing").to_numpy() & trials["valid"].to_numpy()
        taps = {}
        for col in LIST_COLUMNS:
            parsed = split[col].result() if col in split else None
            numbers, row, counts = parsed if parsed is not None else parse_lists(trials[col], files, lines, col)
            _check_tap_values(numbers, row, files, lines, col)
            taps[col] = (numbers, row)
            mism = testing_valid & (counts != n_taps)
            if mism.any():
                i = int(np.flatnonzero(mism)[0])
                _warn(messages, f"{int(mism.sum())} valid testing attempt(s) list a number of {col} different "
                                f"from n_taps (first at {files[i]}:{lines[i]}); the listed values are used")
    if trials.empty:
        raise ValueError(f"{data_dir}: the trials.csv files hold no attempts")
    return Study(trials=trials, subjects=subjects, catalog=tuple(catalog), kinds=kinds, warnings=tuple(messages),
                 taps=taps, labels=labels)


def catalog_labels(study: Study) -> dict:
    """Sample name -> its label in the catalog the subjects ran (``session.json``'s ``catalog`` objects with a
    ``label``, e.g. ``hfam_mine`` -> "HFAM, my library, firm"); the first subject naming a label wins. Samples
    without one are absent (the figures then use the project palette's label or the name). Collected while
    the session files are read (:func:`load_study`; reading 10,000 of them again cost 0.9 s per call)."""
    return dict(study.labels)

