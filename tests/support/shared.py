"""Costly test products made once per test run and shared by every pytest-xdist worker.

A session-scoped fixture runs once per *process*: with ``make test``'s workers (``pytest -n auto``) a costly
set-up (a simulated demo, a successive isolation, a synthetic study) would be made once in each worker.
Here it is made once per run, by whichever worker asks first, under an exclusive ``fcntl`` lock on a file in
the run's base temporary folder (``<basetemp>`` without xdist, its parent -- the folder holding ``popen-gw0``,
``popen-gw1`` -- with it); the other worker waits on the lock and then reads the product. Every run has a new
base folder, so nothing is shared between runs: a product always comes from this run's sources.

A product that failed to build leaves no mark: the next worker to ask builds it again (and fails the same
way, in its own test). Consumers read the products and never change them (the same rule as for any
session-scoped fixture); a test that needs to change one copies it first.
"""

from __future__ import annotations

import fcntl
import os
import pickle
import shutil
from pathlib import Path
from typing import Callable, TypeVar

T = TypeVar("T")


def run_dir(tmp_path_factory) -> Path:
    """The folder every worker of this run shares: ``<basetemp>/shared`` (its parent under xdist)."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent                     # <run basetemp>/popen-gwN -> <run basetemp>
    folder = base / "shared"
    folder.mkdir(exist_ok=True)
    return folder


def shared_folder(tmp_path_factory, name: str, build: Callable[[Path], object]) -> Path:
    """A folder ``name`` that ``build(folder)`` fills, built once per run for all workers.

    ``build`` gets an empty folder at its final path (products may name their own paths); the folder counts
    as built only once ``build`` has returned (a marker file then), so a reader never takes half a product.
    """
    root = run_dir(tmp_path_factory)
    folder = root / name
    done = root / f"{name}.built"
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)       # held while building: the other worker waits here
        if not done.exists():
            shutil.rmtree(folder, ignore_errors=True)   # left by a build that raised
            folder.mkdir()
            build(folder)
            done.touch()
    return folder


def shared_value(tmp_path_factory, name: str, compute: Callable[[Path], T]) -> T:
    """``compute(folder)``'s value, computed once per run for all workers (pickled in ``folder``).

    ``compute`` may write files into ``folder`` (its own, kept for the run) and refer to them in its value.
    Each worker gets its own unpickled copy.
    """
    box: dict = {}

    def build(folder: Path) -> None:
        box["value"] = compute(folder)
        (folder / "value.pickle").write_bytes(pickle.dumps(box["value"], protocol=pickle.HIGHEST_PROTOCOL))

    folder = shared_folder(tmp_path_factory, name, build)
    if "value" in box:
        return box["value"]                    # this worker computed it: no round trip through the pickle
    return pickle.loads((folder / "value.pickle").read_bytes())
