"""The simulated closed loops compiled ahead of time: ``renderer.law.run_sim`` and ``renderer.law3.run_sim3``
as C extensions.

``renderer.law.run_sim`` runs the servo law and the simulated device's physics together (the law of
every loop, the physics of ``devices.sim.kernel``); ``renderer.law3.run_sim3`` does the same in 3-D (the
god-object proxy of ``renderer.proxy``, the 3-D law, the 3-DOF device's tap axis and lateral axes).
JIT-compiled, a process pays ~0.3-0.5 s before its first tick: importing numba (which also loads
scipy.linalg) and loading the cached machine code. The same functions compiled once by ``numba.pycc``
into extension modules load in milliseconds without numba, so a whole ``renderer run --device sim`` (or
``sim:3d``) process costs little more than its physics.

Two builds (:data:`TARGETS`), each its own extension: the 1-DOF loop (``_hfam_sim_loop``: ``run_sim``,
the device's physics step ``tick`` and homing's loop ``run_homing``, :mod:`renderer.homing`) and the 3-D loop (``_hfam_sim3_loop``: ``run_sim3``, the per-tick
``law3_tick``, the proxy's ``proxy_step`` and ``first_hit``, and ``tick``), so an edit of the 3-D law
leaves the 1-DOF build in use and the other way round.

One source: each extension is built from the JIT functions themselves (same Python source, same LLVM
pipeline: the logs are bit-identical, ``tests/renderer/test_sim_aot.py``). Each build lives in a folder
named by a digest of the sources it was built from (``Target.sources``), Python and numpy, so an edited
law, proxy or kernel is never run from a stale build: it falls back to the JIT path until rebuilt.

Where and when (docs/renderer.md, "Compiled ahead of time"):

* ``$HFAM_SIM_AOT_DIR`` or ``$XDG_CACHE_HOME/hfam-haptics/sim-loop`` (``~/.cache/...``);
* built by ``python -m renderer compile-sim`` (both; ~5 s and ~15 s; ``make bench`` does it), or in the
  background after the first ``renderer run`` on a simulated device that found none (a detached ``python -m
  renderer.sim_aot``, one at a time per build; runs until it is done use the JIT path);
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
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import NamedTuple

import numpy as np

import devices.sim.layout
from plumbing.fileio import user_cache_dir

MODULE = "_hfam_sim_loop"
#: renderer.law.run_sim(c, w, log, dev, sp, ss, srs, traj, grip, n_max) -> ticks run
SIGNATURE = ("int64(float64[::1], float64[::1], float64[:, ::1], float64[::1], float64[::1], float64[::1], "
             "uint64[::1], float64[::1], float64[::1], int64)")
#: devices.sim.kernel.tick(s, p, rs, traj, grip, k, i_cmd) -> (position_m, accel_m_s2, grip_N, hot)
TICK_SIGNATURE = ("UniTuple(float64, 4)(float64[::1], float64[::1], uint64[::1], float64[::1], float64[::1], "
                  "int64, float64)")
#: renderer.law.run_homing(h, dev, sp, ss, srs, traj, grip, n_max) -> return code (renderer.homing's compiled loop)
HOMING_SIGNATURE = ("int64(float64[::1], float64[::1], float64[::1], float64[::1], uint64[::1], float64[::1], "
                    "float64[::1], int64)")
_SCENE = "float64[:, ::1], float64[:, ::1], float64[:, ::1], int64[::1]"      # obj, tri, node, stack
#: renderer.law3.run_sim3(c, w, obj, tri, node, stack, log, dev, sp, ss, srs, traj, grip, lat, lp, frame, igrav,
#: n_max) -> ticks run
SIGNATURE3 = (f"int64(float64[::1], float64[::1], {_SCENE}, float64[:, ::1], float64[::1], float64[::1], "
              "float64[::1], uint64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], "
              "float64, int64)")
#: renderer.law3.law3_tick(c, w, obj, tri, node, stack, log, t, x, y, z, acc, grip, status) -> (fx, fy, fz)
LAW3_SIGNATURE = (f"UniTuple(float64, 3)(float64[::1], float64[::1], {_SCENE}, float64[:, ::1], float64, float64, "
                  "float64, float64, float64, float64, int64)")
#: renderer.proxy.proxy_step(obj, tri, node, stack, ps, gx, gy, gz) -> constraints met
PROXY_SIGNATURE = f"int64({_SCENE}, float64[::1], float64, float64, float64)"
#: renderer.proxy.first_hit(obj, tri, node, stack, a, b) -> (t, object, normal, shaded normal, surface point)
FIRST_HIT_SIGNATURE = (f"Tuple((float64, int64, float64, float64, float64, float64, float64, float64, float64, "
                       f"float64, float64))({_SCENE}, float64, float64, float64, float64, float64, float64)")
_RENDERER = Path(__file__).resolve().parent
_SIM = Path(devices.sim.layout.__file__).resolve().parent
#: every file whose source is compiled into the 1-DOF extension (run_sim and all it calls)
SOURCES = (_RENDERER / "law.py", _RENDERER / "law_layout.py", _RENDERER / "passivity.py", _RENDERER / "ring.py",
           _RENDERER / "scene.py",
           _SIM / "kernel.py", _SIM / "layout.py")
#: every file whose source is compiled into the 3-D extension, or that the files compiled in import (the
#: scene's modules: their constants; tests/plumbing/test_jitcache.py checks the list against the imports)
SOURCES3 = (_RENDERER / "law3.py", _RENDERER / "law3_layout.py", _RENDERER / "proxy.py",
            _RENDERER / "proxy_layout.py", _RENDERER / "scene3.py", _RENDERER / "scene.py", _RENDERER / "meshfile.py",
            _RENDERER / "passivity.py", _RENDERER / "ring.py", _SIM / "kernel.py", _SIM / "layout.py",
            _SIM / "lateral.py")
MODES = ("auto", "nobuild", "off")


@dataclass(frozen=True)
class Target:
    """One ahead-of-time build: its extension module's name, the sources that key it, and what it exports.

    ``exports``: (name in the extension, ``module:function`` of the JIT function compiled, numba signature).
    ``name`` is the build's ``--target`` in ``python -m renderer.sim_aot``.
    """

    name: str
    module: str
    sources: tuple
    exports: tuple


#: the 1-DOF simulated loop (renderer.law.run_sim) and the device's physics step
LOOP1 = Target("1d", MODULE, SOURCES, (("run_sim", "renderer.law:run_sim", SIGNATURE),
                                       ("tick", "devices.sim.kernel:tick", TICK_SIGNATURE),
                                       ("run_homing", "renderer.law:run_homing", HOMING_SIGNATURE)))
#: the 3-D simulated loop (renderer.law3.run_sim3), its per-tick law, the proxy's steps, the physics step
LOOP3 = Target("3d", "_hfam_sim3_loop", SOURCES3, (("run_sim3", "renderer.law3:run_sim3", SIGNATURE3),
                                                   ("law3_tick", "renderer.law3:law3_tick", LAW3_SIGNATURE),
                                                   ("proxy_step", "renderer.proxy:proxy_step", PROXY_SIGNATURE),
                                                   ("first_hit", "renderer.proxy:first_hit", FIRST_HIT_SIGNATURE),
                                                   ("tick", "devices.sim.kernel:tick", TICK_SIGNATURE)))
TARGETS = {t.name: t for t in (LOOP1, LOOP3)}
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


def source_key(target: Target = LOOP1) -> str:
    """Key (16 hex) of a build's compiled sources, the Python build, numpy's version and the machine.

    Two CRC-32s (zlib: loaded anyway; hashlib's OpenSSL costs ~7 ms at start-up), of the sources and of
    the environment with every source's name and length: an edit changes the key (a CRC-32 catches every
    change of up to 32 bits and misses others with odds 2^-32); it guards against stale builds, not
    against adversaries. The manifest of each build records the sources' SHA-256 as well.
    """
    blob = b"".join(path.read_bytes() for path in target.sources)
    env = "|".join([sys.version, np.__version__, platform.machine(), sys.implementation.cache_tag, BUILD_OPTIONS,
                    *(f"{p.name}:{p.stat().st_size}" for p in target.sources)])
    return f"{zlib.crc32(blob):08x}{zlib.crc32(env.encode()):08x}"


def extension_path(key: str | None = None, base: Path | None = None, target: Target = LOOP1) -> Path:
    """Where the build of ``target`` for ``key`` (default: the current sources) lives."""
    key = source_key(target) if key is None else key
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    return (cache_dir() if base is None else base) / key / (target.module + suffix)


def load(target: Target = LOOP1):
    """The ahead-of-time compiled extension module of ``target``, or None: no build for these sources,
    ``HFAM_SIM_AOT=off``, or a build that fails to load (reported once on stderr). Looked up once per
    process."""
    if target.module in _loaded:
        return _loaded[target.module]
    found = None
    if mode() != "off":
        path = extension_path(target=target)
        if path.is_file():
            try:
                spec = importlib.util.spec_from_file_location(target.module, path)
                module = importlib.util.module_from_spec(spec)
                spec.loader.exec_module(module)
                found = module if all(callable(getattr(module, name, None)) for name, _, _ in target.exports) \
                    else None
            except Exception as exc:  # a damaged or foreign build: the JIT path gives the same results
                print(f"renderer: the ahead-of-time compiled loop {path} did not load ({exc}); using the "
                      f"JIT-compiled one (rebuild: python -m renderer compile-sim)", file=sys.stderr)
    _loaded[target.module] = found
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
    return jit_laws().law.run_sim, None


class Kernels3(NamedTuple):
    """The compiled functions of the 3-D loop: from the ahead-of-time build (``aot``) or numba's JIT."""

    run_sim3: object
    law3_tick: object
    proxy_step: object
    first_hit: object
    #: the device's physics step for ``SimDevice.use_compiled_step`` (None: the device keeps its JIT step)
    tick: object
    aot: bool


