"""What software produced a result: Python, every dependency that affects results, the project's version and commit.

One helper for every file that records provenance (``session.json``,
``run.json``, identification reports, library metadata). Versions are read
from the installed distributions' metadata, so nothing heavy is imported.
"""

from __future__ import annotations

import functools
import os
import platform
import re
import subprocess
import sys
import threading
from pathlib import Path

#: Distributions whose version can change a result (numerics, statistics, I/O, figures, transports).
RESULT_PACKAGES = ("numpy", "scipy", "numba", "llvmlite", "pandas", "statsmodels", "matplotlib",
                   "pyserial", "hidapi", "sounddevice")

PROJECT = "hfam-haptics"


def _normalize(name: str) -> str:
    """A distribution name as wheels spell it in their ``.dist-info`` folder (PEP 503, ``-``/``.`` -> ``_``)."""
    return re.sub(r"[-_.]+", "_", name).lower()


def _dist_version(name: str) -> str | None:
    """The installed version of distribution ``name`` (None if not installed).

    Read from the ``{name}-{version}.dist-info`` folder names on ``sys.path``, first match wins (what
    ``importlib.metadata.version`` finds; ~20x faster: no metadata files parsed, and importlib.metadata,
    ~25 ms to import, is loaded only for a distribution installed some other way, e.g. an ``.egg-info``).
    """
    version = _dist_info_versions().get(_normalize(name))
    if version is not None:
        return version
    import importlib.metadata  # deferred: 15 ms CPU of every run; only a distribution without a .dist-info needs it

    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


@functools.lru_cache(maxsize=1)
def _dist_info_versions() -> dict[str, str]:
    found: dict[str, str] = {}
    for entry in sys.path:
        try:
            names = os.listdir(entry or ".")
        except OSError:
            continue
        for folder in names:
            if folder.endswith(".dist-info") and "-" in folder:
                dist, version = folder[:-len(".dist-info")].split("-", 1)
                found.setdefault(_normalize(dist), version)
    return found


def git_commit(repo: str | Path | None = None) -> tuple[str | None, bool | None]:
    """The git commit of the project's source tree and whether it has uncommitted changes.

    Parameters
    ----------
    repo : str or Path, optional
        Folder of the checkout; default: the one holding this package.

    Returns
    -------
    commit, dirty : str or None, bool or None
        ``(None, None)`` when the code is not in a git checkout or git is unavailable.
    """
    repo = Path(repo) if repo else Path(__file__).resolve().parents[1]
    if not (repo / ".git").exists():
        return None, None
    try:
        sha = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True,
                             timeout=5)
        if sha.returncode != 0:
            return None, None
        st = subprocess.run(["git", "-C", str(repo), "status", "--porcelain", "--untracked-files=no"],
                            capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None, None
    return sha.stdout.strip(), (bool(st.stdout.strip()) if st.returncode == 0 else None)


@functools.lru_cache(maxsize=1)
def _versions_once() -> tuple:
    commit, dirty = git_commit()
    out = {PROJECT: _dist_version(PROJECT) or "unknown", "git_commit": commit, "git_dirty": dirty,
           "python": platform.python_version(), "platform": platform.platform()}
    for name in RESULT_PACKAGES:
        out[name] = _dist_version(name)
    return tuple(out.items())


_versions_lock = threading.Lock()


def _versions() -> tuple:
    # one computation per process, also when prefetch()'s thread is still at it (this waits for it)
    with _versions_lock:
        return _versions_once()


def prefetch() -> None:
    """Start working out :func:`software_versions` in a background thread (most of it is waiting for
    ``git status``, ~10 ms), so a command that will save a result does not wait for it at the end. Not
    for a paced hardware loop's process: the thread takes the GIL for a few ms."""
    threading.Thread(target=_versions, name="provenance", daemon=True).start()


def software_versions() -> dict:
    """Provenance of a result, for ``session.json``/``run.json``/reports (computed once per process).

    Returns
    -------
    dict
        ``{"hfam-haptics": "0.1.0", "git_commit": "<sha>" or None, "git_dirty": bool or None,
        "python": "3.11.2", "platform": "...", "numpy": "...", "scipy": ..., "numba": ..., "llvmlite": ...,
        "pandas": ..., "statsmodels": ..., "matplotlib": ..., "pyserial": ..., "hidapi": ...,
        "sounddevice": ...}``; a distribution that is not installed is None.
    """
    return dict(_versions())


def version_line() -> str:
    """``"hfam-haptics 0.1.0 (git 1a2b3c4d, modified)"``: the short form for metadata strings and ``--version``."""
    v = software_versions()
    git = ""
    if v["git_commit"]:
        git = f" (git {v['git_commit'][:8]}{', modified' if v['git_dirty'] else ''})"
    return f"{PROJECT} {v[PROJECT]}{git}"
