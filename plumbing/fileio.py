"""Small file helpers shared by the writers and readers of devices (and the packages built on it)."""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

from .studyfiles import study_data_at


def user_cache_dir() -> Path:
    """The project's per-user cache: ``$XDG_CACHE_HOME/hfam-haptics`` or ``~/.cache/hfam-haptics``."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hfam-haptics"




def current_umask() -> int:
    """The process's umask, read without changing it (``/proc/self/status``; fallback: set and restore).

    Returns
    -------
    int
        e.g. ``0o022``.
    """
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    old = os.umask(0o022)
    os.umask(old)
    return old


def fsync_dir(path) -> None:
    """fsync a directory so that a rename or a new entry in it survives a power loss (best effort)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


#: the name :func:`atomic_open` gives its temporary file: ``mkstemp(prefix=<name> + ".", suffix=".tmp")``,
#: i.e. ``<name>.<8 of a-z, 0-9, _>.tmp`` (``tempfile``'s random names)
ATOMIC_TEMP_RE = re.compile(r"^(?P<target>.+)\.[a-z0-9_]{8}\.tmp$")


def atomic_temp_target(name: str) -> str | None:
    """The file name an :func:`atomic_open` temporary file ``name`` was for, or None if ``name`` is not one
    (e.g. a user's ``notes.2026-11-26.tmp``)."""
    m = ATOMIC_TEMP_RE.match(name)
    return m.group("target") if m else None


@contextmanager
def atomic_open(path, mode: str = "w", **kwargs):
    """Open a temporary file next to ``path`` that replaces ``path`` only once written completely.

    The rename is atomic, so a reader sees the old file or the new one, never a
    partial one; on any error the temporary file is deleted and ``path`` keeps
    its old content. The parent folder is created if needed. The temporary file
    has a unique name and is created exclusively (``mkstemp``); it is fsynced
    before the rename and the folder after it, so the new content survives a
    crash or power loss once this returns. The file gets the mode an ordinary
    ``open`` would give (``0o666`` minus the user's umask), not ``mkstemp``'s 0600.

    Parameters
    ----------
    path : str or Path
        Destination.
    mode : str
        ``"w"`` (text; ``encoding`` defaults to UTF-8) or ``"wb"``.
    **kwargs
        Passed to :func:`open` (e.g. ``newline=""`` for csv).

    Yields
    ------
    file object
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if "b" not in mode:
        kwargs.setdefault("encoding", "utf-8")
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~current_umask())
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        fsync_dir(path.parent)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically and durably (see :func:`atomic_open`); returns ``path`` as a Path."""
    with atomic_open(path, "wb") as fh:
        fh.write(data)
    return Path(path)