def loop3_kernels() -> Kernels3:
    """The 3-D loop's compiled functions (:class:`Kernels3`): the ahead-of-time build's if there is one for
    these sources (:data:`LOOP3`), else ``renderer.law3``'s and ``renderer.proxy``'s (numba JIT). Never
    builds (as :func:`run_sim_function`)."""
    module = load(LOOP3)
    if module is not None:
        return Kernels3(module.run_sim3, module.law3_tick, module.proxy_step, module.first_hit, module.tick, True)
    law3 = jit_laws().law3
    return Kernels3(law3.run_sim3, law3.law3_tick, law3.PX.proxy_step, law3.PX.first_hit, None, False)


def jit_laws():
    """The JIT-compiled laws (``renderer.law``, ``renderer.law3``), imported by the first loop that runs
    per tick or finds no current ahead-of-time build (both at once: the second costs ~10 ms more)."""
    from . import law, law3  # deferred: numba and the JIT laws, 0.7 s CPU; a run with ahead-of-time builds needs none of it

    return SimpleNamespace(law=law, law3=law3)


def _marker(base: Path, key: str, kind: str) -> Path:
    """``<base>/<key>.lock`` (a builder is at work) or ``<base>/<key>.failed`` (why the last build failed)."""
    return base / f"{key}.{kind}"


