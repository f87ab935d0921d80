"""Crash-safe study data: one folder per subject (format in docs/study.md).

``DATA/<subject>/session.json``   subject info and settings; ``finished_at`` null until done
``DATA/<subject>/trials.csv``     one row per attempt, appended, flushed and fsynced as it ends
``DATA/<subject>/schedule.jsonl`` planned orders, every redraw, familiarization end, resumes
``DATA/<subject>/traces/<phase>_t<trial>_a<attempt>.npz``  full-rate traces of one attempt

Write order per attempt: trace file (atomic rename), then the CSV row. A row
therefore always has its trace; a trace without a row belongs to an attempt
that was interrupted and is re-run (and rewritten) on ``--resume``. The row
also says whether it ended familiarization (``ends_familiarization``), so the
phase transition is in the same durable step as the attempt.

Start-up is atomic: the folder is built as ``DATA/.<subject>.starting-*``
(``session.json``, ``trials.csv`` header, ``schedule.jsonl`` with the plan,
``traces/``) and renamed into place; a kill before the rename leaves no
subject folder (the debris is ignored and cleaned by the next start).

One writer per subject: ``DATA/<subject>/.lock`` is held with an exclusive
``fcntl.flock`` for the whole run (it dies with the process); it holds the pid
and host of the holder, which a second runner names in its error.
"""

from __future__ import annotations

import csv
import datetime as _dt
import errno
import io
import json
import math
import os
import re
import shutil
import signal
import tempfile
from pathlib import Path

import numpy as np

from plumbing.fileio import atomic_temp_target, current_umask, fsync_dir
from plumbing.fileio import atomic_write_bytes as _atomic_write_bytes
from plumbing.outdir import FileLock

from .choices import EXPERIENCE  # noqa: F401 (study.data.EXPERIENCE, as before: the choices live in study.choices)

TRIAL_COLUMNS = (
    "subject", "phase", "trial", "attempt", "sample", "kind", "rating", "rejected", "saturated", "overpowered",
    "valid", "n_taps", "incoming_velocity_mean_m_s", "penetration_mean_m", "incoming_velocities_m_s",
    "penetration_depths_m", "started_at", "duration_s", "ends_familiarization",
)
# sessions written before ``ends_familiarization`` existed (their transition is in schedule.jsonl)
LEGACY_TRIAL_COLUMNS = TRIAL_COLUMNS[:-1]
LOCK_NAME = ".lock"


class SubjectBusy(ValueError):
    """Another runner holds the subject's lock (its pid and host are in the message)."""


_CRASH_COUNT = 0


def crash_point(name: str) -> None:
    """Fault injection for the kill tests: SIGKILL this process at the N-th durable step.

    With ``STUDY_CRASH_AT=N`` in the environment the N-th call (counted from 1 over the process's life)
    kills the process with SIGKILL, exactly as a power cut or ``kill -9`` would at that point; with
    ``STUDY_CRASH_LOG=<file>`` every call appends ``name`` to that file (to count a session's steps).
    Without these variables this does nothing.
    """
    global _CRASH_COUNT
    _CRASH_COUNT += 1
    log = os.environ.get("STUDY_CRASH_LOG")
    if log:
        with open(log, "a") as fh:
            fh.write(f"{_CRASH_COUNT} {name}\n")
    at = os.environ.get("STUDY_CRASH_AT")
    if at and int(at) == _CRASH_COUNT:
        os.kill(os.getpid(), signal.SIGKILL)


_HELD_LOCKS: set = set()
_HELD_STORES: set = set()


def release_all_locks() -> None:
    """Drop every subject lock and held trials.csv this process has (the end of a run inside a longer-lived
    process, e.g. tests)."""
    for store in list(_HELD_STORES):
        store.close_trials()
    for lock in list(_HELD_LOCKS):
        lock.release()


