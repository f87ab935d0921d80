"""Crash-safe study data: one folder per subject (format in docs/study.md).

``DATA/<subject>/session.json``   subject info and settings; ``finished_at`` null until done
``DATA/<subject>/trials.csv``     one row per attempt, appended, flushed and fsynced as it ends
``DATA/<subject>/schedule.jsonl`` planned orders, every redraw, familiarization end, resumes
``DATA/<subject>/traces/<phase>_t<trial>_a<attempt>.npz``  full-rate traces of one attempt

Write order per attempt: trace file (atomic rename), then the CSV row. A row
therefore always has its trace; a trace without a row belongs to an attempt
that was interrupted and is re-run (and rewritten) on ``--resume``.
"""

from __future__ import annotations

import csv
import datetime as _dt
import io
import json
import os
import re
from pathlib import Path

import numpy as np

TRIAL_COLUMNS = (
    "subject", "phase", "trial", "attempt", "sample", "kind", "rating", "rejected", "saturated", "overpowered",
    "valid", "n_taps", "incoming_velocity_mean_m_s", "penetration_mean_m", "incoming_velocities_m_s",
    "penetration_depths_m", "started_at", "duration_s",
)
SUBJECT_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")
EXPERIENCE = ("none", "few", "regular")


def utc_now() -> str:
    """ISO 8601 UTC timestamp with milliseconds."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def check_subject_id(subject: str) -> str:
    """Refuse ids that could escape the data folder or are awkward as folder names."""
    if not isinstance(subject, str) or not SUBJECT_RE.match(subject):
        raise ValueError(f"subject id {subject!r} is not allowed: use 1-64 letters, digits, '_' or '-' "
                         "(no path characters such as '/', '\\\\', '..', spaces)")
    return subject


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a fsynced temporary file and rename (never a half file)."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def _fmt_bool(value: bool) -> str:
    return "true" if value else "false"


def _fmt_float(value: float) -> str:
    return "" if value is None or value != value else repr(float(value))


def format_row(row: dict) -> dict:
    """Turn an attempt record into CSV strings (lists ';'-joined, booleans true|false, rating empty if None)."""
    out = {}
    for key in TRIAL_COLUMNS:
        value = row[key]
        if key in ("rejected", "saturated", "overpowered", "valid"):
            out[key] = _fmt_bool(value)
        elif key in ("incoming_velocities_m_s", "penetration_depths_m"):
            out[key] = ";".join(repr(float(v)) for v in value)
        elif key in ("incoming_velocity_mean_m_s", "penetration_mean_m", "duration_s"):
            out[key] = _fmt_float(value)
        elif key == "rating":
            out[key] = "" if value is None else str(int(value))
        else:
            out[key] = str(value)
    return out


def parse_row(raw: dict, where: str) -> dict:
    """Inverse of :func:`format_row`; errors name ``where`` (file and line)."""
    row = dict(raw)
    try:
        for key in ("rejected", "saturated", "overpowered", "valid"):
            if raw[key] not in ("true", "false"):
                raise ValueError(f"{key}={raw[key]!r} is not true|false")
            row[key] = raw[key] == "true"
        row["trial"] = int(raw["trial"])
        row["attempt"] = int(raw["attempt"])
        row["rating"] = int(raw["rating"]) if raw["rating"] else None
        row["n_taps"] = int(raw["n_taps"])
    except (KeyError, ValueError) as exc:
        raise ValueError(f"{where}: bad value ({exc})") from None
    return row


class SessionStore:
    """The folder of one subject; see the module doc.

    Parameters
    ----------
    root : path
        The data folder (``--out``); created if missing.
    subject : str
        Subject id (checked with :func:`check_subject_id`).
    resume : bool
        Open an existing, unfinished session instead of creating a new one.
    """

    def __init__(self, root, subject: str, resume: bool = False) -> None:
        self.subject = check_subject_id(subject)
        self.root = Path(root)
        self.dir = self.root / subject
        self.session_path = self.dir / "session.json"
        self.trials_path = self.dir / "trials.csv"
        self.schedule_path = self.dir / "schedule.jsonl"
        self.traces_dir = self.dir / "traces"
        self.resume = resume
        self.session: dict | None = None

    # -- checks before anything starts -----------------------------------
    def check(self) -> None:
        """Refuse before the session starts: unwritable folder, existing subject without resume, etc."""
        try:
            self.root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ValueError(f"data folder {self.root} cannot be created: {exc.strerror}") from None
        if not self.root.is_dir():
            raise ValueError(f"data folder {self.root} is not a directory")
        probe = self.root / f".write-test-{os.getpid()}"
        try:
            with open(probe, "wb") as fh:
                fh.write(b"x")
            probe.unlink()
        except OSError as exc:
            raise ValueError(f"data folder {self.root} is not writable: {exc.strerror}") from None
        if self.resume:
            if not self.session_path.is_file():
                raise FileNotFoundError(f"--resume: no session to resume at {self.session_path}")
            session = self.load_session()
            if session.get("finished_at"):
                raise ValueError(f"--resume: session {self.session_path} already finished at "
                                 f"{session['finished_at']}")
        elif self.dir.exists():
            raise ValueError(f"subject {self.subject!r} already has data in {self.dir}; "
                             "use --resume to continue it or choose another subject id (nothing was overwritten)")

    # -- session.json ----------------------------------------------------
    def load_session(self) -> dict:
        try:
            return json.loads(self.session_path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{self.session_path}: not valid JSON ({exc})") from None

    def create(self, session: dict) -> None:
        self.dir.mkdir(parents=True, exist_ok=False)
        self.traces_dir.mkdir()
        self.session = dict(session)
        self.write_session()
        with open(self.trials_path, "w", newline="") as fh:
            csv.writer(fh, lineterminator="\n").writerow(TRIAL_COLUMNS)
            fh.flush()
            os.fsync(fh.fileno())
        self.schedule_path.touch()
        _fsync_dir(self.dir)

    def write_session(self) -> None:
        atomic_write_bytes(self.session_path, (json.dumps(self.session, indent=2) + "\n").encode())

    def finish(self) -> None:
        self.session["finished_at"] = utc_now()
        self.write_session()

    # -- trials.csv ------------------------------------------------------
    def read_trials(self) -> list[dict]:
        """Read recorded attempts, dropping (and truncating away) a torn last line from a crash."""
        data = self.trials_path.read_bytes()
        if data and not data.endswith(b"\n"):
            cut = data.rfind(b"\n") + 1
            with open(self.trials_path, "r+b") as fh:
                fh.truncate(cut)
                fh.flush()
                os.fsync(fh.fileno())
            data = data[:cut]
        reader = csv.DictReader(io.StringIO(data.decode("utf-8")))
        if tuple(reader.fieldnames or ()) != TRIAL_COLUMNS:
            raise ValueError(f"{self.trials_path}: header {reader.fieldnames} is not {list(TRIAL_COLUMNS)}")
        return [parse_row(raw, f"{self.trials_path} line {i + 2}") for i, raw in enumerate(reader)]

    def append_trial(self, row: dict) -> None:
        """Append one attempt row, then flush and fsync (the row is on disk when this returns)."""
        with open(self.trials_path, "a", newline="") as fh:
            csv.DictWriter(fh, TRIAL_COLUMNS, lineterminator="\n").writerow(format_row(row))
            fh.flush()
            os.fsync(fh.fileno())

    # -- schedule.jsonl ----------------------------------------------------
    def log_event(self, event: dict) -> None:
        with open(self.schedule_path, "a") as fh:
            fh.write(json.dumps({"at": utc_now(), **event}) + "\n")
            fh.flush()
            os.fsync(fh.fileno())

    def read_events(self) -> list[dict]:
        events = []
        if not self.schedule_path.exists():
            return events
        for line in self.schedule_path.read_text().splitlines():
            try:
                events.append(json.loads(line))
            except json.JSONDecodeError:
                pass  # a torn last line from a crash; events are informative, rows are authoritative
        return events

    # -- traces ----------------------------------------------------------
    def trace_path(self, phase: str, trial: int, attempt: int) -> Path:
        return self.traces_dir / f"{phase}_t{trial:03d}_a{attempt:02d}.npz"

    def write_trace(self, phase: str, trial: int, attempt: int, arrays: dict) -> Path:
        path = self.trace_path(phase, trial, attempt)
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        atomic_write_bytes(path, buf.getvalue())
        return path
