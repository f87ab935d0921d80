"""Crash-safe study data: one folder per subject (the files: plumbing.studyfiles; their format: docs/study.md).

``DATA/<subject>/session.json``   subject info and settings; ``finished_at`` null until done
``DATA/<subject>/trials.csv``     one row per attempt (or trial), appended, flushed and fsynced as it ends
``DATA/<subject>/schedule.jsonl`` planned orders, every redraw, familiarization end, invalid attempts, resumes
``DATA/<subject>/staircase_state.jsonl`` an adaptive session's staircase state after each trial
``DATA/<subject>/traces/<phase>_t<trial>_a<attempt>.npz``  full-rate traces of one attempt

This module is the only writer of a subject's folder: one row log (trials.csv, held open for the whole
session and checked before every write), one durable append for the JSON-lines files (written, flushed and
fsynced before the next step), and one torn-line policy for every file a crash can cut mid-line: a last line
without its newline is completed when it is whole (it parses), otherwise moved to ``<file>.torn`` with a note
naming the file and line, never thrown away.

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
``fcntl.flock`` for the whole run (it dies with the process) and removed when the
run ends; a second runner names the holder's pid (the kernel's, from its table of
locks) and host in its error.

Every file a session appends to (trials.csv, schedule.jsonl, staircase_state.jsonl)
is held open from the start (or its first line) to the end and checked before every
write: one moved, replaced, truncated or appended to by something else stops the
session before anything more is written.
"""

from __future__ import annotations

import datetime as _dt
import errno
import io
import json
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
from plumbing.studyfiles import (RATING, RATING_CORE_COLUMNS, SCHEDULE_JSONL, SESSION_JSON, TRACES_DIR, TRIALS_CSV,
                                 DamagedRow, RowFormat, parse_trials, read_session_json, trace_name)