class SubjectLock(FileLock):
    """Exclusive per-subject OS lock: ``fcntl.flock`` on ``<folder>/.lock``, released when the process dies
    (:class:`plumbing.outdir.FileLock`, the lock of every output folder; this one stays in the folder).

    Parameters
    ----------
    folder : Path
        The subject folder (or the start-up folder that becomes it).
    """

    def __init__(self, folder: Path) -> None:
        super().__init__(Path(folder) / LOCK_NAME)

    def acquire(self, subject: str) -> None:
        """Take the lock or raise :class:`SubjectBusy` naming the holder; then write our pid and host."""
        if not self.try_acquire():
            raise SubjectBusy(f"subject {subject!r} is in use by another runner: {self.holder(self.path)} "
                              f"(lock {self.path}); nothing was written")
        os.fsync(self.fd)
        _HELD_LOCKS.add(self)

    def release(self) -> None:
        """Drop the lock (closing our descriptor); harmless when not held."""
        super().release()
        _HELD_LOCKS.discard(self)

SUBJECT_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")
#: names Windows reserves for devices, in any case (a folder ``DATA/CON`` cannot be created or copied there)
RESERVED_NAMES = re.compile(r"^(CON|PRN|AUX|NUL|COM[0-9]|LPT[0-9])$", re.IGNORECASE)
PHASES = ("familiarization", "demonstration", "testing")
KINDS = ("real", "virtual")
RATING_MIN, RATING_MAX = 1, 7
#: what to do about a damaged trials.csv (docs/study.md, "A damaged trials.csv")
REPAIR_HINT = ("trials.csv is damaged; nothing was changed. Repair (docs/study.md, \"A damaged trials.csv\"): "
               "restore it from a backup, or keep a copy and move this line and every line after it to "
               "trials.csv.damaged; --resume then runs those attempts again")


class DataFileChanged(ValueError):
    """The session's trials.csv was moved, replaced, truncated or appended to by something else while the
    runner held it; the session stopped before writing anything more."""


def utc_now() -> str:
    """ISO 8601 UTC timestamp with milliseconds."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def check_subject_id(subject: str) -> str:
    """Refuse ids that could escape the data folder or are awkward as folder names."""
    if not isinstance(subject, str) or not SUBJECT_RE.match(subject):
        raise ValueError(f"subject id {subject!r} is not allowed: use 1-64 letters, digits, '_' or '-' "
                         "(no path characters such as '/', '\\\\', '..', spaces)")
    if RESERVED_NAMES.match(subject):
        raise ValueError(f"subject id {subject!r} is not allowed: Windows reserves it for a device (CON, PRN, "
                         "AUX, NUL, COM1-9, LPT1-9), so its folder could not be copied there; choose another id")
    return subject


_fsync_dir = fsync_dir


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a unique, fsynced temporary file and rename; fsync the folder."""
    _atomic_write_bytes(path, data)


def _fmt_bool(value: bool) -> str:
    return "true" if value else "false"


def _fmt_float(value: float) -> str:
    return "" if value is None or value != value else repr(float(value))


def format_row(row: dict) -> dict:
    """Turn an attempt record into CSV strings (lists ';'-joined, booleans true|false, rating empty if None)."""
    out = {}
    for key in TRIAL_COLUMNS:
        value = row.get(key) if key == "ends_familiarization" else row[key]
        if key in ("rejected", "saturated", "overpowered", "valid"):
            out[key] = _fmt_bool(value)
        elif key in ("incoming_velocities_m_s", "penetration_depths_m"):
            out[key] = ";".join(repr(float(v)) for v in value)
        elif key in ("incoming_velocity_mean_m_s", "penetration_mean_m", "duration_s"):
            out[key] = _fmt_float(value)
        elif key == "rating":
            out[key] = "" if value is None else str(int(value))
        elif key == "ends_familiarization":
            out[key] = _fmt_bool(bool(row.get(key, False)))
        else:
            out[key] = str(value)
    return out


def _number(text: str, key: str, empty_ok: bool) -> float | None:
    """A finite number >= 0 written by :func:`format_row` (``None`` for an empty cell when ``empty_ok``)."""
    if text == "" and empty_ok:
        return None
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{key}={text!r} is not a number") from None
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{key}={text!r} must be a finite number >= 0")
    return value


