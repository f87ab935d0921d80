"""``python -m benchmarks``: run every ``benchmarks/bench_*.py`` (each has ``main()``) and print its figures."""

from __future__ import annotations

import ast
import functools
import importlib
import os
import pathlib
import sys


@functools.cache
def _source(path: pathlib.Path) -> ast.Module:
    """A benchmark module's syntax tree: what the runner needs of it is read without importing it (imports are
    heavy)."""
    return ast.parse(path.read_text(encoding="utf-8"))


def _summary(path: pathlib.Path) -> str:
    """First line of a benchmark module's docstring."""
    doc = ast.get_docstring(_source(path)) or ""
    return doc.strip().splitlines()[0] if doc.strip() else ""


def here_file(name: str) -> pathlib.Path:
    return pathlib.Path(__file__).parent / f"{name}.py"


def _by_default(path: pathlib.Path) -> bool:
    """False for a benchmark whose module sets ``RUN_BY_DEFAULT = False``."""
    for node in _source(path).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "RUN_BY_DEFAULT" for t in node.targets):
            return bool(ast.literal_eval(node.value))
    return True


def _parameters(path: pathlib.Path) -> list[str]:
    """The parameter names of a benchmark module's ``main``."""
    for node in _source(path).body:
        if isinstance(node, ast.FunctionDef) and node.name == "main":
            return [a.arg for a in node.args.args + node.args.kwonlyargs]
    return []


def main(argv=None) -> int:
    names = sorted(p.stem for p in pathlib.Path(__file__).parent.glob("bench_*.py"))
    args = list(sys.argv[1:] if argv is None else argv)

    def known(a):
        return a in names or f"bench_{a}" in names

    # words after one benchmark's name that are not all names are that benchmark's own options and arguments
    # (``python -m benchmarks suite --runs 3``, ``python -m benchmarks analysis 10000 --warm-bytecode``)
    options = args[1:] if len(args) > 1 and known(args[0]) and not all(map(known, args[1:])) else []
    args = args[:1] if options else args
    if {"-h", "--help"} & set(args):
        here = pathlib.Path(__file__).parent
        print("usage: python -m benchmarks [NAME ...] | NAME OPTION ...\n\nRun the benchmarks (all but the suite's "
              "own, or the NAMEs given, with or without the bench_ prefix) and print their figures; what follows "
              "one NAME, unless it is only more names, is that benchmark's own options and arguments (python -m "
              "benchmarks suite --help; python -m benchmarks analysis 10000 --warm-bytecode).\n\nbenchmarks:")
        for name in names:
            print(f"  {name.removeprefix('bench_'):<14} {_summary(here / (name + '.py'))}")
        print("\nexample: python -m benchmarks identify sim")
        return 0
    unknown = [a for a in args if not known(a)]
    if unknown:
        print(f"error: unknown benchmark(s) {unknown}; python -m benchmarks --help lists them", file=sys.stderr)
        return 2
    if options:
        name = args[0] if args[0] in names else f"bench_{args[0]}"
        if "argv" not in _parameters(here_file(name)):
            print(f"error: benchmark {args[0]} takes no options or arguments, got {' '.join(options)}",
                  file=sys.stderr)
            return 2
        code = importlib.import_module(f"benchmarks.{name}").main(options)
        return code if isinstance(code, int) else 0    # some return their figures (a dict) for other callers
    wanted = set(args)
    failed = 0
    for name in names:
        if wanted and name not in wanted and name.removeprefix("bench_") not in wanted:
            continue
        if not wanted and not _by_default(here_file(name)):
            continue                     # e.g. the whole test suite: asked for by name only
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
