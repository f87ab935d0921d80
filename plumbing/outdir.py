"""The one way a command writes its output folder: beside, then swapped in whole; one writer at a time.

``with output_folder(out, force) as w:`` ... write into ``w.path`` ... :

1. ``out`` is checked, refused whatever ``force``: a file, or a path below one; a study's data (a study
   folder, a subject folder, or inside one: :func:`plumbing.fileio.refuse_study_data`); one of the
   command's ``inputs``, or a folder that contains one or lies inside one (:func:`plumbing.fileio.refuse_inputs`).
2. An OS lock is taken: ``fcntl.flock`` on ``<parent>/.<name>.lock`` (:class:`FileLock`, the lock the
   study's subject folders use too), held until the block ends and dropped by the kernel when the
   process dies however it dies. A second writer of the same ``out`` is refused at once, naming the
   holder's pid (the kernel's, :func:`lock_holder_pid`) and host.
3. A whole folder (no ``products``) is replaced only when this program wrote it: it holds :data:`MARKER`
   (written into every such folder, naming the command; another command's is not replaced), or, written
   by a version before the marker, holds nothing but the command's own files (``own``). A folder holding
   anything else, or a subject folder at any depth, is refused with or without ``force``.
4. Earlier results are refused without ``force``, naming them (all of ``out``, or the entries that match
   the command's ``products`` when it names them).
5. Debris of an earlier writer of ``out`` that was killed (SIGKILL, power cut) is removed: its
   staging folders ``<parent>/.<name>.staging-*`` (and the older ``.<name>.identify-*``). Only the lock
   holder writes them, and it holds the lock now, so none of them belongs to a live run.
6. ``w.path`` is a new staging folder ``<parent>/.<name>.staging-XXXXXXXX`` on the same file system.
7. When the block ends without an exception the staging folder replaces ``out`` in one step (Linux
   ``renameat2(RENAME_EXCHANGE)``; elsewhere two renames): a reader sees the earlier folder or the new
   one, never a mixture. Files of ``out`` that are not the command's (``products``, when given) are
   carried over (hard links) before the swap. The earlier folder is then deleted.
8. On any exception (an error, Ctrl-C, SIGTERM/SIGHUP, which the block turns into
   :class:`plumbing.stopsignals.Terminated`) the staging folder is deleted and ``out`` is untouched;
   :meth:`OutputFolder.set_aside` instead keeps it beside ``out`` (``<out>.failed``, ``<out>.interrupted``)
   where its contents are worth keeping (a failed identification's finished stages, a partial run).

Signals are blocked during the swap and the clean-up, so neither is cut in two. What a SIGKILL leaves:
``out`` as it was (or the new one, if the kill came after the swap), plus the staging folder and the lock
file, both removed by the next run that writes ``out``. docs/architecture.md, "Output folders".
"""

from __future__ import annotations

import atexit
import ctypes
import datetime as _dt
import errno
import fcntl
import fnmatch
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

from .errors import UserError
from .fileio import check_output_dir, check_output_file, current_umask, fsync_dir, refuse_inputs
from .stopsignals import signals_blocked, stop_on_signals
from .studyfiles import study_data_within

#: output folders opened and not yet committed, discarded or set aside: a stop signal that lands between
#: ``open()`` and the caller's ``with`` (or any exit that skips ``__exit__``) must not leave a staging folder
_OPEN: set = set()


def _hostname() -> str:
    """This machine's name, as ``socket.gethostname()`` gives it (the kernel's node name) without importing
    socket (3-8 ms of every command that writes a folder)."""
    return os.uname().nodename


def _discard_open() -> None:
    """At exit (SystemExit from a stop signal included): delete the staging folders nobody finished."""
    for folder in list(_OPEN):
        folder.discard()


atexit.register(_discard_open)

#: the prefixes of the staging folders of ``out``: this module's, and ``devices identify``'s before it
STAGING_TAGS = ("staging", "identify")
#: the file in a folder this module wrote whole (no ``products``): which command wrote it and when. ``force``
#: replaces a folder only when it holds this file, or (written before the file existed) only the command's
#: own files (``own``); docs/architecture.md, "Output folders"
MARKER = ".hfam-output.json"

