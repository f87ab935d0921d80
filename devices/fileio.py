"""Small file helpers shared by the writers and readers of devices (and the packages built on it)."""

from __future__ import annotations

import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_open(path, mode: str = "w", **kwargs):
    """Open a temporary file next to ``path`` that replaces ``path`` only once written completely.

    The rename is atomic, so a reader sees the old file or the new one, never a
    partial one; on any error the temporary file is deleted and ``path`` keeps
    its old content. The parent folder is created if needed.

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
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


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