def _check_values(raw: dict, row: dict) -> None:
    """Ranges and consistency of one parsed row (what :func:`format_row` can write); ValueError otherwise."""
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
    for key in ("incoming_velocity_mean_m_s", "penetration_mean_m"):
        _number(raw[key], key, empty_ok=True)
    _number(raw["duration_s"], "duration_s", empty_ok=True)
    for key in ("incoming_velocities_m_s", "penetration_depths_m"):
        values = [_number(x, key, empty_ok=False) for x in raw[key].split(";")] if raw[key] else []
        if len(values) != row["n_taps"]:
            raise ValueError(f"{key} lists {len(values)} values but n_taps={row['n_taps']}")
    try:
        _dt.datetime.fromisoformat(raw["started_at"])
    except (TypeError, ValueError):
        raise ValueError(f"started_at={raw['started_at']!r} is not an ISO 8601 time") from None


def parse_row(raw: dict, where: str) -> dict:
    """Inverse of :func:`format_row`, checking every field (count, type, range, consistency: what the
    runner can write); errors name ``where`` (file and line)."""
    if None in raw:  # csv.DictReader puts the fields beyond the header under the key None
        raise ValueError(f"{where}: {len(raw) - 1 + len(raw[None])} fields, the header has {len(raw) - 1}")
    if any(value is None for value in raw.values()):  # ... and fills a short row's missing fields with None
        n = sum(value is not None for value in raw.values())
        raise ValueError(f"{where}: {n} fields, the header has {len(raw)}")
    row = dict(raw)
    row.setdefault("ends_familiarization", None)  # legacy file: the transition is in schedule.jsonl
    try:
        if row["ends_familiarization"] is not None:
            if raw["ends_familiarization"] not in ("true", "false"):
                raise ValueError(f"ends_familiarization={raw['ends_familiarization']!r} is not true|false")
            row["ends_familiarization"] = raw["ends_familiarization"] == "true"
        for key in ("rejected", "saturated", "overpowered", "valid"):
            if raw[key] not in ("true", "false"):
                raise ValueError(f"{key}={raw[key]!r} is not true|false")
            row[key] = raw[key] == "true"
        row["trial"] = int(raw["trial"])
        row["attempt"] = int(raw["attempt"])
        row["rating"] = int(raw["rating"]) if raw["rating"] else None
        row["n_taps"] = int(raw["n_taps"])
        _check_values(raw, row)
    except (KeyError, ValueError) as exc:
        raise ValueError(f"{where}: bad value ({exc})") from None
    return row


def _check_sequence(row: dict, where: str, seen: set, attempts: dict, phase_at: int) -> None:
    """The row continues the file's sequence: phases in order (familiarization, demonstration, testing),
    each ``(phase, trial, attempt)`` once, and a trial's attempts numbered 1, 2, ... as they were run."""
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


def _fd_path(fd: int) -> str:
    """Where the file open as ``fd`` is now (Linux ``/proc``; "" when unknown or deleted)."""
    try:
        path = os.readlink(f"/proc/self/fd/{fd}")
    except OSError:
        return ""
    return "" if path.endswith(" (deleted)") else path


def _whole_last_row(head: bytes, last: bytes, where: str) -> bool:
    """Whether ``last`` (a trials.csv line without its newline, after the lines ``head``) is a complete,
    valid row: as many fields as the header and every value parses."""
    try:
        head_text, last_text = head.decode("utf-8"), last.decode("utf-8")
        header = next(csv.reader(io.StringIO(head_text)), None)
        if header is None:                          # the header line itself lacks its newline
            return tuple(next(csv.reader([last_text]), ())) in (TRIAL_COLUMNS, LEGACY_TRIAL_COLUMNS)
        fields = list(csv.reader(io.StringIO(last_text + "\n")))
        if len(fields) != 1 or len(fields[0]) != len(header):
            return False
        parse_row(dict(zip(header, fields[0])), where)
        return True
    except (UnicodeDecodeError, ValueError, csv.Error):
        return False