class OutputBusy(UserError):
    """Another process is writing the same output (its pid and host are in the message)."""


def lock_holder_pid(path) -> int | None:
    """The pid of the process holding an ``flock`` on the file ``path``, from the kernel's table of locks
    (Linux ``/proc/locks``: ``N: FLOCK ADVISORY WRITE <pid> <major>:<minor>:<inode> ...``), or None when no
    lock on it is listed (or the table cannot be read). The pid written in a lock file can be stale or
    forged; this one is the kernel's.
    """
    try:
        st = os.stat(path)
        with open("/proc/locks", encoding="ascii", errors="replace") as fh:
            table = fh.read()
    except OSError:
        return None
    key = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    for line in table.splitlines():
        parts = line.split()
        if len(parts) < 6 or parts[1] == "->" or parts[1] != "FLOCK":   # "->": a process waiting, not holding
            continue
        if parts[5] == key:
            try:
                pid = int(parts[4])
            except ValueError:
                return None
            return pid if pid > 0 else None
    return None


class FileLock:
    """Exclusive OS lock on a file: ``fcntl.flock``, released when the descriptor is closed or the process dies.

    The holder writes its pid and host into the file, which a refused second writer names.

    Parameters
    ----------
    path : str or Path
        The lock file (created if needed).
    unlink : bool
        Remove the file when released (a lock beside an output folder; safe: :meth:`acquire` retries
        when the file it locked was removed or replaced meanwhile). False: the file stays (a lock inside
        a folder that lives on, e.g. a study's subject folder).
    """

    def __init__(self, path, unlink: bool = False) -> None:
        self.path = Path(path)
        self.unlink = bool(unlink)
        self.fd: int | None = None

    @staticmethod
    def holder(path) -> str:
        """``"pid N on host H"``: the process that holds the lock on ``path`` now, as the kernel says
        (:func:`lock_holder_pid`, ``/proc/locks``), with the host the holder wrote; where the kernel does not
        say (not Linux, a network file system), the pid and host written in the file."""
        written = None
        try:
            info = json.loads(Path(path).read_text(encoding="utf-8"))
            written = (int(info["pid"]), str(info["host"]))
        except (OSError, ValueError, KeyError, TypeError):
            pass
        pid = lock_holder_pid(path)
        if pid is not None:
            host = written[1] if written is not None and written[0] == pid else _hostname()
            return f"pid {pid} on host {host}"
        if written is not None:
            return f"pid {written[0]} on host {written[1]} (as written in the lock file)"
        return "a process that has not written its pid yet"

    @staticmethod
    def busy(path) -> bool:
        """True when a process holds the lock file ``path`` (tested without creating or writing anything)."""
        try:
            fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
        except OSError:
            return False
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            return False
        except OSError:
            return True
        finally:
            os.close(fd)

    def try_acquire(self) -> bool:
        """Take the lock without waiting; False if another process holds it. Then write our pid and host."""
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                os.close(fd)
                if exc.errno in (errno.EWOULDBLOCK, errno.EACCES, errno.EAGAIN):
                    return False
                raise
            try:  # the holder before us may have removed (unlinked) the file we locked: lock the new one
                same = os.path.samestat(os.fstat(fd), os.stat(self.path))
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        data = json.dumps({"pid": os.getpid(), "host": _hostname()}).encode()
        os.ftruncate(fd, 0)
        os.pwrite(fd, data, 0)
        self.fd = fd
        return True

    def release(self) -> None:
        """Drop the lock (and remove the file if ``unlink``); harmless when not held."""
        if self.fd is None:
            return
        if self.unlink:
            try:
                os.unlink(self.path)  # while held: a process waiting on it then retries on a new file
            except OSError:
                pass
        os.close(self.fd)  # closing the last descriptor drops the flock
        self.fd = None