def schedule_build(target: Target = LOOP1) -> bool:
    """Start ``python -m renderer.sim_aot --background --target <name>`` detached, unless ``HFAM_SIM_AOT``
    is not ``auto``, or a build for these sources exists, is under way, or failed before (``<key>.failed``
    holds why; ``compile-sim`` retries). Returns True if started."""
    if mode() != "auto":
        return False
    base, key = cache_dir(), source_key(target)
    if extension_path(key, base, target).is_file() or _marker(base, key, "failed").is_file():
        return False
    lock = _marker(base, key, "lock")
    try:
        if lock.is_file() and time.time() - lock.stat().st_mtime < STALE_LOCK_S:
            return False
        base.mkdir(parents=True, exist_ok=True)
        subprocess.Popen([sys.executable, "-m", "renderer.sim_aot", "--background", "--target", target.name],
                         stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True, close_fds=True)
    except OSError:  # an unwritable cache or no process slot: the JIT path works without it
        return False
    return True


def build(base: Path | None = None, background: bool = False, target: Target = LOOP1) -> Path:
    """Compile ``target``'s functions into ``<base>/<key>/<module><ext>`` (atomic: built in a temporary
    folder, renamed when complete; the same target's builds of other keys are removed).

    Parameters
    ----------
    base : Path or None
        Folder of the builds (default :func:`cache_dir`).
    background : bool
        Take the build lock and give up quietly if another builder holds it; record a failure in
        ``<key>.failed`` (so later runs do not retry every time) instead of raising.
    target : Target
        :data:`LOOP1` (default) or :data:`LOOP3`.

    Returns
    -------
    Path
        The extension module.
    """
    base = cache_dir() if base is None else Path(base)
    key = source_key(target)
    dest = extension_path(key, base, target)
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
        sources = _compile(tmp, target)
        seconds = time.perf_counter() - t0
        _check_loads(tmp / dest.name, target)
        (tmp / "manifest.json").write_text(json.dumps({
            "key": key, "module": target.module, "sources": sources,
            "python": sys.version, "numpy": np.__version__, "machine": platform.machine(), "options": BUILD_OPTIONS,
            "compile_s": round(seconds, 2)}, indent=2) + "\n", encoding="utf-8")
        try:
            os.rename(tmp, dest.parent)
        except OSError:  # another builder finished first: keep its build
            if not dest.is_file():
                raise
        for old in base.iterdir():  # earlier sources' builds of this target: never loaded again
            if old.is_dir() and old.name != key and ".build" not in old.name and _built_module(old) == target.module:
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


