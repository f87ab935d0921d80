"""The ``python -m <package> <command>`` dispatcher shared by devices, renderer, stimuli, study and analysis.

Each package's ``__main__`` lists its commands once, as a table of
:class:`Command` (name, parser module, one-line help). A command is two modules: its parser
(``cli_<x>_parser.py``: ``register(subparsers)``, light) and its body (``cli_<x>.py``, its imports at the
top). ``--help`` of the package lists the commands without importing a single parser module; only the
parser of the command that runs (or whose ``--help`` is asked) is imported. The parser names the body as
a :class:`Body` (``set_defaults(func=Body("pkg.cli_x", "run"))``), which :func:`main` imports only when
the command runs. So ``python -m renderer run --help`` does not pay for numba, scipy.signal or matplotlib.

Errors the user can fix (:class:`ValueError`, :class:`FileNotFoundError`,
:class:`plumbing.errors.UserError`, which ``devices.DeviceError`` derives from) print one ``error: ...`` line and exit 2;
a reader that goes away (``| head``) exits 1 without a traceback; Ctrl-C that a command does not handle
itself prints ``interrupted`` and exits 130 (no traceback); SIGTERM or SIGHUP that reach the dispatcher as
:class:`plumbing.stopsignals.Terminated` (inside a command's output folder, which the stop leaves as it was)
print ``stopped by SIGTERM`` and exit 143 (129); a full disk (ENOSPC, EDQUOT, EFBIG) prints one
``error:`` line and exits 2.

A command whose parser sets ``fast_exit=True`` (``set_defaults``) declares that it has closed every
file and joined every thread it started when it returns; run as a script (:func:`run_as_script`),
its process then ends after the exit handlers (``atexit``) without tearing the interpreter down.

A :class:`Command` runs, as a script, with ``blas_threads`` BLAS threads (default one) unless the
user chose (``OPENBLAS_NUM_THREADS``, ``MKL_NUM_THREADS``, ``OMP_NUM_THREADS``; the processes it starts
inherit them). OpenBLAS starts its worker threads when numpy loads, and each spins (yielding) for
about 2^28 cycles, ~0.1 s, waiting for work: in a simulated ``renderer run``, which makes no BLAS call,
that was a quarter of the process's CPU samples (``perf``), on the core its log writer and
provenance thread use. No command here makes BLAS calls big enough to gain from more threads: the
successive isolation of the simulated device took 14.3 s of CPU and 9.5 s of wall time with OpenBLAS's
default threads, 8.3 s and 8.3 s with one (two cores).
"""

from __future__ import annotations

import argparse
import atexit
import errno
import gc
import importlib
import os
import sys
import warnings
from typing import NamedTuple, Sequence

from .errors import UserError
from .stopsignals import Terminated


#: the write errors of a full disk (ENOSPC), an exhausted quota (EDQUOT) and a file-size limit (EFBIG,
#: ``ulimit -f``): one ``error:`` line, exit 2, like a user error
DISK_FULL_ERRNOS = frozenset(getattr(errno, n) for n in ("ENOSPC", "EDQUOT", "EFBIG") if hasattr(errno, n))

#: set by :func:`main` when the command that ran declared ``fast_exit`` and returned
_fast_exit_ok = False
#: set by :func:`run_as_script`: the process is the command's own
_as_script = False


class Body:
    """A command's body named by module and function, imported on the first call (``--help`` never calls it).

    Parameters
    ----------
    module : str
        Dotted name of the body's module, e.g. ``"renderer.cli_run"``.
    function : str
        The function in it that takes the parsed ``argparse.Namespace`` and returns the exit code.
    """

    __slots__ = ("module", "function")

    def __init__(self, module: str, function: str):
        self.module = module
        self.function = function

    def resolve(self):
        """Import the body's module and return the function."""
        return getattr(importlib.import_module(self.module), self.function)

    def __call__(self, args):
        """Run the body with the parsed arguments ``args``; returns its exit code."""
        return self.resolve()(args)

    def __repr__(self) -> str:
        return f"Body({self.module!r}, {self.function!r})"


