"""The simulated closed loop compiled ahead of time: ``renderer.law.run_sim`` as a C extension.

``renderer.law.run_sim`` runs the servo law and the simulated device's physics together (the law of
every loop, the physics of ``devices.sim.kernel``). JIT-compiled, a process pays ~0.3-0.5 s before its
first tick: importing numba (which also loads scipy.linalg) and loading the cached machine code. The
same function compiled once by ``numba.pycc`` into an extension module loads in milliseconds without
numba, so a whole ``renderer run --device sim`` process costs little more than its physics.

One source: the extension is built from ``renderer.law.run_sim`` itself (same Python source, same
LLVM pipeline: the logs are bit-identical, ``tests/renderer/test_sim_aot.py``). Each build lives in a
folder named by a digest of the sources it was built from (``SOURCES``), Python and numpy, so an
edited law or kernel is never run from a stale build: it falls back to the JIT path until rebuilt.

Where and when (docs/renderer.md, "Compiled ahead of time"):

* ``$HFAM_SIM_AOT_DIR`` or ``$XDG_CACHE_HOME/hfam-haptics/sim-loop`` (``~/.cache/...``);
* built by ``python -m renderer compile-sim`` (~5 s; ``make bench`` does it), or in the background after
  the first ``renderer run`` on a simulated device that found none (a detached ``python -m
  renderer.sim_aot``, one at a time; runs until it is done use the JIT path);
* ``HFAM_SIM_AOT=auto`` (default: use, build in the background if missing), ``nobuild`` (use if
  present, never build by itself; the tests' setting), ``off`` (always the JIT path).
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np

import devices.sim.layout
from plumbing.cliargs import with_examples
from plumbing.fileio import user_cache_dir

MODULE = "_hfam_sim_loop"
#: renderer.law.run_sim(c, w, log, dev, sp, ss, srs, traj, grip, n_max) -> ticks run
SIGNATURE = ("int64(float64[::1], float64[::1], float64[:, ::1], float64[::1], float64[::1], float64[::1], "
             "uint64[::1], float64[::1], float64[::1], int64)")
#: devices.sim.kernel.tick(s, p, rs, traj, grip, k, i_cmd) -> (position_m, accel_m_s2, grip_N, hot)
TICK_SIGNATURE = ("UniTuple(float64, 4)(float64[::1], float64[::1], uint64[::1], float64[::1], float64[::1], "
                  "int64, float64)")
_RENDERER = Path(__file__).resolve().parent
_SIM = Path(devices.sim.layout.__file__).resolve().parent
#: every file whose source is compiled into the extension (run_sim and all it calls)
SOURCES = (_RENDERER / "law.py", _RENDERER / "law_layout.py", _RENDERER / "passivity.py", _RENDERER / "scene.py",
           _SIM / "kernel.py", _SIM / "layout.py")
MODES = ("auto", "nobuild", "off")
#: how the exported functions are built (part of the key): they release the GIL while they run, like the
#: JIT ``run_sim`` (``nogil=True``), so other threads of the process keep running during a compiled run;
#: and without numba's reference-counting runtime, like the JIT kernels (``_nrt=False``, plumbing/jitcache.py)
BUILD_OPTIONS = "release_gil no_nrt"
STALE_LOCK_S = 600.0        # a builder that has held the lock this long died: take over

_loaded: dict = {}


def mode() -> str:
    """``$HFAM_SIM_AOT`` (``auto`` when unset).

    Raises
    ------
    ValueError
        An unknown value (named, with the allowed ones).
    """
    value = os.environ.get("HFAM_SIM_AOT", "auto").strip().lower() or "auto"
    if value not in MODES:
        raise ValueError(f"HFAM_SIM_AOT must be one of {', '.join(MODES)}, got {value!r}")
    return value


def cache_dir() -> Path:
    """Folder of the builds: ``$HFAM_SIM_AOT_DIR`` or ``<user cache>/hfam-haptics/sim-loop``."""
    env = os.environ.get("HFAM_SIM_AOT_DIR")
    return Path(env) if env else user_cache_dir() / "sim-loop"


def source_key() -> str:
    """Key (16 hex) of the compiled sources, the Python build, numpy's version and the machine.

    Two CRC-32s (zlib: loaded anyway; hashlib's OpenSSL costs ~7 ms at start-up), of the sources and of
    the environment with every source's name and length: an edit changes the key (a CRC-32 catches every
    change of up to 32 bits and misses others with odds 2^-32); it guards against stale builds, not
    against adversaries. The manifest of each build records the sources' SHA-256 as well.
    """
    blob = b"".join(path.read_bytes() for path in SOURCES)
    env = "|".join([sys.version, np.__version__, platform.machine(), sys.implementation.cache_tag, BUILD_OPTIONS,
                    *(f"{p.name}:{p.stat().st_size}" for p in SOURCES)])
    return f"{zlib.crc32(blob):08x}{zlib.crc32(env.encode()):08x}"


def extension_path(key: str | None = None, base: Path | None = None) -> Path:
    """Where the build for ``key`` (default: the current sources) lives."""
    key = source_key() if key is None else key
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    return (cache_dir() if base is None else base) / key / (MODULE + suffix)


def load():
    """The ahead-of-time compiled extension module (``run_sim``, ``tick``), or None: no build for these
    sources, ``HFAM_SIM_AOT=off``, or a build that fails to load (reported once on stderr). Looked up once
    per process."""
    if "module" in _loaded:
        return _loaded["module"]
    found = None
    if mode() != "off":
        path = extension_path()
        if path.is_file():
            try:
                spec = importlib.util.spec_from_file_location(MODULE, path)
                module = importlib.util.module_from_spec(spec)
                spec.loader.exec_module(module)
                found = module if callable(getattr(module, "tick", None)) else None
            except Exception as exc:  # a damaged or foreign build: the JIT path gives the same results
                print(f"renderer: the ahead-of-time compiled loop {path} did not load ({exc}); using the "
                      f"JIT-compiled one (rebuild: python -m renderer compile-sim)", file=sys.stderr)
    _loaded["module"] = found
    return found


def run_sim_function():
    """``(run_sim, step)`` to call: the ahead-of-time build's ``run_sim`` and ``tick`` (the device's
    physics step, ``devices.sim.kernel.tick``) if there is a build for these sources; else
    ``renderer.law.run_sim`` (numba JIT) and None (the device keeps its own JIT step). Never builds:
    ``renderer run`` starts the background build after its run (:func:`schedule_build`), so a demo or a
    study session does not share its cores with a compiler."""
    module = load()
    if module is not None:
        return module.run_sim, module.tick
    from . import law  # deferred: numba (~0.3 s), needed only without an ahead-of-time build

    return law.run_sim, None


def _marker(base: Path, key: str, kind: str) -> Path:
    """``<base>/<key>.lock`` (a builder is at work) or ``<base>/<key>.failed`` (why the last build failed)."""
    return base / f"{key}.{kind}"


def schedule_build() -> bool:
    """Start ``python -m renderer.sim_aot`` detached, unless ``HFAM_SIM_AOT`` is not ``auto``, or a build
    for these sources exists, is under way, or failed before (``<key>.failed`` holds why; ``compile-sim``
    retries). Returns True if started."""
    if mode() != "auto":
        return False
    base, key = cache_dir(), source_key()
    if extension_path(key, base).is_file() or _marker(base, key, "failed").is_file():
        return False
    lock = _marker(base, key, "lock")
    try:
        if lock.is_file() and time.time() - lock.stat().st_mtime < STALE_LOCK_S:
            return False
        base.mkdir(parents=True, exist_ok=True)
        subprocess.Popen([sys.executable, "-m", "renderer.sim_aot", "--background"], stdin=subprocess.DEVNULL,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                         close_fds=True)
    except OSError:  # an unwritable cache or no process slot: the JIT path works without it
        return False
    return True


def build(base: Path | None = None, background: bool = False) -> Path:
    """Compile ``renderer.law.run_sim`` and ``devices.sim.kernel.tick`` into ``<base>/<key>/_hfam_sim_loop<ext>``
    (atomic: built in a temporary folder, renamed when complete; builds of other keys are removed).

    Parameters
    ----------
    base : Path or None
        Folder of the builds (default :func:`cache_dir`).
    background : bool
        Take the build lock and give up quietly if another builder holds it; record a failure in
        ``<key>.failed`` (so later runs do not retry every time) instead of raising.

    Returns
    -------
    Path
        The extension module.
    """
    import hashlib  # deferred: the manifest's SHA-256 only; OpenSSL costs ~7 ms at a run's start-up

    base = cache_dir() if base is None else Path(base)
    key = source_key()
    dest = extension_path(key, base)
    if dest.is_file():
        return dest
    base.mkdir(parents=True, exist_ok=True)
    lock, failed = _marker(base, key, "lock"), _marker(base, key, "failed")
    if background:
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            if time.time() - lock.stat().st_mtime < STALE_LOCK_S:
                return dest
            lock.unlink(missing_ok=True)
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        os.write(fd, str(os.getpid()).encode())
        os.close(fd)
    tmp = Path(tempfile.mkdtemp(prefix=f"{key}.build", dir=base))
    try:
        t0 = time.perf_counter()
        _compile(tmp)
        seconds = time.perf_counter() - t0
        _check_loads(tmp / dest.name)
        (tmp / "manifest.json").write_text(json.dumps({
            "key": key, "sources": {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in SOURCES},
            "python": sys.version, "numpy": np.__version__, "machine": platform.machine(), "options": BUILD_OPTIONS,
            "compile_s": round(seconds, 2)}, indent=2) + "\n", encoding="utf-8")
        try:
            os.rename(tmp, dest.parent)
        except OSError:  # another builder finished first: keep its build
            if not dest.is_file():
                raise
        for old in base.iterdir():  # earlier sources' builds: never loaded again
            if old.is_dir() and old.name != key and ".build" not in old.name and (old / "manifest.json").is_file():
                shutil.rmtree(old, ignore_errors=True)
        failed.unlink(missing_ok=True)
    except Exception as exc:
        if not background:
            raise
        failed.write_text(f"{type(exc).__name__}: {exc}\n", encoding="utf-8")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        if background:
            lock.unlink(missing_ok=True)
    return dest


def _compile(out_dir: Path) -> None:
    """numba.pycc: ``renderer.law.run_sim`` (and everything it calls, inlined) for ``SIGNATURE`` and the
    device's physics step ``devices.sim.kernel.tick`` for ``TICK_SIGNATURE``."""
    import warnings  # deferred: build only

    with warnings.catch_warnings():
        # numba.pycc is "pending deprecation" (numba 0.57+) but is numba's supported AOT path today
        warnings.simplefilter("ignore")
        from numba.pycc import CC  # deferred: numba's compiler, build only

        from devices.sim import kernel  # deferred: the JIT kernel whose source is compiled, build only

        from . import law  # deferred: the JIT law whose source is compiled, build only

        from numba.pycc import compiler as pycc_compiler  # deferred: build only

        cc = CC(MODULE)
        cc.output_dir = str(out_dir)
        cc.verbose = False
        # the kernels never allocate (each is compiled with _nrt=False): no runtime to link in, and a kernel
        # that did need it would make the build fail to load (an undefined NRT symbol), not run slower
        cc.use_nrt = False
        cc.export("run_sim", SIGNATURE)(law.run_sim.py_func)
        cc.export("tick", TICK_SIGNATURE)(kernel.tick.py_func)
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


