"""Where the system parts live: programs and libraries provisioned into ``<repo>/.deps`` or installed system-wide.

The project uses a few non-Python parts: PortAudio (masking audio), espeak-ng
(spoken cues), Chromium (browser tests), the AVR toolchain (firmware build),
simavr (running the firmware) and a host C compiler. ``make test`` provisions
the missing ones without root into ``<repo>/.deps`` (``python -m
plumbing.provision``: Debian packages fetched with apt's download-only mode and
unpacked with ``dpkg-deb -x`` into ``.deps/root``, wrappers in ``.deps/bin``);
``make system-deps`` (root) installs them system-wide instead. Code that needs
one of them asks this module, which looks in ``.deps`` first, then the system.

Environment
-----------
``HFAM_DEPS``
    ``auto`` (default): ``.deps`` first, then the system; ``provision``: only
    ``.deps`` (system copies ignored; used to test the provisioning honestly on a
    machine that has them; the machine's own ``cc`` and ``make`` still come from
    the system, see ``BASE_TOOLS``); ``system``: only the system (``.deps`` ignored).
``HFAM_DEPS_DIR``
    The ``.deps`` folder (default: ``.deps`` next to the packages, i.e. in the
    repository of an editable install).
``HFAM_DEPS_WITHOUT``
    Comma-separated component names to treat as absent (to exercise the
    fallbacks, e.g. ``espeak-ng``: the cues become chimes).
``HFAM_MISSING_DEPS``
    ``skip``: tests needing a missing part are skipped with the reason instead of
    failing (opt-in; without it a missing part fails ``make test``).

Only the standard library is imported here, so every command can afford it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import shutil
import struct
import sys
import sysconfig
from dataclasses import dataclass
from pathlib import Path

MODES = ("auto", "provision", "system")


@dataclass(frozen=True)
class Component:
    """One system part the project needs.

    Parameters
    ----------
    name : str
        Short name used by :func:`require`, the stamp and the messages (``"portaudio"``).
    what : str
        What it is, for people.
    packages : tuple of str
        The Debian packages that provide it (``make system-deps`` installs the same).
    tests : str
        The tests that need it (printed when it is missing).
    """

    name: str
    what: str
    packages: tuple[str, ...]
    tests: str


COMPONENTS: dict[str, Component] = {c.name: c for c in (
    Component("portaudio", "PortAudio library (masking audio)", ("libportaudio2", "libjack-jackd2-0"),
              "tests/study/session/test_audio.py"),
    Component("espeak-ng", "espeak-ng speech synthesizer (spoken cues)", ("espeak-ng",),
              "tests/study/session/test_audio.py (spoken cues)"),
    Component("chromium", "Chromium browser (headless view tests)", ("chromium",),
              "tests/study/session/test_views_browser.py, tests/analysis/test_analysis_report.py"),
    Component("avr-toolchain", "AVR toolchain avr-gcc + avr-libc (firmware build)",
              ("gcc-avr", "binutils-avr", "avr-libc"), "tests/devices/firmware/test_c_firmware.py (AVR build)"),
    Component("simavr", "simavr AVR simulator and libsimavr (running the firmware)",
              ("simavr", "libsimavr2", "libsimavr-dev", "libsimavrparts1"), "the simavr firmware tests (tests/devices/firmware/)"),
    Component("cc", "host C compiler cc (C firmware checks)", ("gcc", "libc6-dev"),
              "tests/devices/firmware/test_c_firmware.py (host builds)"),
)}


class MissingDependency(RuntimeError):
    """A system part is not available; the message names it, the tests it affects and the fix."""


def mode() -> str:
    """The lookup mode from ``HFAM_DEPS``: ``"auto"``, ``"provision"`` or ``"system"``.

    Returns
    -------
    str
        One of :data:`MODES`.

    Raises
    ------
    ValueError
        ``HFAM_DEPS`` has another value.
    """
    m = os.environ.get("HFAM_DEPS", "auto").strip() or "auto"
    if m not in MODES:
        raise ValueError(f"HFAM_DEPS={m!r}: expected one of {', '.join(MODES)}")
    return m


def deps_root() -> Path:
    """The ``.deps`` folder (``HFAM_DEPS_DIR``, else ``<repo>/.deps``), whether or not it exists."""
    env = os.environ.get("HFAM_DEPS_DIR")
    if env:
        return Path(env).expanduser().resolve()
    return Path(__file__).resolve().parents[1] / ".deps"


def root_dir() -> Path:
    """``.deps/root``: where the Debian packages are unpacked (their ``/usr`` is ``root/usr``)."""
    return deps_root() / "root"


def bin_dir() -> Path:
    """``.deps/bin``: wrappers that run the unpacked programs with their libraries and data."""
    return deps_root() / "bin"


def multiarch() -> str:
    """The Debian multiarch triplet of this Python (``"x86_64-linux-gnu"``)."""
    return sysconfig.get_config_var("MULTIARCH") or f"{os.uname().machine}-linux-gnu"


def _use_deps() -> bool:
    return mode() != "system"


def _use_system() -> bool:
    return mode() != "provision"


def provisioned_library_dirs() -> list[str]:
    """Library folders inside ``.deps/root`` (existing ones, search order), empty in ``system`` mode."""
    if not _use_deps():
        return []
    r = root_dir()
    dirs = [r / "usr" / "lib" / multiarch(), r / "lib" / multiarch(), r / "usr" / "lib"]
    return [str(d) for d in dirs if d.is_dir()]


def include_dirs() -> list[str]:
    """C include folders to pass as ``-I``: ``.deps/root/usr/include`` when provisioned (system ones are implicit)."""
    if not _use_deps():
        return []
    d = root_dir() / "usr" / "include"
    return [str(d)] if d.is_dir() else []


def library_dirs() -> list[str]:
    """C library folders to pass as ``-L`` and ``-Wl,-rpath,``: the provisioned ones (system ones are implicit)."""
    return provisioned_library_dirs()


def _system_path() -> str:
    deps_bin = str(bin_dir())
    return os.pathsep.join(p for p in os.environ.get("PATH", os.defpath).split(os.pathsep)
                           if p and os.path.abspath(p) != deps_bin)


#: Which component each program belongs to (for ``HFAM_DEPS_WITHOUT``).
_TOOL_COMPONENT = {"espeak-ng": "espeak-ng", "chromium": "chromium", "chromium-browser": "chromium",
                   "simavr": "simavr", "cc": "cc"}


#: Programs of the machine itself (the developers' guide: Python, gcc and make on every machine), never
#: provisioned: ``provision`` mode still takes them from the system.
BASE_TOOLS = frozenset({"cc", "gcc", "make"})


def _hidden(component: str) -> bool:
    # an empty name is no component (an unset variable splits into [""])
    return bool(component) and component in {c.strip() for c in os.environ.get("HFAM_DEPS_WITHOUT", "").split(",")}


def tool(name: str) -> str | None:
    """Full path of program ``name``: ``.deps/bin/<name>`` first, then ``PATH`` (as the mode allows).

    Parameters
    ----------
    name : str
        Program name (``"espeak-ng"``, ``"chromium"``, ``"avr-gcc"``, ``"simavr"``, ``"cc"``).

    Returns
    -------
    str or None
        The path, or None when it is nowhere to be found (or its component is in ``HFAM_DEPS_WITHOUT``).
    """
    if _hidden(_TOOL_COMPONENT.get(name, "avr-toolchain" if name.startswith("avr-") else "")):
        return None
    if _use_deps():
        p = bin_dir() / name
        if p.is_file() and os.access(p, os.X_OK):
            return str(p)
    if _use_system() or name in BASE_TOOLS:
        return shutil.which(name, path=_system_path())
    return None


def tool_env(env: dict | None = None) -> dict:
    """A copy of ``env`` (default ``os.environ``) with ``.deps/bin`` first on ``PATH`` (mode permitting).

    In ``provision`` mode the system folders stay on ``PATH`` after it (``make`` and
    the shell live there), so programs not provisioned still come from the system.
    """
    env = dict(os.environ if env is None else env)
    if _use_deps() and bin_dir().is_dir():
        env["PATH"] = str(bin_dir()) + os.pathsep + env.get("PATH", os.defpath)
    return env


_SYSTEM_LIB_DIRS = ("/usr/lib/{m}", "/lib/{m}", "/usr/local/lib", "/usr/lib", "/lib")


def _system_library(soname: str) -> str | None:
    for d in _SYSTEM_LIB_DIRS:
        p = Path(d.format(m=multiarch())) / soname
        if p.exists():
            return str(p)
    return None


def library(soname: str) -> str | None:
    """Full path of shared library ``soname`` (``"libportaudio.so.2"``): ``.deps`` first, then the system dirs."""
    for d in provisioned_library_dirs():
        p = Path(d) / soname
        if p.exists():
            return str(p)
    return _system_library(soname) if _use_system() else None


def portaudio_library() -> str | None:
    """Full path of ``libportaudio.so.2`` (provisioned or system), or None."""
    return None if _hidden("portaudio") else library("libportaudio.so.2")


def elf_needed(path: str | os.PathLike) -> list[str]:
    """The ``DT_NEEDED`` sonames of a 64-bit little-endian ELF shared object (empty if it is not one).

    Parameters
    ----------
    path : str or path
        The library file.

    Returns
    -------
    list of str
        Sonames in the order the dynamic section lists them.
    """
    data = Path(path).read_bytes()
    if data[:4] != b"\x7fELF" or data[4] != 2 or data[5] != 1:
        return []
    phoff, = struct.unpack_from("<Q", data, 0x20)
    phentsize, phnum = struct.unpack_from("<HH", data, 0x36)
    loads, dyn = [], None
    for k in range(phnum):
        p_type, _, p_offset, p_vaddr, _, p_filesz = struct.unpack_from("<IIQQQQ", data, phoff + k * phentsize)
        if p_type == 1:
            loads.append((p_vaddr, p_offset, p_filesz))
        elif p_type == 2:
            dyn = (p_offset, p_filesz)
    if dyn is None:
        return []

    def offset(vaddr):
        for v, o, n in loads:
            if v <= vaddr < v + n:
                return vaddr - v + o
        return vaddr

    needed, strtab = [], None
    for k in range(dyn[1] // 16):
        tag, val = struct.unpack_from("<qQ", data, dyn[0] + 16 * k)
        if tag == 0:
            break
        if tag == 1:
            needed.append(val)
        elif tag == 5:
            strtab = offset(val)
    if strtab is None:
        return []
    return [data[strtab + n:data.index(b"\0", strtab + n)].decode() for n in needed]


_loaded: dict[str, ctypes.CDLL] = {}


def load_library(path: str | os.PathLike) -> ctypes.CDLL:
    """Load a shared library with ``RTLD_GLOBAL``, loading first its provisioned dependencies.

    ``dlopen`` only searches the system for a library's dependencies, so every
    ``DT_NEEDED`` soname that exists in ``.deps`` is loaded first, by path
    (recursively); later lookups of that soname then find the loaded copy.

    Parameters
    ----------
    path : str or path
        The library file.

    Returns
    -------
    ctypes.CDLL
        The loaded library (kept loaded for the life of the process).
    """
    path = str(path)
    if path in _loaded:
        return _loaded[path]
    for soname in elf_needed(path):
        for d in provisioned_library_dirs():
            dep = Path(d) / soname
            if dep.exists() and str(dep) != path:
                load_library(dep)
                break
    _loaded[path] = ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
    return _loaded[path]


def import_sounddevice():
    """Import ``sounddevice`` with PortAudio loaded from an explicit path (provisioned or system).

    sounddevice finds PortAudio only through ``ctypes.util.find_library``, which
    searches the system (and needs gcc/ld on ``PATH`` for some lookups). Here the
    library found by :func:`portaudio_library` is loaded (with its provisioned
    dependencies, e.g. ``libjack.so.0``) and ``find_library("portaudio")`` returns
    its path while sounddevice is imported, so the provisioned copy is used even
    when ``PATH`` is empty. In ``system`` mode sounddevice searches as usual.

    Returns
    -------
    module
        ``sounddevice``.

    Raises
    ------
    OSError
        PortAudio cannot be found or loaded (sounddevice's own error when it searched).
    """
    if "sounddevice" in sys.modules:
        return sys.modules["sounddevice"]

    path = portaudio_library()
    if path is None and mode() == "provision":
        raise OSError(f"PortAudio library not found in {root_dir()} (HFAM_DEPS=provision; run 'make test' "
                      "or 'python -m plumbing.provision' to provision it)")
    original = ctypes.util.find_library
    if path is not None:  # else sounddevice searches the system itself, with its own error
        load_library(path)

        def find_library(name):
            return path if name == "portaudio" else original(name)

        ctypes.util.find_library = find_library
    try:
        # sounddevice finds PortAudio only while find_library is patched above
        import sounddevice  # deferred: PortAudio may be missing (OSError here, not at import); ~10 ms once found
    finally:
        ctypes.util.find_library = original
    return sounddevice


def _has(component: str) -> bool:
    if _hidden(component):
        return False
    if component == "portaudio":
        return portaudio_library() is not None
    if component == "espeak-ng":
        return tool("espeak-ng") is not None
    if component == "chromium":
        return chromium() is not None
    if component == "avr-toolchain":
        return all(tool(t) for t in ("avr-gcc", "avr-objcopy", "avr-size"))
    if component == "simavr":
        return simavr_header_dir() is not None and library("libsimavr.so.2") is not None and tool("simavr") is not None
    if component == "cc":  # never provisioned: the system's compiler counts in every mode
        return (tool("cc") or shutil.which("cc")) is not None
    raise KeyError(component)


def chromium() -> str | None:
    """Path of the Chromium program (``.deps/bin/chromium`` wrapper, else ``chromium``/``chromium-browser`` on PATH)."""
    return tool("chromium") or tool("chromium-browser")


def simavr_header_dir() -> str | None:
    """The folder holding ``simavr/sim_avr.h`` (pass it as ``-I``), provisioned or system, or None."""
    dirs = include_dirs() + (["/usr/include", "/usr/local/include"] if _use_system() else [])
    for d in dirs:
        if (Path(d) / "simavr" / "sim_avr.h").exists():
            return d
    return None


def simavr_flags() -> tuple[list[str], list[str]]:
    """Compiler and linker flags to build a C harness against libsimavr (provisioned or system).

    Returns
    -------
    cflags, ldflags : list of str
        ``-I<dir> -I<dir>/simavr`` and ``-L<lib> -Wl,-rpath,<lib> -lsimavr -lsimavrparts -lelf``
        (the rpath makes the harness load the provisioned libraries at run time).

    Raises
    ------
    MissingDependency
        simavr's headers or library are missing.
    """
    require("simavr")
    inc = simavr_header_dir()
    cflags = [f"-I{inc}", f"-I{inc}/simavr"]
    ldflags = []
    for d in library_dirs():
        ldflags += [f"-L{d}", f"-Wl,-rpath,{d}"]
    return cflags, ldflags + ["-lsimavr", "-lsimavrparts", "-lelf"]


def missing() -> list[Component]:
    """The components not available in the current mode."""
    return [c for name, c in COMPONENTS.items() if not _has(name)]


def missing_line(c: Component) -> str:
    """One line naming a missing component, the tests it affects and the fix."""
    return (f"missing: {c.what} [{c.name}] needed by {c.tests}; fix: 'make test' provisions it into "
            f"{deps_root()} (apt), or 'make system-deps' as root (Debian packages {' '.join(c.packages)})")


def require(name: str) -> None:
    """Raise :class:`MissingDependency` (naming the component, its tests and the fix) unless ``name`` is available.

    Parameters
    ----------
    name : str
        A key of :data:`COMPONENTS`.
    """
    if not _has(name):
        raise MissingDependency(missing_line(COMPONENTS[name]))
