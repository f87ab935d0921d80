"""Building the ahead-of-time extension of :mod:`renderer.sim_aot` (numba.pycc): imported by a build only.

A module of its own so that its imports (numba's compiler, the JIT laws, proxy and kernel whose sources
are compiled: ~1.1 s CPU) sit at its top and a simulated run, which only loads a finished build, never pays
them.
"""

from __future__ import annotations

import hashlib
import importlib
import shutil
import tempfile
import warnings
from pathlib import Path

with warnings.catch_warnings():
    # numba.pycc is "pending deprecation" (numba 0.57+) but is numba's supported AOT path today
    warnings.simplefilter("ignore")
    from numba.pycc import CC
    from numba.pycc import compiler as pycc_compiler

# the modules whose JIT functions are compiled (renderer.sim_aot.TARGETS names them as "module:function")
from devices.sim import kernel  # noqa: F401
from . import law, law3, proxy  # noqa: F401


def sha256_hex(path: Path) -> str:
    """SHA-256 of the file at ``path`` (hex), for the build's manifest."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _jit_function(where: str):
    """The JIT-compiled function ``module:function`` (:data:`renderer.sim_aot.TARGETS`' exports)."""
    module, _, name = where.partition(":")
    return getattr(importlib.import_module(module), name)


def compile_extension(out_dir: Path, module: str, exports) -> None:
    """numba.pycc: the JIT functions ``exports`` names (and everything they call, inlined) compiled into
    the extension module ``module`` in ``out_dir``.

    Parameters
    ----------
    out_dir : Path
        Folder the extension is written to.
    module : str
        The extension's module name (:attr:`renderer.sim_aot.Target.module`).
    exports : sequence of (str, str, str)
        Per exported function: its name in the extension, the JIT function (``module:function``) and its
        numba signature (:attr:`renderer.sim_aot.Target.exports`).

    Notes
    -----
    For the build, Python's temporary folder (``tempfile.tempdir``) is a folder inside ``out_dir``: a build
    runs in a process of its own (``renderer compile-sim``, the background builder), where nothing else makes
    temporary files meanwhile.
    """
    # numba.pycc's scratch folders (its object files, and the compiler check's temp.c and temp.cxx, which it
    # never removes) go into a folder of the build's own, removed here, not into the user's temporary folder
    scratch = tempfile.mkdtemp(prefix=".scratch", dir=out_dir)
    saved_tempdir = tempfile.tempdir
    tempfile.tempdir = scratch
    try:
        _compile_into(out_dir, module, exports)
    finally:
        tempfile.tempdir = saved_tempdir
        shutil.rmtree(scratch, ignore_errors=True)


def _compile_into(out_dir: Path, module: str, exports) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numba.pycc's pending deprecation, also when it is used
        cc = CC(module)
        cc.output_dir = str(out_dir)
        cc.verbose = False
        # the kernels never allocate (each is compiled with _nrt=False): no runtime to link in, and a kernel
        # that did need it would make the build fail to load (an undefined NRT symbol), not run slower
        cc.use_nrt = False
        for name, where, signature in exports:
            cc.export(name, signature)(_jit_function(where).py_func)
        # numba.pycc has no switch for numba's ``release_gil`` flag (what ``nogil=True`` sets for the JIT):
        # its compiler makes its flags with ``Flags()``, so it gets a subclass that sets it, for this build
        # only. tests/renderer/test_sim_aot.py checks that a build's run_sim lets another thread run.
        pycc_flags = pycc_compiler.Flags

        class _ReleaseGilFlags(pycc_flags):
            def __init__(self, *args, **kwargs):
                super().__init__(*args, **kwargs)
                self.release_gil = True

        pycc_compiler.Flags = _ReleaseGilFlags
        try:
            cc.compile()
        finally:
            pycc_compiler.Flags = pycc_flags
