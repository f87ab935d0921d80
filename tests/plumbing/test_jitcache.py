"""plumbing.jitcache: the kernels' numba cache follows edits of every source compiled in; kernels are NRT-free."""

import ast
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from plumbing import jitcache

ROOT = Path(jitcache.__file__).resolve().parent.parent
KERNEL_MODULES = ("devices.sim.kernel", "devices.sim.teleop_kernel", "devices.identify._fastplay",
                  "devices.identify.successive._fastrun", "stimuli.hfam._fasttap", "renderer.law")


def _imports_full_parse(path: Path, root: Path) -> set[Path]:
    """Reference for jitcache._imports: every import statement found by a full ``ast.parse`` of the file
    (``_imports`` parses only the lines that look like imports), resolved the same way."""
    return {f for node in ast.walk(ast.parse(path.read_bytes())) for f in jitcache._resolve(node, path, root)}


def test_import_scan_agrees_with_a_full_parse_on_every_project_file():
    files = [p for pkg in ("devices", "renderer", "stimuli", "study", "analysis") for p in (ROOT / pkg).rglob("*.py")]
    assert len(files) > 100
    differing = [str(p.relative_to(ROOT)) for p in files
                 if jitcache._imports(p.resolve(), ROOT) != _imports_full_parse(p.resolve(), ROOT)]
    assert differing == []


def test_the_compiled_loop_depends_on_exactly_the_ahead_of_time_build_sources():
    from renderer import law, sim_aot

    deps = set(jitcache.dependency_files(law.__file__))
    # the decorator module decides no generated code; every other file is compiled in, and keys the build
    assert deps - {Path(jitcache.__file__).resolve()} == {p.resolve() for p in sim_aot.SOURCES}


def test_the_compiled_3d_loop_depends_on_exactly_the_3d_build_sources():
    from renderer import law3, sim_aot

    deps = set(jitcache.dependency_files(law3.__file__))
    assert deps - {Path(jitcache.__file__).resolve()} == {p.resolve() for p in sim_aot.SOURCES3}


def test_relative_and_star_imports_resolve(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    for f in ("__init__.py", "sub/__init__.py", "layout.py", "sub/b.py", "sub/c.py", "d.py"):
        (pkg / f).write_text("")
    (pkg / "sub" / "a.py").write_text(textwrap.dedent("""\
        from ..layout import *
        from . import b
        from .c import (X,
                        Y)
        import json

        def f():
            from pkg.d import thing  # deferred imports count too
        x = "a string, not an import: from pkg import nothing_here"
        """))
    got = {p.relative_to(tmp_path).as_posix() for p in jitcache.dependency_files(pkg / "sub" / "a.py")}
    assert got == {"pkg/sub/a.py", "pkg/layout.py", "pkg/sub/b.py", "pkg/sub/c.py", "pkg/d.py"}


def _run(tmp_path, code):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), str(ROOT)]))
    env.pop("NUMBA_CACHE_DIR", None)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout.split()


def test_an_edited_dependency_recompiles_a_cached_caller(tmp_path):
    """numba's own cache keeps a caller's copy of an edited callee of another file (the control); the
    dependency-stamped one recompiles once, then loads from the cache again."""
    pkg = tmp_path / "jitpkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    dep = pkg / "dep.py"
    dep.write_text("from numba import njit\n\n@njit(cache=True)\ndef f():\n    return 1.0\n")
    (pkg / "user.py").write_text(textwrap.dedent("""\
        from numba import njit
        from plumbing.jitcache import njit as stamped_njit
        from .dep import f

        @stamped_njit(cache=True, _nrt=False)
        def g():
            return f() + 10.0

        @njit(cache=True)
        def g_plain():
            return f() + 10.0
        """))
    code = ("import jitpkg.user as u; a = u.g(); b = u.g_plain(); "
            "print(a, b, u.g.stats.cache_hits.most_common(1)[0][1] if u.g.stats.cache_hits else 0)")
    assert _run(tmp_path, code) == ["11.0", "11.0", "0"]      # compiled, cached
    assert _run(tmp_path, code) == ["11.0", "11.0", "1"]      # loaded from the cache
    dep.write_text("from numba import njit\n\n@njit(cache=True)\ndef f():\n    return 2.0\n")
    # numba's stamp: g_plain's cache entry still holds f's old body; the dependency stamp recompiles g
    assert _run(tmp_path, code) == ["12.0", "11.0", "0"]
    assert _run(tmp_path, code) == ["12.0", "11.0", "1"]


@pytest.mark.parametrize("module", KERNEL_MODULES)
def test_every_kernel_is_cached_dependency_stamped_and_nrt_free(module):
    import importlib

    from numba.core.registry import CPUDispatcher

    mod = importlib.import_module(module)
    kernels = [v for v in vars(mod).values() if isinstance(v, CPUDispatcher) and v.__module__ == module]
    assert kernels, module
    for k in kernels:
        assert k.targetoptions.get("_nrt") is False, (module, k.__name__)
        assert getattr(k.py_func, jitcache.ROOT_ATTR, None) == str(ROOT), (module, k.__name__)
        assert isinstance(k._cache._impl.locator, (jitcache.InTreeLocator, jitcache.UserWideLocator,
                                                   jitcache.UserProvidedLocator)), (module, k.__name__)