LOCK_NAME = ".lock"
#: where the traces of an attempt that was run again after a kill are kept (``traces/interrupted/``)
INTERRUPTED_DIR = "interrupted"


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
    (:class:`plumbing.outdir.FileLock`, the lock of every output folder). The file is removed when the lock is
    released (a session's end, clean or not, but not a kill): no stale pid is left in the folder, and a runner
    that opened the file just before its removal locks a new one (:meth:`FileLock.try_acquire`).

    Parameters
    ----------
    folder : Path
        The subject folder (or the start-up folder that becomes it).
    """

    def __init__(self, folder: Path) -> None:
        super().__init__(Path(folder) / LOCK_NAME, unlink=True)

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


def _fd_path(fd: int) -> str:
    """Where the file open as ``fd`` is now (Linux ``/proc``; "" when unknown or deleted)."""
    try:
        path = os.readlink(f"/proc/self/fd/{fd}")
    except OSError:
        return ""
    return "" if path.endswith(" (deleted)") else path


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


def mend_last_line(path: Path, data: bytes, whole, then: str = "removed it and kept it in") -> bytes:
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
    then : str
        What the note says was done with a torn line (:func:`cut_torn_tail`).

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
    return cut_torn_tail(path, data, cut, line_no, then)


def _whole_json_line(head: bytes, last: bytes, where: str) -> bool:
    """Whether ``last`` (a JSON-lines file's last line without its newline) is a whole JSON object."""
    try:
        return isinstance(json.loads(last), dict)
    except (ValueError, RecursionError):
        return False


#: the files a session writes atomically (their half-written temporary files are removed on --resume)
_ATOMIC_PRODUCTS = (".json", ".jsonl", ".csv", ".npz")


def _is_session_temp(name: str) -> bool:
    target = atomic_temp_target(name)
    return target is not None and target.endswith(_ATOMIC_PRODUCTS)


class _Held:
    """A subject file held open for appending: its path, descriptor, (device, inode) and the size this runner
    left it at."""

    __slots__ = ("path", "fd", "ident", "size")

    def __init__(self, path: Path, fd: int, ident: tuple, size: int) -> None:
        self.path, self.fd, self.ident, self.size = path, fd, ident, size

    def check(self, rows_note: str | None) -> None:
        """Raise :class:`DataFileChanged` unless the path still names this file, with the size this runner left."""
        held = os.fstat(self.fd)
        try:
            now = os.stat(self.path)
        except FileNotFoundError:
            now = None
        if now is None or (now.st_dev, now.st_ino) != self.ident:
            where = _fd_path(self.fd)
            what = "was moved away or deleted" if now is None else "was replaced by another file"
            raise DataFileChanged(
                f"{self.path} {what} while the session ran"
                + (f" (the runner's file is now {where})" if where else "")
                + f"; the session stopped and wrote nothing more"
                + (f" ({rows_note})" if rows_note else "")
                + f". Put the runner's file back as {self.path} and continue with --resume")
        if held.st_size != self.size:
            change = "truncated" if held.st_size < self.size else "appended to by another program"
            raise DataFileChanged(
                f"{self.path} was {change} while the session ran ({held.st_size} bytes, the runner "
                f"wrote {self.size}); the session stopped and wrote nothing more. Check the file "
                "(docs/study.md, \"A damaged trials.csv\") and continue with --resume")

    def append(self, data: bytes) -> None:
        """Append ``data`` through the descriptor, fsync it, and account for its size."""
        view = memoryview(data)
        while view:
            n = os.write(self.fd, view)
            view = view[n:]
        os.fsync(self.fd)
        self.size += len(data)


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

    #: trials.csv's format (plumbing.studyfiles): the rating study's, or the experiment kind's
    rows: RowFormat = RATING

    def __init__(self, root, subject: str, resume: bool = False) -> None:
        self.subject = check_subject_id(subject)
        self.root = Path(root)
        self.dir = self.root / subject
        self.session_path = self.dir / SESSION_JSON
        self.trials_path = self.dir / TRIALS_CSV
        self.schedule_path = self.dir / SCHEDULE_JSONL
        self.traces_dir = self.dir / TRACES_DIR
        self.resume = resume
        self.session: dict | None = None
        self.lock: SubjectLock | None = None
        self.legacy_columns = False
        #: the files held open from the session's start to its end (trials.csv, schedule.jsonl, and
        #: staircase_state.jsonl once written): name -> :class:`_Held`
        self._held: dict = {}

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

    # -- the data files, held ---------------------------------------------------
    def hold_trials(self) -> None:
        """Open trials.csv and schedule.jsonl once for the whole session (appending) and remember which files
        they are and their sizes (a JSON-lines file written later, staircase_state.jsonl, is held from its
        first line on: :meth:`append_json_line`).

        Every later write first checks (:meth:`check_trials`) that each path still names its file with the
        size this runner left: a file moved away, replaced, truncated or appended to by something else stops
        the session before anything more is written."""
        self._hold(TRIALS_CSV)
        if (self.dir / SCHEDULE_JSONL).exists():
            self._hold(SCHEDULE_JSONL)

    def hold_file(self, name: str) -> None:
        """Hold the subject's file ``name`` (a JSON-lines file a kind reads on ``--resume``, once its torn last
        line was mended) like trials.csv, when it exists: a change from now on stops the session."""
        if (self.dir / name).exists():
            self._hold(name)

    def _hold(self, name: str, create: bool = False) -> "_Held":
        held = self._held.get(name)
        if held is None:
            flags = os.O_WRONLY | os.O_APPEND | os.O_CLOEXEC | (os.O_CREAT if create else 0)
            fd = os.open(self.dir / name, flags, 0o666)
            st = os.fstat(fd)
            held = self._held[name] = _Held(self.dir / name, fd, (st.st_dev, st.st_ino), st.st_size)
            _HELD_STORES.add(self)
        return held

    def close_trials(self) -> None:
        """Close the held files (harmless when none is held)."""
        for held in self._held.values():
            os.close(held.fd)
        self._held = {}
        _HELD_STORES.discard(self)

    def check_trials(self) -> None:
        """Raise :class:`DataFileChanged` unless every held file is still the file this runner holds, unchanged."""
        for held in self._held.values():
            held.check(self._rows_note() if held.path == self.trials_path else None)

    def _rows_note(self) -> str:
        held = self._held.get(TRIALS_CSV)
        return f"{held.size if held else 0} bytes of rows were written to it"

    def _append_held(self, data: bytes, name: str = TRIALS_CSV) -> None:
        """Append ``data`` through the held file ``name``, fsync it, and account for its size."""
        self._held[name].append(data)

    # -- session.json ----------------------------------------------------
    def load_session(self) -> dict:
        """Read ``session.json`` (plumbing.studyfiles.read_session_json: one line naming the file when damaged)."""
        return read_session_json(self.session_path)

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
            (tmp / TRACES_DIR).mkdir()
            self.session = dict(session)
            atomic_write_bytes(tmp / SESSION_JSON, (json.dumps(self.session, indent=2) + "\n").encode())
            crash_point("startup: session.json written")
            atomic_write_bytes(tmp / TRIALS_CSV, self.rows.header_line().encode())
            crash_point("startup: trials.csv written")
            lines = "".join(json.dumps({"at": utc_now(), **e}) + "\n" for e in events)
            atomic_write_bytes(tmp / SCHEDULE_JSONL, lines.encode())
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
        """Read recorded rows (:attr:`rows`' format, every value and the sequence checked). A last line without
        its newline is completed if it is a whole, valid row; only one that does not parse (torn by a crash) is
        dropped: copied to ``trials.csv.torn``, truncated away, with a note naming the file and line."""
        data = mend_last_line(self.trials_path, self.trials_path.read_bytes(), self.rows.whole_last_row)
        try:
            rows, header = parse_trials(self.rows, data, self.trials_path, self.subject)
        except DamagedRow as exc:
            raise ValueError(f"{exc}; {REPAIR_HINT}") from None
        self.legacy_columns = header == RATING_CORE_COLUMNS
        return rows

    def append_trial(self, row: dict) -> None:
        """Append one row through the held trials.csv, then fsync (the row is on disk when this returns);
        :class:`DataFileChanged` first if the file changed under the runner."""
        columns = RATING_CORE_COLUMNS if self.legacy_columns else None
        self.append_trial_text(self.rows.line(row, columns))
        where = f"{row['phase']} " if "phase" in row else "trial "
        crash_point(f"row written: {where}{row['trial']}/{row['attempt']}")

    def append_trial_text(self, text: str) -> None:
        """Append formatted CSV line(s) through the held trials.csv and fsync them; :class:`DataFileChanged`
        first if a held file changed under the runner (every kind of session writes its rows through this)."""
        self.hold_trials()
        self.check_trials()
        self._append_held(text.encode("utf-8"))

    # -- the JSON-lines files: schedule.jsonl, staircase_state.jsonl ------------------------------------------
    def append_json_line(self, name: str, line: dict, label: str) -> None:
        """Append ``line`` as one JSON line to the subject's file ``name`` through its held descriptor and fsync
        it (on disk when this returns); :class:`DataFileChanged` first if a held file changed under the runner.
        ``label`` names the durable step (:func:`crash_point`)."""
        held = self._hold(name, create=True) if self._held else None
        self.check_trials()
        data = (json.dumps(line) + "\n").encode("utf-8")
        if held is None:   # not a session's store (a caller that holds nothing): a plain durable append
            _append_durably(self.dir / name, data)
        else:
            held.append(data)
        crash_point(label)

    def read_json_lines(self, name: str, then: str = "removed it and kept it in") -> list[dict]:
        """The objects of the subject's JSON-lines file ``name``, in order ([] when it does not exist).

        A last line without its newline is completed when it parses; one that does not (torn by a crash) is
        moved to ``<name>.torn`` with a note (``then`` says what becomes of it).

        Raises
        ------
        ValueError
            A whole line that is not a JSON object (not a crash's work: the file was edited), naming it.
        """
        path = self.dir / name
        if not path.exists():
            return []
        data = mend_last_line(path, path.read_bytes(), _whole_json_line, then)
        out = []
        for number, line in enumerate(data.decode("utf-8", errors="replace").splitlines(), start=1):
            try:
                obj = json.loads(line)
            except ValueError as exc:
                raise ValueError(f"{path} line {number}: not a JSON object ({exc}); the file is damaged") from None
            except RecursionError:
                raise ValueError(f"{path} line {number}: not a JSON object (nested too deeply); the file is "
                                 "damaged") from None
            if not isinstance(obj, dict):
                raise ValueError(f"{path} line {number}: not a JSON object; the file is damaged")
            out.append(obj)
        return out

    def log_event(self, event: dict) -> None:
        """Append one event (with its UTC time) to the schedule log and fsync it."""
        self.append_json_line(SCHEDULE_JSONL, {"at": utc_now(), **event}, f"event logged: {event.get('event')}")

    def read_events(self) -> list[dict]:
        """The schedule log's events, in order (:meth:`read_json_lines`: a torn last line is kept aside)."""
        return self.read_json_lines(SCHEDULE_JSONL)

    # -- traces ----------------------------------------------------------
    def _keep_aside(self, path: Path) -> Path:
        """Move the trace ``path`` of an earlier, unrecorded attempt into ``traces/interrupted/``; returns where."""
        aside = self.traces_dir / INTERRUPTED_DIR
        aside.mkdir(exist_ok=True)
        target, n = aside / path.name, 1
        while target.exists():
            n += 1
            target = aside / f"{path.stem}.{n}{path.suffix}"
        os.rename(path, target)
        fsync_dir(aside)
        fsync_dir(self.traces_dir)
        return target

    def trace_path(self, phase: str, trial: int, attempt: int) -> Path:
        """Path of the trace file of one attempt (``<phase>_t<trial>_a<attempt>.npz``)."""
        return self.traces_dir / trace_name(phase, trial, attempt)

    def write_trace(self, phase: str, trial: int, attempt: int, arrays: dict) -> Path:
        """Write one attempt's arrays (``np.savez``) atomically; returns the path.

        A trace already there belongs to an attempt run before a kill that has no row and no event (cut short,
        or its event line torn): it is moved to ``traces/interrupted/`` first (``<name>``, then ``<name>.2.npz``,
        ...), never overwritten."""
        self.check_trials()  # a session whose trials.csv is gone writes no trace either
        path = self.trace_path(phase, trial, attempt)
        if path.exists():
            self._keep_aside(path)
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        atomic_write_bytes(path, buf.getvalue())
        crash_point(f"trace written: {path.name}")
        return path
