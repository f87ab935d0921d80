"""Small file helpers shared by the writers and readers of devices (and the packages built on it)."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import zipfile
from contextlib import contextmanager
from pathlib import Path


def user_cache_dir() -> Path:
    """The project's per-user cache: ``$XDG_CACHE_HOME/hfam-haptics`` or ``~/.cache/hfam-haptics``."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hfam-haptics"


def save_npz(path, arrays: dict) -> None:
    """``np.savez(path, **arrays)`` (uncompressed ``.npz``, one ``.npy`` member per array) without copying
    contiguous arrays: each is written from its own memory, where ``np.savez`` copies every array in
    chunks (``tobytes``) first; a 30 s servo log is 34 MB. Read back by ``np.load`` like any ``.npz``
    (``tests/devices/test_fileio.py`` checks it against ``np.savez``)."""
    import numpy as np  # deferred: this module serves commands that never load numpy

    with zipfile.ZipFile(path, mode="w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name, arr in arrays.items():
            arr = np.asanyarray(arr)
            with zf.open(name + ".npy", mode="w", force_zip64=True) as fp:
                if arr.flags.c_contiguous and arr.dtype.kind in "biuf" and arr.size:
                    np.lib.format.write_array_header_1_0(fp, np.lib.format.header_data_from_array_1_0(arr))
                    fp.write(memoryview(arr).cast("B"))
                else:  # object, structured, empty or strided: numpy's own writer
                    np.lib.format.write_array(fp, arr, allow_pickle=False)


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


def load_npz(path, what: str = ".npz file"):
    """Open an ``.npz`` archive safely (no pickles); errors name the file and say what is wrong.

    Distinguishes a missing file, an empty one, a pickle (refused: loading it could run code), a
    single-array ``.npy`` file, another kind of file, and a truncated or corrupt zip archive.

    Parameters
    ----------
    path : str or Path
    what : str
        What the file should be, for the messages ("HFAM library", "trace").

    Returns
    -------
    numpy.lib.npyio.NpzFile
        Use it as a context manager.

    Raises
    ------
    FileNotFoundError, ValueError
        One line: ``"<path>: <what> ... (reason)"``.
    """
    import numpy as np  # deferred: numpy only where archives are read

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    with open(path, "rb") as fh:
        head = fh.read(8)
    if not head:
        raise ValueError(f"{path}: {what} is empty (0 bytes)")
    if head[:1] == b"\x80" or head[:1] in (b"(", b"]", b"}"):
        raise ValueError(f"{path}: {what} is a Python pickle, not an .npz archive (refused: loading pickles can "
                         "run code)")
    if head.startswith(b"\x93NUMPY"):
        raise ValueError(f"{path}: {what} is a single-array .npy file, not an .npz archive")
    if not head.startswith(b"PK"):
        raise ValueError(f"{path}: {what} is not an .npz (zip) archive (it starts with {head[:8]!r})")
    try:
        return np.load(path, allow_pickle=False)
    except (zipfile.BadZipFile, EOFError, OSError) as exc:
        raise ValueError(f"{path}: {what} is a truncated or corrupt zip archive ({exc})") from None


def atomic_write_text(path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_open`); returns ``path`` as a Path."""
    with atomic_open(path) as fh:
        fh.write(text)
    return Path(path)


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
        ``"<path>: not valid JSON (line N: reason)"``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON (line {exc.lineno}: {exc.msg})") from None


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
