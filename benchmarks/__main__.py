"""``python -m benchmarks``: run every ``benchmarks/bench_*.py`` (each has ``main()``) and print its figures."""

from __future__ import annotations

import importlib
import os
import pathlib
import sys


def main(argv=None) -> int:
    names = sorted(p.stem for p in pathlib.Path(__file__).parent.glob("bench_*.py"))
    wanted = set(argv or sys.argv[1:])
    failed = 0
    for name in names:
        if wanted and name not in wanted and name.removeprefix("bench_") not in wanted:
            continue
        print(f"== {name}", flush=True)
        try:
            importlib.import_module(f"benchmarks.{name}").main()
        except Exception as exc:  # keep going so one broken benchmark does not hide the others
            failed += 1
            print(f"   FAILED: {exc!r}", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    try:
        code = main()
        sys.stdout.flush()  # a reader that went away (``| head``) shows up here or in a print
    except BrokenPipeError:
        # recipe of the Python docs (signal module, "Note on SIGPIPE"): point stdout at devnull so the
        # interpreter's final flush cannot raise again, and exit 1 without a traceback
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        sys.exit(1)
    sys.exit(code)