class Command(NamedTuple):
    """One subcommand: its name, its parser module (``register(subparsers)``), its help line,
    the modules it imports when it runs (imported by :func:`main` before it runs, see there) and the BLAS
    threads its process should have (default 1; None: the library's default; module doc)."""

    name: str
    module: str
    help: str
    preload: tuple[str, ...] = ()
    blas_threads: int | None = 1


#: the environment variables by which the BLAS builds numpy and scipy ship with (OpenBLAS, MKL, OpenMP
#: builds) take their thread count; read once, when the library loads
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")


def _command_name(argv: Sequence[str]) -> str | None:
    """The command ``argv`` names: its first argument that is not an option."""
    return next((a for a in argv if not a.startswith("-")), None)


def build_parser(prog: str, description: str, commands: Sequence[Command], argv: Sequence[str]):
    """The package's parser; only the command named in ``argv`` (if any) is imported and registered.

    Parameters
    ----------
    prog, description : str
        Shown by ``--help``.
    commands : sequence of Command
    argv : sequence of str
        The arguments; the first one that is not an option names the command.

    Returns
    -------
    argparse.ArgumentParser
    """
    parser = argparse.ArgumentParser(prog=prog, description=description)
    sub = parser.add_subparsers(dest="command", required=True, metavar="{" + ",".join(c.name for c in commands) + "}")
    wanted = _command_name(argv)
    for c in commands:
        if c.name == wanted:
            importlib.import_module(c.module).register(sub)  # may register its sibling commands too
    for c in commands:
        if c.name not in sub.choices:
            sub.add_parser(c.name, help=c.help)  # placeholder: lists the command, imports nothing
    return parser


def main(prog: str, description: str, commands: Sequence[Command], argv: Sequence[str] | None = None) -> int:
    """Parse ``argv`` (default ``sys.argv[1:]``), run the command and return its exit code.

    Returns
    -------
    int
        The command's exit code; 2 after an ``error:`` line for a user error.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    wanted = next((c for c in commands if c.name == _command_name(argv)), None)
    if _as_script and wanted is not None and wanted.blas_threads and "numpy" not in sys.modules:
        for var in BLAS_THREAD_VARS:  # before numpy (and its BLAS) loads; a user's own setting stays
            os.environ.setdefault(var, str(int(wanted.blas_threads)))
    # start-up allocates ~10^5 long-lived objects (code, numpy's tables), which the cyclic collector would
    # walk again and again for nothing (~7 ms of a simulated run): the parser, the command's module and
    # its ``preload`` modules are imported with the collector off, then frozen out of its generations
    collecting = gc.isenabled()
    gc.disable()
    try:
        args = build_parser(console_prog(prog), description, commands, argv).parse_args(argv)
        func = getattr(args, "func", None)
        if isinstance(func, Body):
            args.func = func.resolve()  # the command's body, imported now that it runs
        for c in commands:
            if c.name == getattr(args, "command", None):
                for name in c.preload:
                    importlib.import_module(name)
    except KeyboardInterrupt:  # Ctrl-C while the command's modules load: nothing ran yet, the same one line
        return _interrupted()
    finally:
        if collecting:
            if _as_script:  # a process of its own (in a caller's process, its objects are left alone)
                gc.freeze()
            gc.enable()
    global _fast_exit_ok
    try:
        code = int(args.func(args) or 0)
        _fast_exit_ok = bool(getattr(args, "fast_exit", False))
        return code
    except (ValueError, FileNotFoundError, UserError) as exc:  # UserError: e.g. devices.DeviceError, a port that is absent or mute
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        if exc.errno not in DISK_FULL_ERRNOS:
            raise
        # a full disk, a quota or a file-size limit: the command's output folder or file was not swapped in
        # (plumbing.outdir), so the earlier results stand and no temporary file is left
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"error: {where}cannot write: {exc.strerror} (full disk, quota or file-size limit); earlier results "
              "were left as they were", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C in a command that does not say more itself: one line, the shell's 130
        return _interrupted()
    except Terminated as exc:  # SIGTERM/SIGHUP inside a command's stop_on_signals block (its output staged):
        # one line, the status of a death by that signal (143, 129); the command's clean-up has run
        print(f"{exc}", file=sys.stderr)
        return exc.code


def _interrupted() -> int:
    """Say that Ctrl-C stopped the command (one line, no traceback) and return the shell's status for it, 130."""
    print("\ninterrupted", file=sys.stderr)
    return 130