def atomic_write_text(path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_open`); returns ``path`` as a Path."""
    with atomic_open(path) as fh:
        fh.write(text)
    return Path(path)


def read_text_utf8(path, what: str) -> str:
    """A text file's contents; unreadable or not UTF-8 is a ValueError naming the file (and the line).

    Parameters
    ----------
    path : str or Path
    what : str
        What the file is ("model file", "catalog"), for the message.

    Raises
    ------
    ValueError
        ``"<path>:N: <what> is not UTF-8 text (<reason> at byte B)"`` or ``"<path>: <what> cannot be read (...)"``.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:  # a directory, no permission
        raise ValueError(f"{path}: {what} cannot be read ({exc.strerror})") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:  # e.g. saved as Latin-1
        line = raw[:exc.start].count(b"\n") + 1
        raise ValueError(f"{path}:{line}: {what} is not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def read_json_file(path, what: str):
    """Parse a JSON file.

    Parameters
    ----------
    path : str or Path
    what : str
        What the file is, for the not-found message ("model file", "model set index").

    Raises
    ------
    FileNotFoundError
        ``"<what> not found: <path>"``.
    ValueError
        ``"<path>: not valid JSON (line N: reason)"``, ``"<path>:N: <what> is not UTF-8 text (...)"``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    text = read_text_utf8(path, what)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON (line {exc.lineno}: {exc.msg})") from None
    except RecursionError:   # nested 10^5 deep: one line, not a traceback
        raise ValueError(f"{path}: not valid JSON here (nested too deeply)") from None


def refuse_overwrite(path, force: bool, flag: str = "--force") -> Path:
    """Refuse to replace a user's results: an existing file, or an existing folder that is not empty.

    Parameters
    ----------
    path : str or path
        The output file or folder a command is about to write.
    force : bool
        The user asked to overwrite (``--force``): nothing is refused.
    flag : str
        The option that allows overwriting, named in the message.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        ``path`` exists (a file, or a non-empty folder) and ``force`` is false; the
        message names the path and the flag.
    """
    p = Path(path)
    if force or not p.exists():
        return p
    if p.is_dir():
        if any(p.iterdir()):
            raise ValueError(f"{p} exists and is not empty; not overwriting earlier results: choose another "
                             f"--out or pass {flag} to replace them")
        return p
    raise ValueError(f"{p} exists; not overwriting it: choose another --out or pass {flag} to replace it")


def _parent_not_a_folder(p: Path, what: str) -> None:
    for parent in p.parents:
        if parent.exists() and not parent.is_dir():
            raise ValueError(f"cannot write {what} {p}: {parent} is a file, not a folder")


def refuse_study_data(path, what: str = "--out") -> Path:
    """Refuse an output that is, or lies inside, a study's data: a subject folder, a file of one, a study folder
    (a folder of subject folders), or a folder below one (:func:`plumbing.studyfiles.study_data_at`). Whatever
    ``--force`` says: only ``study run`` writes there.

    Returns
    -------
    Path

    Raises
    ------
    ValueError
        ``"--out P is (inside) the subject folder D/S01 ...; choose an --out outside the study's data"``.
    """
    p = Path(path)
    found = study_data_at(p)
    if found is not None:
        folder, kind = found
        how = "is" if folder == Path(os.path.abspath(p)).resolve() else "lies inside"
        held = " (it holds subject folders)" if kind == "study folder" else ""
        raise ValueError(f"{what} {p} {how} the {kind} {folder}{held}: a study's data is written by 'study run' "
                         f"only, and no other command writes there, not even with --force; choose a {what} "
                         "outside it")
    return p


def refuse_inputs(path, inputs, what: str = "--out") -> Path:
    """Refuse an output that is, contains or lies inside one of the command's ``inputs`` (files or folders it
    reads): replacing it, or writing into it, would destroy or change what is being read.

    Parameters
    ----------
    path : str or Path
        The output file or folder.
    inputs : iterable of (str or Path, str)
        Each input with the words that name it in the message (``(args.data, "the data folder")``).

    Raises
    ------
    ValueError
        Naming the output, the input and how they overlap.
    """
    p = Path(path)
    mine = Path(os.path.abspath(p)).resolve()
    for given, name in inputs:
        if given is None:
            continue
        other = Path(os.path.abspath(given)).resolve()
        if mine == other:
            how = "is"
        elif other.is_relative_to(mine):
            how = "contains"
        elif mine.is_relative_to(other):
            how = "lies inside"
        else:
            continue
        raise ValueError(f"{what} {p} {how} {name} {given}, which this command reads; an output never replaces or "
                         f"writes into its input, not even with --force: choose a {what} outside it")
    return p


def check_output_file(path, force: bool, flag: str = "--force", what: str = "--out") -> Path:
    """Check a file a command will write, before it measures or computes anything.

    Refused (``ValueError`` naming the path): an existing folder (also with ``force``: a file
    cannot replace it), a path below an existing file, a file of a study's data (:func:`refuse_study_data`,
    also with ``force``), and an existing file unless ``force`` (:func:`refuse_overwrite`).

    Parameters
    ----------
    path : str or path
    force : bool
        The user passed ``flag``.
    flag : str
        The option that allows overwriting, named in the message.
    what : str
        The option that gave ``path`` (``--out``, ``--plot``), named in the message.

    Returns
    -------
    Path
    """
    p = Path(path)
    if p.is_dir():
        raise ValueError(f"{what} {p} is a folder; give the name of a file to write")
    _parent_not_a_folder(p, what)
    refuse_study_data(p, what)
    return refuse_overwrite(p, force, flag)


def check_output_dir(path, force: bool | None = None, flag: str = "--force", what: str = "--out") -> Path:
    """Check a folder a command will write into, before it measures or computes anything.

    Refused (``ValueError`` naming the path): an existing file, a path below an existing file, a study's data
    folder, a subject folder or a folder inside one (:func:`refuse_study_data`, whatever ``force``) and, when
    ``force`` is given (not None) and false, a folder that is not empty (:func:`refuse_overwrite`).

    Returns
    -------
    Path
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise ValueError(f"{what} {p} is a file, not a folder")
    _parent_not_a_folder(p, what)
    refuse_study_data(p, what)
    if force is not None:
        refuse_overwrite(p, force, flag)
    return p


def clear_products(folder, patterns) -> list[Path]:
    """Delete what an earlier run of a command wrote into ``folder`` (glob ``patterns``), so old and new never mix.

    Parameters
    ----------
    folder : str or path
        The output folder (left in place; other files in it are kept).
    patterns : iterable of str
        Glob patterns relative to ``folder`` (folders matched are removed whole).

    Returns
    -------
    list of Path
        What was deleted.
    """
    gone = []
    folder = Path(folder)
    for pattern in patterns:
        for p in sorted(folder.glob(pattern)):
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink()
            gone.append(p)
    return gone