def read_marker(folder) -> dict | None:
    """The :data:`MARKER` record of ``folder`` (which command wrote it), or None when it has none (or an
    unreadable one, which does not vouch for the folder)."""
    try:
        record = json.loads((Path(folder) / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def _exchange(a: Path, b: Path) -> bool:
    """Swap the names of ``a`` and ``b`` in one step (Linux ``renameat2(RENAME_EXCHANGE)``); False if unsupported."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    renameat2.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint)
    at_fdcwd, rename_exchange = -100, 2
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):  # a file system without it
        return False
    raise OSError(err, os.strerror(err), str(b))


def _link_tree(src: Path, dst: Path) -> None:
    """Copy ``src`` (a file or a folder) to ``dst``, hard-linking files where the file system allows."""
    def link(s, d):
        try:
            os.link(s, d)
        except OSError:
            shutil.copy2(s, d)
    if src.is_dir() and not src.is_symlink():
        shutil.copytree(src, dst, symlinks=True, copy_function=link)
    elif src.is_symlink():
        os.symlink(os.readlink(src), dst)
    else:
        link(src, dst)


class OutputFolder:
    """An output folder being written: see the module doc. Made by :func:`output_folder`.

    Attributes
    ----------
    out : Path
        The folder the command writes.
    path : Path
        Where to write now: the staging folder beside ``out``.
    replacing : bool
        ``out`` held something (the user passed ``force``): it is replaced when the block ends.
    """

    def __init__(self, out, force: bool, products=None, flag: str = "--force", what: str = "--out",
                 in_place: bool = False, results: str = "earlier results", inputs=(), command: str | None = None,
                 own=None) -> None:
        self.out = Path(out)
        self.results = results
        self.in_place = bool(in_place)
        self.force = bool(force)
        self.products = tuple(products) if products is not None else None
        self.flag, self.what = flag, what
        self.inputs = tuple(inputs)
        self.command = command
        self.own = own if own is None or callable(own) else tuple(own)
        self.path: Path | None = None
        self.replacing = False
        self.done = False
        self._lock = None
        self._signals = None

    # -- opening ---------------------------------------------------------------------------------------
    def open(self) -> "OutputFolder":
        """Check ``out``, take the lock, refuse earlier results without ``force``, reclaim debris, make the staging folder."""
        out = self._check()
        if out.name in ("", ".", ".."):
            out = Path(os.path.abspath(out))
            self.out = out
        parent = out.parent
        parent.mkdir(parents=True, exist_ok=True)
        self._signals = stop_on_signals()
        self._signals.__enter__()
        try:
            self._lock = FileLock(parent / f".{out.name}.lock", unlink=True)
            if not self._lock.try_acquire():
                self._lock = None
                raise OutputBusy(f"{out} is being written by another run: {FileLock.holder(parent / f'.{out.name}.lock')}"
                                 f" (lock {parent / f'.{out.name}.lock'}); wait for it or choose another {self.what}")
            earlier = self.earlier_results()
            if earlier and not self.in_place and self.products is None:
                self._check_replaceable(out, earlier)
            if earlier and not self.force and not self.in_place:
                shown = ", ".join(earlier[:4]) + (f", ... ({len(earlier)} entries)" if len(earlier) > 4 else "")
                raise ValueError(f"{self.what} {out} already holds {self.results} ({shown}); not overwriting "
                                 f"them: choose another {self.what} or pass {self.flag} to replace them")
            self.replacing = bool(earlier)
            self.reclaimed = reclaim_staging(out)
            if self.in_place:
                out.mkdir(exist_ok=True)
                self.path = out
                return self
            with signals_blocked():
                self.path = Path(tempfile.mkdtemp(prefix=f".{out.name}.staging-", dir=parent))
                _OPEN.add(self)  # discarded at exit if the caller never reaches its ``with`` (a signal between)
                os.chmod(self.path, 0o777 & ~current_umask())
            if self.products is None and not isinstance(self, OutputFile):
                self._write_marker()   # the folder is this command's: its --force may replace it
        except BaseException:
            self.discard()   # a stop signal delivered as the staging folder was made: it goes too
            raise
        return self

    def _check(self) -> Path:
        """``out``, refused (ValueError) if it is a file or below one, is or lies inside a study's data
        (:func:`plumbing.fileio.refuse_study_data`), or is, contains or lies inside one of ``inputs``."""
        out = check_output_dir(self.out, what=self.what)
        refuse_inputs(out, self.inputs, self.what)
        return out

    def _check_replaceable(self, out: Path, earlier: list) -> None:
        """Refuse (ValueError) to replace a folder this program did not write, whatever ``force``: one
        without :data:`MARKER` unless it holds only the command's own files (``own``: a folder an older
        version wrote); one another command wrote; one that holds a study's subject folder."""
        written_by = read_marker(out)
        if written_by is None:
            foreign = [e for e in earlier if self.own is None or not any(
                fnmatch.fnmatch(e.rstrip("/"), pat) for pat in self.own)]
            if foreign:
                shown = ", ".join(foreign[:4]) + (f", ... ({len(foreign)} entries)" if len(foreign) > 4 else "")
                raise ValueError(f"{self.what} {out} holds files this program did not write ({shown}) and no "
                                 f"{MARKER} of an earlier run; not replacing it, with or without {self.flag}: "
                                 f"choose another {self.what} (or move those files away yourself)")
        elif self.command is not None and written_by.get("command") not in (None, self.command):
            raise ValueError(f"{self.what} {out} holds the results of '{written_by.get('command')}', not of "
                             f"'{self.command}'; not replacing them, with or without {self.flag}: choose another "
                             f"{self.what}")
        inner = study_data_within(out)
        if inner is not None:
            raise ValueError(f"{self.what} {out} contains the subject folder {inner} of a study; not replacing it, "
                             f"with or without {self.flag}: choose another {self.what}")

    def _write_marker(self) -> None:
        """:data:`MARKER` in the staging folder: the folder is this command's, replaceable by its ``force``."""
        record = {"command": self.command, "written_at": _dt.datetime.now(_dt.timezone.utc).isoformat(
            timespec="seconds").replace("+00:00", "Z"), "note": "written by this program; its --force may replace "
                  "this folder whole"}
        (self.path / MARKER).write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")

    def earlier_results(self) -> list[str]:
        """The entries of ``out`` that a new run replaces: all of them, or those matching ``products``
        (folders end in ``/``)."""
        if not self.out.is_dir():
            return []
        return sorted(p.name + ("/" if p.is_dir() else "") for p in self.out.iterdir() if p.name != MARKER and (
                      self.products is None or any(fnmatch.fnmatch(p.name, pat) for pat in self.products)))

    # -- ending -----------------------------------------------------------------------------------------
    def commit(self) -> Path:
        """Swap the staging folder in as ``out`` (module doc, 6); returns ``out``. Idempotent."""
        if self.done or self.in_place:
            self.done = True
            self._close()
            return self.out
        out, new = self.out, self.path
        with signals_blocked():
            if self.products is not None and out.is_dir():
                for entry in sorted(out.iterdir()):  # the user's own files in out stay
                    if not (new / entry.name).exists() and not any(fnmatch.fnmatch(entry.name, pat)
                                                                   for pat in self.products):
                        _link_tree(entry, new / entry.name)
            if out.is_dir() and _exchange(new, out):
                shutil.rmtree(new, ignore_errors=True)  # the earlier folder, now under the staging name
            elif out.is_dir():
                old = Path(tempfile.mkdtemp(prefix=f".{out.name}.staging-", dir=out.parent))
                os.rename(out, old / "old")   # a kill now leaves the earlier folder in old (reclaimed; documented)
                os.rename(new, out)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.rename(new, out)
            fsync_dir(out.parent)
            self.done = True
        self._close()
        return out

    def discard(self) -> None:
        """Delete the staging folder; ``out`` stays as it was. Idempotent."""
        if not self.done and self.path is not None and not self.in_place:
            with signals_blocked():
                shutil.rmtree(self.path, ignore_errors=True)
                self.done = True
        self._close()

    def set_aside(self, label: str) -> Path:
        """Keep what was written beside ``out`` as ``<out>.<label>`` (the next free ``.<label>.2``, ...)
        instead of deleting it; ``out`` stays as it was. Returns where it went (``out`` itself when the
        folder is written in place)."""
        if self.in_place:
            self.done = True
            self._close()
            return self.out
        kept = self.out.parent / f"{self.out.name}.{label}"
        n = 1
        with signals_blocked():
            while True:
                try:
                    os.rename(self.path, kept)  # fails if kept exists and is not empty
                    break
                except OSError:
                    if not kept.exists():
                        raise
                    n += 1
                    kept = self.out.parent / f"{self.out.name}.{label}.{n}"
            self.done = True
        self._close()
        return kept

    def _close(self) -> None:
        _OPEN.discard(self)
        if self._lock is not None:
            self._lock.release()
            self._lock = None
        if self._signals is not None:
            signals, self._signals = self._signals, None
            signals.__exit__(None, None, None)

    def __enter__(self) -> "OutputFolder":
        return self.open() if self.path is None else self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            self.commit()
        else:
            if isinstance(exc, OSError) and exc.errno is not None and self.path is not None:
                # a write that failed (a full disk): name the output, not the staging folder
                exc.filename = self.shown(exc.filename) if exc.filename else str(self.out)
            self.discard()
        return False

    def shown(self, path) -> str:
        """``path`` inside the staging folder, named as it would be in ``out`` (for messages)."""
        if isinstance(self, OutputFile):
            return str(self.out) if Path(path).parent == self._staging_dir else str(path)
        try:
            rel = Path(path).relative_to(self.path)
        except ValueError:
            return str(path)
        return str(self.out / rel) if str(rel) != "." else str(self.out)


class OutputFile(OutputFolder):
    """One output file written the same way (:func:`output_file`): ``path`` is ``<staging>/<name>``, renamed
    over ``out`` when the block ends without an exception (``os.replace``: atomic for a file)."""

    def _check(self) -> Path:
        """``out``, refused (ValueError) if it is a folder, below a file, a file of a study's data or one of
        ``inputs``, or exists and not ``force``, or exists and is not the command's own (``own``)."""
        out = check_output_file(self.out, True, what=self.what)
        refuse_inputs(out, self.inputs, self.what)
        if out.exists() and not self.force:
            raise ValueError(f"{self.what} {out} exists; not overwriting it: choose another {self.what} or pass "
                             f"{self.flag} to replace it")
        if out.exists() and self.own is not None and not self.own(out):
            raise ValueError(f"{self.what} {out} exists and is not {self.results} (what this command writes); not "
                             f"replacing it, with or without {self.flag}: choose another {self.what}")
        return out

    def _check_replaceable(self, out: Path, earlier: list) -> None:
        """Nothing more: a file's checks are in :meth:`_check` (``own``)."""

    def open(self) -> "OutputFile":
        """As :meth:`OutputFolder.open`; ``path`` is then the file to write."""
        super().open()
        self._staging_dir, self.path = self.path, self.path / self.out.name
        return self

    def earlier_results(self) -> list[str]:
        """``[name]`` when the file exists (it is replaced), else empty."""
        return [self.out.name] if self.out.is_file() else []

    def commit(self) -> Path:
        """Rename the file written over ``out``; returns ``out``. Idempotent."""
        if not self.done:
            with signals_blocked():
                os.replace(self.path, self.out)
                fsync_dir(self.out.parent)
                shutil.rmtree(self._staging_dir, ignore_errors=True)
                self.done = True
        self._close()
        return self.out

    def discard(self) -> None:
        """Delete what was written; ``out`` stays as it was. Idempotent."""
        if not self.done and self.path is not None:
            with signals_blocked():
                # stopped inside OutputFolder.open, ``path`` is still the staging folder itself
                shutil.rmtree(getattr(self, "_staging_dir", self.path), ignore_errors=True)
                self.done = True
        self._close()

    def set_aside(self, label: str) -> Path:
        """Not offered for a file: use :meth:`discard`."""
        raise NotImplementedError("an output file is written whole or not at all")


def output_file(out, force: bool, flag: str = "--force", what: str = "--out", inputs=(), own=None,
                results: str = "a result") -> OutputFile:
    """One output file, written beside and renamed into place, one writer at a time (module doc).

    ``with output_file(path, force) as w:`` write ``w.path`` (a file of the same name in a staging folder
    beside ``out``). Refused (ValueError): ``out`` is a folder, is below a file, is a file of a study's data,
    is one of ``inputs``, exists and not ``force``, or exists and ``own(out)`` is false (not a file this
    command writes: ``force`` replaces only those); :class:`OutputBusy` while another process writes it. An
    error, Ctrl-C or SIGTERM/SIGHUP leaves the earlier file as it was and nothing beside it.

    Parameters
    ----------
    inputs : iterable of (path, str)
        The files or folders the command reads, with their names for the message.
    own : callable or None
        ``own(path) -> bool``: whether an existing ``out`` is the command's kind of file (None: any file).
    results : str
        What the command's file is, for the message ("a timing-check record").

    Returns
    -------
    OutputFile
    """
    return OutputFile(out, force, flag=flag, what=what, inputs=inputs, own=own, results=results)


def output_folder(out, force: bool, products=None, flag: str = "--force", what: str = "--out",
                  in_place: bool = False, results: str = "earlier results", inputs=(), command: str | None = None,
                  own=None) -> OutputFolder:
    """The output folder ``out`` of a command, written beside and swapped in whole (module doc).

    Parameters
    ----------
    out : str or Path
        The folder the command writes.
    force : bool
        The user passed ``flag``: earlier results in ``out`` are replaced (once the new ones are whole).
    products : sequence of str, optional
        Glob patterns of what the command writes into ``out``; other files there are the user's and are
        kept. None (default): the whole folder is the command's.
    flag, what : str
        The option that allows replacing, and the one that gave ``out``, named in the messages.
    in_place : bool
        Write into ``out`` itself, under its lock (continuing an interrupted run there: ``--resume``);
        nothing is refused or swapped.
    results : str
        What the earlier results are, in the refusal ("a demo's results").
    inputs : iterable of (path, str)
        The files and folders the command reads, with the words that name them ("the data folder"): ``out``
        may not be, contain or lie inside any of them (:func:`plumbing.fileio.refuse_inputs`).
    command : str or None
        The command (``"analysis report"``), recorded in the folder's :data:`MARKER`; ``force`` does not
        replace a folder another command wrote.
    own : sequence of str or None
        Glob patterns of every file the command writes into a whole folder (no ``products``): a folder
        without :data:`MARKER` (an older version's) is replaced only when it holds nothing else.

    Returns
    -------
    OutputFolder
        A context manager (``with output_folder(...) as w``: write into ``w.path``); or call
        ``open()`` first, to refuse early, and use it as a context manager later.

    Raises
    ------
    ValueError
        ``out`` is a file, is below one, is or lies inside a study's data, is, contains or lies inside one
        of ``inputs``, holds earlier results and not ``force``, or (a whole folder) holds what this command
        did not write (module doc): refused with or without ``force``.
    OutputBusy
        Another process writes ``out`` now.
    """
    return OutputFolder(out, force, products=products, flag=flag, what=what, in_place=in_place,
                        results=results, inputs=inputs, command=command, own=own)


def reclaim_staging(out) -> list[Path]:
    """Remove the staging folders a killed writer of ``out`` left (call only with ``out``'s lock held)."""
    out = Path(out)
    gone = []
    if not out.parent.is_dir():
        return gone
    for entry in sorted(out.parent.iterdir()):
        if any(entry.name.startswith(f".{out.name}.{tag}-") for tag in STAGING_TAGS) and entry.is_dir():
            with signals_blocked():
                shutil.rmtree(entry, ignore_errors=True)
            gone.append(entry)
    return gone