def _built_module(folder: Path) -> str | None:
    """The extension module a build folder holds (its manifest's ``module``; builds made before there
    were two targets hold the 1-DOF one), or None for a folder that is not a finished build."""
    try:
        manifest = json.loads((folder / "manifest.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return manifest.get("module", MODULE) if isinstance(manifest, dict) else None


def _compile(out_dir: Path, target: Target = LOOP1) -> dict:
    """Compile ``target``'s extension into ``out_dir`` (:func:`renderer.sim_aot_build.compile_extension`).

    Returns
    -------
    dict
        Source file name -> SHA-256 (hex) of each of ``target.sources``, for the build's manifest.
    """
    from . import sim_aot_build  # deferred: numba's compiler and the JIT sources, 1.1 s CPU; a run never builds

    sim_aot_build.compile_extension(out_dir, target.module, target.exports)
    return {p.name: sim_aot_build.sha256_hex(p) for p in target.sources}


def _check_loads(path: Path, target: Target = LOOP1) -> None:
    """Import the fresh build in a process of its own (this one may hold an older build under the same
    module name): a build that cannot load (e.g. an undefined symbol) is never installed.

    Raises
    ------
    RuntimeError
        The build did not load; the message names it and quotes the import error.
    """
    names = [name for name, _, _ in target.exports]
    code = ("import importlib.util, sys; spec = importlib.util.spec_from_file_location(sys.argv[2], sys.argv[1]); "
            "m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m); "
            "missing = [n for n in sys.argv[3:] if not callable(getattr(m, n, None))]; "
            "assert not missing, f'{missing} missing'")
    proc = subprocess.run([sys.executable, "-c", code, str(path), target.module, *names], capture_output=True,
                          text=True, timeout=300)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise RuntimeError(f"the build {path} does not load: {last}")


def compile_command(args) -> int:
    """The ``compile-sim`` command: build both loops (or report the existing builds), print where and how long."""
    for target in TARGETS.values():
        path = extension_path(target=target)
        if args.force and path.is_file():
            shutil.rmtree(path.parent)
        existed = path.is_file()
        t0 = time.perf_counter()
        path = build(target=target)
        what = "up to date" if existed else f"compiled in {time.perf_counter() - t0:.1f} s"
        label = "simulated closed loop" if target is LOOP1 else "simulated 3-D closed loop"
        print(f"{label} {what}: {path}", flush=True)
    return 0


def main(argv=None) -> int:
    """``python -m renderer.sim_aot [--background] [--target 1d|3d]``: build for the current sources (the
    background builder that :func:`schedule_build` starts; ``python -m renderer compile-sim`` for people)."""
    args = list(sys.argv[1:] if argv is None else argv)
    name = args[args.index("--target") + 1] if "--target" in args[:-1] else LOOP1.name
    if name not in TARGETS:
        print(f"error: --target must be one of {', '.join(TARGETS)}, got {name!r}", file=sys.stderr)
        return 2
    build(background="--background" in args, target=TARGETS[name])
    return 0


if __name__ == "__main__":
    sys.exit(main())