def _append_durably(path: Path, data: bytes) -> None:
    """Append ``data`` to ``path`` and fsync it before returning."""
    with open(path, "ab") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def cut_torn_tail(path: Path, data: bytes, keep: int, line_no: int, then: str = "removed it and kept it in") -> bytes:
    """Move ``data[keep:]`` (the tail of ``path`` a crash tore) to ``<path>.torn`` and truncate ``path`` to
    ``keep`` bytes, durably, with a note naming file and line. Returns ``data[:keep]``.

    The torn bytes are appended to the ``.torn`` file, never thrown away (a person can read them).
    """
    torn = path.with_name(path.name + ".torn")
    _append_durably(torn, data[keep:].rstrip(b"\n") + b"\n")
    with open(path, "r+b") as fh:
        fh.truncate(keep)
        fh.flush()
        os.fsync(fh.fileno())
    print(f"note: {path} line {line_no} was torn by a crash while it was written (it does not parse); "
          f"{then} {torn}")
    return data[:keep]


def mend_last_line(path: Path, data: bytes, whole) -> bytes:
    """A CSV file's last line without its newline (a crash while it was written), mended on disk.

    Parameters
    ----------
    path : Path
        The file ``data`` was read from.
    data : bytes
        Its content.
    whole : callable
        ``whole(head, last, where) -> bool``: whether ``last`` (the line without its newline, after the
        lines ``head``) is a complete, valid row; ``where`` names file and line for its messages.

    Returns
    -------
    bytes
        The content as it now is on disk: a whole last row gets its newline; one that does not parse is
        moved to ``<path>.torn`` (:func:`cut_torn_tail`).
    """
    if not data or data.endswith(b"\n"):
        return data
    cut = data.rfind(b"\n") + 1
    line_no = data.count(b"\n") + 1
    if whole(data[:cut], data[cut:], f"{path} line {line_no}"):
        _append_durably(path, b"\n")
        return data + b"\n"
    return cut_torn_tail(path, data, cut, line_no)


#: the files a session writes atomically (their half-written temporary files are removed on --resume)
_ATOMIC_PRODUCTS = (".json", ".jsonl", ".csv", ".npz")


