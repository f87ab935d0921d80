"""``python -m benchmarks``: run every ``benchmarks/bench_*.py`` (each has ``main()``) and print its figures."""

from __future__ import annotations

import ast
import importlib
import os
import pathlib
import sys


def _summary(path: pathlib.Path) -> str:
    """First line of a benchmark module's docstring, read without importing it (imports are heavy)."""
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    return doc.strip().splitlines()[0] if doc.strip() else ""


def main(argv=None) -> int:
    names = sorted(p.stem for p in pathlib.Path(__file__).parent.glob("bench_*.py"))
    args = list(sys.argv[1:] if argv is None else argv)
    if {"-h", "--help"} & set(args):
        here = pathlib.Path(__file__).parent
        print("usage: python -m benchmarks [NAME ...]\n\nRun the benchmarks (all, or the NAMEs given, with or without "
              "the bench_ prefix) and print their figures.\n\nbenchmarks:")
        for name in names:
            print(f"  {name.removeprefix('bench_'):<14} {_summary(here / (name + '.py'))}")
        print("\nexample: python -m benchmarks identify sim")
        return 0
    unknown = [a for a in args if a not in names and f"bench_{a}" not in names]
    if unknown:
        print(f"error: unknown benchmark(s) {unknown}; python -m benchmarks --help lists them", file=sys.stderr)
        return 2
    wanted = set(args)
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