def console_prog(prog: str) -> str:
    """``hfam-<package>`` when run as that console script, else ``prog`` (``python -m <package>``).

    Parameters
    ----------
    prog : str
        The module form of the program name, used in usage and error lines.

    Returns
    -------
    str
        The name the user typed, so ``--help`` and errors show a command they can copy.
    """
    name = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    return name if name.startswith("hfam-") else prog


#: the project's source tree: a warning raised from a file under it is ours (``warning:`` line)
_PROJECT_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep
_default_showwarning = warnings.showwarning


def show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Print one of the project's warnings as a ``warning: <message>`` line on stderr, like the ``error:`` lines.

    A warning raised by the project's own code (a device limit, an implausible parameter, an analysis note)
    is meant for the user, who needs its words, not the source file, line number and category Python
    prints by default. Other libraries' warnings keep Python's format (their location is how one finds
    the cause). Installed by :func:`run_as_script` (commands run as programs), so a library user's own
    warning handling is left alone.
    """
    where = str(filename)
    if where.startswith(_PROJECT_ROOT) and not where.startswith((_PROJECT_ROOT + ".venv", _PROJECT_ROOT + ".deps")):
        print(f"warning: {message}", file=sys.stderr if file is None else file)
    else:
        _default_showwarning(message, category, filename, lineno, file, line)


def run_as_script(main_func) -> None:
    """``if __name__ == "__main__"`` body: run ``main_func()`` and exit with its code; quiet on a broken pipe.

    After a command that declared ``fast_exit`` (module doc), with no other thread alive, the exit
    handlers run and the process ends with ``os._exit``: the interpreter's teardown (every module,
    numpy's and OpenBLAS's included) costs ~7-15 ms that such a command's user would only wait for.
    """
    global _as_script
    _as_script = True
    warnings.showwarning = show_warning
    try:
        code = main_func()
        sys.stdout.flush()  # a reader that went away (``| head``) shows up here or in a print
        # the process ends here: frozen, the objects are left out of the interpreter's collections at
        # exit, which otherwise walk all of them (~0.25 s with numba, scipy and matplotlib loaded); every
        # file the commands write is closed (and renamed into place) before they return
        gc.freeze()
        threading = sys.modules.get("threading")
        if _fast_exit_ok and (threading is None or threading.active_count() == 1):
            atexit._run_exitfuncs()  # what the interpreter would run first at exit (flushes, finalizers)
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
    except BrokenPipeError:
        # recipe of the Python docs (signal module, "Note on SIGPIPE"): point stdout at devnull so the
        # interpreter's final flush cannot raise again, and exit 1 without a traceback
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        sys.exit(1)
    _forget_interrupted_exec()
    sys.exit(code)


def _forget_interrupted_exec() -> None:
    """Keep a Ctrl-C the command handled from ending the process by SIGINT after it returned its code.

    CPython marks a KeyboardInterrupt that leaves an ``exec()`` of source text as unhandled, even when code
    outside that ``exec()`` catches it, and a ``python -m`` process whose mark is set ends by SIGINT (status
    -2) whatever its exit code. scipy runs such an ``exec()`` as it imports, so a report stopped by Ctrl-C
    during its imports printed ``interrupted`` and died by SIGINT instead of exiting 130 (1 run in 20-30).
    The next ``exec()`` of source text clears the mark. A KeyboardInterrupt nobody caught never gets here:
    that process still ends by SIGINT, as a shell expects of an uncaught Ctrl-C.
    """
    exec("None", {})
