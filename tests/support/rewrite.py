"""pytest's rewritten test modules, written once before the workers start: ``python -m tests.support.rewrite``.

pytest rewrites the ``assert`` statements of every test module (and ``conftest.py``) it imports, and caches the
result beside it (``__pycache__/<name>.cpython-311-pytest-<version>.pyc``) -- unless ``PYTHONDONTWRITEBYTECODE``
is set, as on this project's CI machines: then every xdist worker rewrites every module again, 5.5 s of the
9.3 s of CPU each worker spends collecting. ``make test`` (its ``.venv/.compiled`` step) writes them here once,
with pytest's own functions: the same code a worker makes, in pytest's checked-hash pyc, which pytest validates
against the source on every read (an edited test module is rewritten by the worker that imports it, as before).

It uses names private to pytest (``_pytest.assertion.rewrite``); where a pytest version lacks them it says so
and writes nothing (the workers rewrite, as without it).
"""

from __future__ import annotations

import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from tests.support.parallel import usable_cores

ROOT = Path(__file__).resolve().parents[2]


def rewritten_files(root: Path) -> list[Path]:
    """The files pytest rewrites on import under ``root``: ``test_*.py`` and ``conftest.py``."""
    return sorted(p for p in root.rglob("*.py")
                  if (p.name.startswith("test_") or p.name == "conftest.py") and "__pycache__" not in p.parts)


def write_rewritten(path: Path) -> bool:
    """Rewrite ``path`` as pytest would (no config: pytest's defaults, which this project keeps) and write its
    cached pyc unless a valid one is there; True if written."""
    from _pytest.assertion import rewrite as rw

    pyc = rw.get_cache_dir(path) / (path.name[:-3] + rw.PYC_TAIL)
    if rw._read_pyc(path, pyc) is not None:
        return False
    source_hash, co = rw._rewrite_test(path, None)
    pyc.parent.mkdir(exist_ok=True)
    tmp = pyc.with_name(f"{pyc.name}.{os.getpid()}")
    with open(tmp, "wb") as fh:
        rw._write_pyc_fp(fh, source_hash, co)
    os.replace(tmp, pyc)            # atomic: a reader never sees half a file
    return True


def main(argv: list[str] | None = None) -> int:
    roots = [Path(a) for a in (argv if argv is not None else sys.argv[1:])] or [ROOT / "tests"]
    try:
        from _pytest.assertion import rewrite as rw
        for name in ("get_cache_dir", "PYC_TAIL", "_read_pyc", "_rewrite_test", "_write_pyc_fp"):
            getattr(rw, name)
    except (ImportError, AttributeError) as exc:
        print(f"pytest's rewritten test modules not cached ({exc}): each test worker rewrites them")
        return 0
    files = [p for r in roots for p in rewritten_files(r)]
    with ProcessPoolExecutor(max_workers=min(usable_cores(), 8)) as pool:
        written = sum(pool.map(write_rewritten, files, chunksize=8))
    print(f"pytest's rewritten test modules: {written} written, {len(files) - written} up to date")
    return 0


if __name__ == "__main__":
    sys.exit(main())