def _check_loads(path: Path) -> None:
    """Import the fresh build in a process of its own (this one may hold an older build under the same
    module name): a build that cannot load (e.g. an undefined symbol) is never installed.

    Raises
    ------
    RuntimeError
        The build did not load; the message names it and quotes the import error.
    """
    code = ("import importlib.util, sys; spec = importlib.util.spec_from_file_location(sys.argv[2], sys.argv[1]); "
            "m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m); "
            "assert callable(m.run_sim) and callable(m.tick), 'run_sim or tick missing'")
    proc = subprocess.run([sys.executable, "-c", code, str(path), MODULE], capture_output=True, text=True,
                          timeout=300)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise RuntimeError(f"the build {path} does not load: {last}")


def register(subparsers) -> None:
    """Add the ``compile-sim`` command to ``python -m renderer``."""
    p = subparsers.add_parser("compile-sim", help="compile the simulated closed loop ahead of time (fast sim runs)",
                              description="Compile renderer.law.run_sim (servo law + simulated physics) and the "
                                          "device's physics step into an extension module, so simulated runs "
                                          "start without numba. Runs by itself in the background after the "
                                          "first simulated run that finds none (HFAM_SIM_AOT=auto).")
    p.add_argument("--force", action="store_true", help="rebuild even if a build for these sources exists")
    with_examples(p, "hfam-renderer compile-sim", "hfam-renderer compile-sim --force")
    p.set_defaults(func=compile_command)


def compile_command(args) -> int:
    """The ``compile-sim`` command: build (or report the existing build) and print where and how long."""
    path = extension_path()
    if args.force and path.is_file():
        shutil.rmtree(path.parent)
    existed = path.is_file()
    t0 = time.perf_counter()
    path = build()
    what = "up to date" if existed else f"compiled in {time.perf_counter() - t0:.1f} s"
    print(f"simulated closed loop {what}: {path}")
    return 0


def main(argv=None) -> int:
    """``python -m renderer.sim_aot [--background]``: build for the current sources (the background
    builder that :func:`schedule_build` starts; ``python -m renderer compile-sim`` for people)."""
    args = sys.argv[1:] if argv is None else argv
    build(background="--background" in args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