def _is_session_temp(name: str) -> bool:
    target = atomic_temp_target(name)
    return target is not None and target.endswith(_ATOMIC_PRODUCTS)


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

    #: the header ``create`` writes to trials.csv (a psychophysics session's store has its own columns)
    trial_columns = TRIAL_COLUMNS

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
        self.lock: SubjectLock | None = None
        self.legacy_columns = False
        self._trials_fd: int | None = None   # trials.csv, held open from the session's start to its end
        self._trials_id: tuple | None = None  # its (device, inode)
        self._trials_size = 0                 # its size as this runner left it

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
        self._clean_startup_debris()
        if self.dir.is_dir() and not self.session_path.is_file() and self._only_startup_debris():
            # a start-up killed by an older version: no session.json, no attempt; keep it aside, never delete
            aside = self.root / f".{self.subject}.abandoned-{_dt.datetime.now():%Y%m%dT%H%M%S}-{os.getpid()}"
            os.rename(self.dir, aside)
            print(f"note: {self.dir} held an interrupted start-up with no recorded attempt; moved to {aside}")
        if self.dir.is_dir() and self.resume:
            self.lock = SubjectLock(self.dir)
            self.lock.acquire(self.subject)  # SubjectBusy names the holder
            self._remove_partial_writes()
        if self.resume:
            if not self.session_path.is_file():
                raise FileNotFoundError(f"--resume: no session to resume at {self.session_path} (a start-up "
                                        "interrupted before the session was complete leaves no subject folder: "
                                        "start the session again without --resume)")
            session = self.load_session()
            if session.get("finished_at"):
                raise ValueError(f"--resume: session {self.session_path} already finished at "
                                 f"{session['finished_at']}")
        elif self.dir.exists():
            lock_path = self.dir / LOCK_NAME
            busy = f" (in use right now by {SubjectLock.holder(lock_path)})" if SubjectLock.busy(lock_path) else ""
            raise ValueError(f"subject {self.subject!r} already has data in {self.dir}{busy}; "
                             "use --resume to continue it or choose another subject id (nothing was overwritten)")

    def _remove_partial_writes(self) -> None:
        """Remove the temporary files of atomic writes that a killed runner left half written
        (``plumbing.fileio.atomic_open``: ``<name>.<8 random characters>.tmp`` for a file the session
        writes, never renamed into place, so never data). Only that pattern: a user's own ``*.tmp`` file
        is kept. Called with the subject's lock held: no other runner is writing them."""
        stale = [p for p in self.dir.rglob("*.tmp") if p.is_file() and _is_session_temp(p.name)]
        for p in stale:
            p.unlink()
        if stale:
            print(f"note: removed {len(stale)} half-written temporary file(s) of the interrupted run "
                  f"({', '.join(p.name for p in stale[:3])}{', ...' if len(stale) > 3 else ''})")

    def _startup_dirs(self) -> list[Path]:
        return sorted(self.root.glob(f".{self.subject}.starting-*"))

    def _clean_startup_debris(self) -> None:
        """Remove start-up folders of this subject left by killed runners (those whose lock is free)."""
        for folder in self._startup_dirs():
            lock = SubjectLock(folder)
            try:
                lock.acquire(self.subject)
            except (SubjectBusy, OSError):
                continue  # another runner is starting this subject right now
            try:
                shutil.rmtree(folder, ignore_errors=True)
            finally:
                lock.release()

    def _only_startup_debris(self) -> bool:
        """True when the subject folder holds no session.json, no trace and no attempt row."""
        if self.session_path.exists() or any(self.traces_dir.glob("*.npz")):
            return False
        if self.trials_path.exists():
            lines = [ln for ln in self.trials_path.read_bytes().split(b"\n") if ln.strip()]
            if len(lines) > 1:
                return False
        return True

    def release(self) -> None:
        """Drop the subject lock and close trials.csv (both also done by the OS when the process dies)."""
        self.close_trials()
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    # -- the data file, held --------------------------------------------------
    def hold_trials(self) -> None:
        """Open trials.csv once for the whole session (appending) and remember which file it is and its size.

        Every later write first checks (:meth:`check_trials`) that the path still names this file with
        the size this runner left: a file moved away, replaced, truncated or appended to by something else
        stops the session before anything more is written (issue 38)."""
        if self._trials_fd is not None:
            return
        fd = os.open(self.trials_path, os.O_WRONLY | os.O_APPEND | os.O_CLOEXEC)
        st = os.fstat(fd)
        self._trials_fd, self._trials_id, self._trials_size = fd, (st.st_dev, st.st_ino), st.st_size
        _HELD_STORES.add(self)

    def close_trials(self) -> None:
        """Close the held trials.csv (harmless when not held)."""
        if self._trials_fd is not None:
            os.close(self._trials_fd)
            self._trials_fd = None
        _HELD_STORES.discard(self)

    def check_trials(self) -> None:
        """Raise :class:`DataFileChanged` unless trials.csv is still the file this runner holds, unchanged."""
        fd = self._trials_fd
        if fd is None:
            return
        held = os.fstat(fd)
        try:
            now = os.stat(self.trials_path)
        except FileNotFoundError:
            now = None
        if now is None or (now.st_dev, now.st_ino) != self._trials_id:
            where = _fd_path(fd)
            what = ("was moved away or deleted" if now is None else "was replaced by another file")
            raise DataFileChanged(
                f"{self.trials_path} {what} while the session ran"
                + (f" (the runner's file is now {where})" if where else "")
                + f"; the session stopped and wrote nothing more ({self._rows_note()}). Put the runner's file "
                f"back as {self.trials_path} and continue with --resume")
        if held.st_size != self._trials_size:
            change = "truncated" if held.st_size < self._trials_size else "appended to by another program"
            raise DataFileChanged(
                f"{self.trials_path} was {change} while the session ran ({held.st_size} bytes, the runner "
                f"wrote {self._trials_size}); the session stopped and wrote nothing more. Check the file "
                "(docs/study.md, \"A damaged trials.csv\") and continue with --resume")

    def _rows_note(self) -> str:
        return f"{self._trials_size} bytes of rows were written to it"

    def _append_held(self, data: bytes) -> None:
        """Append ``data`` through the held descriptor, fsync it, and account for its size."""
        view = memoryview(data)
        while view:
            n = os.write(self._trials_fd, view)
            view = view[n:]
        os.fsync(self._trials_fd)
        self._trials_size += len(data)

    # -- session.json ----------------------------------------------------
    def load_session(self) -> dict:
        """Read ``session.json``; a binary, truncated or non-JSON file gives one line naming the file."""
        try:
            data = self.session_path.read_bytes()
        except OSError as exc:
            raise ValueError(f"{self.session_path}: cannot be read ({exc.strerror})") from None
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ValueError(f"{self.session_path}: not a text file (byte {exc.start} is not UTF-8); "
                             "session.json is damaged") from None
        if not text.strip():
            raise ValueError(f"{self.session_path}: empty file; session.json is damaged")
        try:
            session = json.loads(text)
        except json.JSONDecodeError as exc:
            truncated = exc.pos >= len(text.rstrip())
            raise ValueError(f"{self.session_path}: {'truncated' if truncated else 'not valid'} JSON "
                             f"(line {exc.lineno}: {exc.msg})") from None
        if not isinstance(session, dict):
            raise ValueError(f"{self.session_path}: expected a JSON object, found {type(session).__name__}")
        return session

    def create(self, session: dict, events=()) -> None:
        """Create the subject folder atomically: build it under a temporary name, then rename it into place.

        The subject lock is taken inside the temporary folder before anything else and moves with it.
        ``events`` (dicts) start ``schedule.jsonl`` (the planned orders).
        """
        tmp = Path(tempfile.mkdtemp(prefix=f".{self.subject}.starting-", dir=self.root))
        os.chmod(tmp, 0o777 & ~current_umask())
        lock = SubjectLock(tmp)
        lock.acquire(self.subject)
        crash_point("startup: folder made")
        try:
            (tmp / "traces").mkdir()
            self.session = dict(session)
            atomic_write_bytes(tmp / "session.json", (json.dumps(self.session, indent=2) + "\n").encode())
            crash_point("startup: session.json written")
            buf = io.StringIO()
            csv.writer(buf, lineterminator="\n").writerow(self.trial_columns)
            atomic_write_bytes(tmp / "trials.csv", buf.getvalue().encode())
            crash_point("startup: trials.csv written")
            lines = "".join(json.dumps({"at": utc_now(), **e}) + "\n" for e in events)
            atomic_write_bytes(tmp / "schedule.jsonl", lines.encode())
            crash_point("startup: schedule.jsonl written")
            fsync_dir(tmp)
            try:
                os.rename(tmp, self.dir)
            except OSError as exc:
                if exc.errno in (errno.EEXIST, errno.ENOTEMPTY):
                    raise SubjectBusy(f"subject {self.subject!r} was created by another runner at the same time: "
                                      f"{SubjectLock.holder(self.dir / LOCK_NAME)}; nothing was written") from None
                raise
            fsync_dir(self.root)
        except BaseException:
            lock.release()
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        lock.path = self.dir / LOCK_NAME
        self.lock = lock
        crash_point("startup: subject folder in place")

    def write_session(self) -> None:
        """Rewrite session.json atomically (a crash leaves the old or the new file, never half)."""
        self.check_trials()
        atomic_write_bytes(self.session_path, (json.dumps(self.session, indent=2) + "\n").encode())
        crash_point("session.json rewritten")

    def finish(self) -> None:
        """Record the end time in session.json."""
        self.session["finished_at"] = utc_now()
        self.write_session()

    # -- trials.csv ------------------------------------------------------
    def read_trials(self) -> list[dict]:
        """Read recorded attempts. A last line without its newline is completed if it is a whole, valid
        row; only one that does not parse (torn by a crash) is dropped: copied to ``trials.csv.torn``,
        truncated away, with a note naming the file and line."""
        data = mend_last_line(self.trials_path, self.trials_path.read_bytes(), _whole_last_row)
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError as exc:
            line = data[:exc.start].count(b"\n") + 1
            raise ValueError(f"{self.trials_path} line {line}: not UTF-8 text (byte {exc.start}: "
                             f"{data[exc.start:exc.start + 1]!r}); trials.csv is damaged") from None
        reader = csv.DictReader(io.StringIO(text))
        try:
            header = tuple(reader.fieldnames or ())
        except csv.Error as exc:
            raise ValueError(f"{self.trials_path} line 1: not CSV ({exc}); {REPAIR_HINT}") from None
        self.legacy_columns = header == LEGACY_TRIAL_COLUMNS
        if header != TRIAL_COLUMNS and not self.legacy_columns:
            raise ValueError(f"{self.trials_path}: header {reader.fieldnames} is not {list(TRIAL_COLUMNS)}")
        rows, seen, attempts, phase_at = [], set(), {}, 0
        try:
            for raw in reader:
                where = f"{self.trials_path} line {reader.line_num}"
                row = parse_row(raw, where)
                if row["subject"] != self.subject:
                    raise ValueError(f"{where}: subject={row['subject']!r}, but the session is {self.subject!r}")
                _check_sequence(row, where, seen, attempts, phase_at)
                phase_at = PHASES.index(row["phase"])
                rows.append(row)
        except csv.Error as exc:
            raise ValueError(f"{self.trials_path} line {reader.line_num}: not CSV ({exc}); {REPAIR_HINT}") from None
        except ValueError as exc:
            raise ValueError(f"{exc}; {REPAIR_HINT}") from None
        return rows

    def append_trial(self, row: dict) -> None:
        """Append one attempt row through the held trials.csv, then fsync (the row is on disk when this
        returns); :class:`DataFileChanged` first if the file changed under the runner."""
        formatted = format_row(row)
        columns = LEGACY_TRIAL_COLUMNS if self.legacy_columns else TRIAL_COLUMNS
        buf = io.StringIO()
        csv.DictWriter(buf, columns, lineterminator="\n", extrasaction="ignore").writerow(formatted)
        self.append_trial_text(buf.getvalue())
        crash_point(f"row written: {row['phase']} {row['trial']}/{row['attempt']}")

    def append_trial_text(self, text: str) -> None:
        """Append formatted CSV line(s) through the held trials.csv and fsync them; :class:`DataFileChanged`
        first if the file changed under the runner (every kind of session writes its rows through this)."""
        self.hold_trials()
        self.check_trials()
        self._append_held(text.encode("utf-8"))

    # -- schedule.jsonl ----------------------------------------------------
    def log_event(self, event: dict) -> None:
        """Append one event (with its UTC time) to the schedule log and fsync it."""
        self.check_trials()
        with open(self.schedule_path, "a") as fh:
            fh.write(json.dumps({"at": utc_now(), **event}) + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        crash_point(f"event logged: {event.get('event')}")

    def read_events(self) -> list[dict]:
        """The schedule log's events, in order; a torn last line (a crash mid-write) is skipped."""
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
        """Path of the trace file of one attempt (``<phase>_t<trial>_a<attempt>.npz``)."""
        return self.traces_dir / f"{phase}_t{trial:03d}_a{attempt:02d}.npz"

    def write_trace(self, phase: str, trial: int, attempt: int, arrays: dict) -> Path:
        """Write one attempt's arrays (``np.savez``) atomically; returns the path."""
        self.check_trials()  # a session whose trials.csv is gone writes no trace either
        path = self.trace_path(phase, trial, attempt)
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        atomic_write_bytes(path, buf.getvalue())
        crash_point(f"trace written: {path.name}")
        return path
