"""numba's on-disk cache for the project's kernels, invalidated when any source compiled into them changes.

numba stamps a cached function with its own file only. A function that calls a jitted function of another
file, or reads another file's constants, has that code frozen into its cache entry, so after an edit of
``devices/sim/kernel.py`` the cached ``renderer.law.run_sim`` kept running the old physics (measured: an
accelerometer offset added to ``kernel.tick`` did not appear in a JIT-compiled closed-loop run until
``renderer/law.py`` itself changed). Functions decorated with :func:`njit` here are cached under a stamp
that also covers every project file their module imports, directly or through other project files
(:func:`dependency_files`); an edit of any of them recompiles the function once.

The kernels are also compiled without numba's reference-counting runtime (``_nrt=False`` at each
decorator): none of them allocates, and with the runtime every call that passes arrays between compiled
functions took an atomic increment and decrement per array (a fifth of a simulated closed loop's time).
A kernel that did allocate fails to compile, loudly.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import os
import re
import textwrap
from pathlib import Path

import numba
from numba.core import caching

#: attribute set on a decorated Python function: the folder its absolute imports are resolved against
ROOT_ATTR = "_hfam_source_root"


def source_root(py_file: str | os.PathLike) -> Path:
    """The folder holding ``py_file``'s top-level package (the first parent without ``__init__.py``)."""
    return _package_root(os.path.dirname(os.path.abspath(py_file)))


@functools.lru_cache(maxsize=None)
def _package_root(folder: str) -> Path:
    path = Path(folder).resolve()
    while (path / "__init__.py").is_file():
        path = path.parent
    return path


def _module_file(root: Path, parts: list[str]) -> Path | None:
    """``root/a/b.py`` or ``root/a/b/__init__.py`` for the module ``a.b``, or None (not under ``root``)."""
    if not parts:
        return None
    base = root.joinpath(*parts)
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate.resolve()
    return None


#: an import statement: ``import ...`` or ``from ... import ...`` with a parenthesised list over lines (its
#: comments may hold parentheses)
_IMPORT = re.compile(r"^[ \t]*(?:from[ \t]+\.*[\w.]*[ \t]+import[ \t]*(?:\((?:[^)#]|#.*)*\)|.*)|import[ \t]+.*)", re.M)


def _statements(source: str):
    """The import statements of ``source``, parsed. Only lines that look like imports are parsed
    (~0.3 ms, against ~5 ms for a whole kernel file); a docstring line that parses as one only adds a file."""
    for match in _IMPORT.finditer(source):
        try:
            tree = ast.parse(textwrap.dedent(match.group(0)))
        except SyntaxError:
            continue
        yield from tree.body


def _resolve(node, path: Path, root: Path) -> set[Path]:
    """The files under ``root`` that one ``import``/``from`` statement ``node`` of ``path`` names."""
    found: set[Path] = set()
    if isinstance(node, ast.Import):
        for alias in node.names:
            parts = alias.name.split(".")
            # ``import a.b.c`` runs a, a.b and a.b.c: any of them may hold what is compiled in
            found.update(f for n in range(1, len(parts) + 1) if (f := _module_file(root, parts[:n])) is not None)
    elif isinstance(node, ast.ImportFrom):
        if node.level:
            package = list(path.relative_to(root).parent.parts)
            if node.level > len(package):
                return found
            parts = package[:len(package) - node.level + 1] + (node.module.split(".") if node.module else [])
        else:
            parts = node.module.split(".")
        module = _module_file(root, parts)
        for alias in node.names:
            sub = _module_file(root, parts + [alias.name]) if alias.name != "*" else None
            if sub is not None:
                found.add(sub)  # ``from package import submodule``
            elif module is not None:
                found.add(module)  # a name defined in the module (or ``*``)
    found.discard(path)
    return found


