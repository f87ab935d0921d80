"""Run a ``python -m <package> <command>`` in the test's own process: the same parser, body and error handling.

A child Python process costs 1-3 s of CPU before the command's first line (numpy, scipy, pandas, numba,
matplotlib), most of what a refused command or a short run costs. Where the process itself is not what a test
is about (its signals, its exit, its environment, what it imports), the test calls the package's ``main`` --
what ``python -m <package>`` and the ``hfam-<package>`` console script call (``plumbing.dispatch``) -- and gets
the exit code and what the command printed. Each command family keeps at least one run as a real process
(``tests/integration/test_readme.py`` runs every command of the README through its console script).

Not the same as a process in one way: ``warnings`` are not turned into ``warning:`` lines (the console
scripts install that, ``plumbing.dispatch.run_as_script``); a test of such a line runs a process.
"""

from __future__ import annotations

import contextlib
import importlib
import os
from dataclasses import dataclass


@dataclass
class Ran:
    """What a command did: the fields of ``subprocess.CompletedProcess`` that the tests read."""

    returncode: int
    stdout: str
    stderr: str


@contextlib.contextmanager
def _cwd(folder):
    if folder is None:
        yield
        return
    before = os.getcwd()
    os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(before)


def run_cli(capsys, package: str, *args, cwd: str | os.PathLike | None = None) -> Ran:
    """``python -m <package> <args>`` in this process, in ``cwd``; its exit code and output.

    Parameters
    ----------
    capsys : pytest's ``capsys`` fixture
        What the command prints is read from it (output printed before the call is dropped).
    package : str
        ``devices``, ``renderer``, ``stimuli``, ``study`` or ``analysis``.
    *args : str or path-like
        The command line after ``python -m <package>``.
    cwd : path-like, optional
        Folder the command runs in (relative paths in ``args`` are relative to it); restored afterwards.
    """
    main = importlib.import_module(f"{package}.__main__").main
    capsys.readouterr()
    with _cwd(cwd):
        try:
            code = main([os.fspath(a) if isinstance(a, os.PathLike) else str(a) for a in args])
        except SystemExit as exc:                      # argparse: usage errors exit 2, --help exits 0
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    out, err = capsys.readouterr()
    return Ran(int(code), out, err)
