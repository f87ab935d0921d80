"""``python -m analysis <command>``: analyse a study folder, or write a synthetic one.

Its own small dispatcher (analysis imports none of the other packages, so it
cannot share :mod:`devices.dispatch`); same rule: the commands are a table,
a command's module is imported only when it runs or its ``--help`` is asked.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import os
import sys

#: (name, module, help); each module has ``register(subparsers)``
COMMAND_TABLE = (
    ("report", "analysis.cli_report", "analyse a study folder: tables, figures, report.md/.html"),
    ("synthetic", "analysis.cli_synthetic", "write a synthetic study folder in the study's data format"),
)


def main(argv=None) -> int:
    """Run ``python -m analysis`` with ``argv`` (default: the command line); returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    _one_blas_thread()
    parser = argparse.ArgumentParser(prog=_prog(), description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True,
                                metavar="{" + ",".join(name for name, _, _ in COMMAND_TABLE) + "}")
    wanted = next((a for a in argv if not a.startswith("-")), None)
    for name, module, help_text in COMMAND_TABLE:
        if name == wanted:
            importlib.import_module(module).register(sub)
        else:
            sub.add_parser(name, help=help_text)  # placeholder: lists the command, imports nothing
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def _one_blas_thread() -> None:
    """One BLAS thread for this process, unless the environment chose, and only before numpy is loaded.

    The analysis' matrix products are small (vectors of attempts, 12 x 12 covariances); a second
    BLAS thread waiting for a busy core cost up to a scheduler slice (~8 ms) per call, 0.6 s per
    report on a loaded two-core machine. Once numpy is imported (a caller's process) the setting
    could not take effect, and the environment is left alone.
    """
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def run() -> None:
    """Entry point of ``python -m analysis`` and of the ``hfam-analysis`` console script: exit with main()'s code."""
    try:
        code = main()
        sys.stdout.flush()  # a reader that went away (``| head``) shows up here or in a print
        # the process ends here: frozen, the objects are left out of the interpreter's collections at
        # exit, which otherwise walk all of them (~0.25 s with pandas, scipy and matplotlib loaded)
        gc.freeze()
    except BrokenPipeError:
        # recipe of the Python docs (signal module, "Note on SIGPIPE"): point stdout at devnull so the
        # interpreter's final flush cannot raise again, and exit 1 without a traceback
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        sys.exit(1)
    sys.exit(code)


def _prog() -> str:
    """``hfam-analysis`` when run as the console script, else ``python -m analysis`` (for usage and error lines)."""
    name = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    return name if name.startswith("hfam-") else "python -m analysis"


if __name__ == "__main__":
    run()