@functools.lru_cache(maxsize=None)
def _imports(path: Path, root: Path) -> frozenset[Path]:
    """The files under ``root`` that ``path`` imports (any ``import``/``from`` statement in it); read once
    per process (the kernels' files import one another)."""
    return frozenset(f for node in _statements(path.read_text(encoding="utf-8")) for f in _resolve(node, path, root))


def dependency_files(py_file: str | os.PathLike, root: str | os.PathLike | None = None) -> tuple[Path, ...]:
    """Every file under ``root`` (default :func:`source_root`) that ``py_file`` imports, transitively,
    ``py_file`` included; sorted.

    The import statements are read from the sources (``ast``), not from ``sys.modules``, so constants
    brought in by ``from .layout import *`` count like functions do.
    """
    start = Path(py_file).resolve()
    base = Path(root).resolve() if root is not None else source_root(start)
    seen = {start}
    todo = [start]
    while todo:
        for dep in _imports(todo.pop(), base):
            if dep not in seen:
                seen.add(dep)
                todo.append(dep)
    return tuple(sorted(seen))


def dependency_stamp(py_file: str | os.PathLike, root: str | os.PathLike | None = None) -> bytes:
    """SHA-256 over the names and contents of :func:`dependency_files` (the cache's source stamp)."""
    path = Path(py_file).resolve()
    base = Path(root).resolve() if root is not None else source_root(path)
    h = hashlib.sha256()
    for dep in dependency_files(path, base):
        h.update(str(dep.relative_to(base)).encode())
        h.update(hashlib.sha256(dep.read_bytes()).digest())
    return h.digest()


@functools.lru_cache(maxsize=None)
def _stamp_once(py_file: str, root: str) -> bytes:
    # once per file and process: the stamp describes the sources this process imported, which an edit
    # made after the import does not change (numba stamps each decorated function; 19 for the servo path)
    return dependency_stamp(py_file, root)


class _DependencyStamp:
    """Locator mixin: numba's stamp of the function's own file, plus :func:`dependency_stamp`; only for
    functions decorated by :func:`njit` (numba's other users keep numba's own locators)."""

    _root: str

    def get_source_stamp(self):
        return super().get_source_stamp(), _stamp_once(self._py_file, self._root)

    @classmethod
    def from_function(cls, py_func, py_file):
        root = getattr(py_func, ROOT_ATTR, None)
        if root is None:
            return None
        self = super().from_function(py_func, py_file)
        if self is not None:
            self._root = root
        return self


def _numba(name: str):
    # older numba releases name these with a leading underscore (0.68 made them public)
    return getattr(caching, name, None) or getattr(caching, "_" + name)


class UserProvidedLocator(_DependencyStamp, _numba("UserProvidedCacheLocator")):
    """``$NUMBA_CACHE_DIR``, dependency-stamped."""


class InTreeLocator(_DependencyStamp, _numba("InTreeCacheLocator")):
    """``__pycache__`` next to the source, dependency-stamped."""


class UserWideLocator(_DependencyStamp, _numba("UserWideCacheLocator")):
    """The user-wide cache folder (a read-only install), dependency-stamped."""


def _register() -> None:
    # numba asks its locator classes in order; these go first, in numba's own order of preference
    classes = _numba("CacheImpl")._locator_classes
    for cls in (UserWideLocator, InTreeLocator, UserProvidedLocator):
        if cls not in classes:
            classes.insert(0, cls)


_register()


def njit(*args, **options):
    """``numba.njit`` whose cache (``cache=True``) is stamped with every source compiled in (module doc).

    Used like ``numba.njit``: ``@njit(cache=True, _nrt=False)``, ``@njit("f8(f8)", cache=True)``,
    ``njit(cache=True)(function)``. The options are numba's, unchanged.
    """
    def decorate(py_func):
        setattr(py_func, ROOT_ATTR, str(source_root(py_func.__code__.co_filename)))
        return numba.njit(*args, **options)(py_func)

    if len(args) == 1 and callable(args[0]) and not options:
        py_func, args = args[0], ()
        return decorate(py_func)
    return decorate
