"""The real firmware in the loop: ``hfam_fw.c`` built with avr-gcc, run on simavr's ATmega328P behind a pty.

:func:`build` compiles the firmware (``make`` in this folder, avr-gcc) and the C harness
``fw_sim.c`` (host ``cc`` against libsimavr) into a cache folder under ``<repo>/build/fw-sim/``
(or a temporary folder when the repository is read-only), keyed by a hash of the sources, so the
source tree stays clean and a second call costs nothing. Tools and libraries are looked up in
``<repo>/.deps`` first (``make test`` provisions them there without root), then the system.

:func:`start_fw_sim` runs the harness: it prints the pty's slave name, which a host opens with the
normal ``serial:<pty>`` device string; :class:`FwSimDevice` (device string ``fw-sim``) does both.
The harness closes the physical loop with a one-axis paddle-and-hand model (the hand taps the
given speeds through the wall height 0), reads the motor command from the PWM compare register,
and measures the firmware's timing (servo tick cycles, interrupt latencies and durations, RAM
high-water by stack painting, encoder counts) into a JSON stats file.

:func:`timing_report` runs the scripted worst case (on-device rendering of a decaying sinusoid,
telemetry every 2nd tick, a host re-arming 128-sample transients, the paddle swept at given speeds)
with no pty and returns the numbers ``python -m devices firmware-report`` prints.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import select
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plumbing import sysdeps
from ..base import DeviceError
from ..hardware.serial_device import SerialDevice

FIRMWARE_DIR = Path(__file__).resolve().parent
REPO = FIRMWARE_DIR.parents[1]
F_CPU_HZ = 16_000_000
SERVO_HZ = 4000
TICK_BUDGET_CYCLES = F_CPU_HZ // SERVO_HZ  # 4,000 cycles per servo period at 4 kHz
RAM_BYTES = 2048
#: The paddle's maximum rated handle speed: above the fastest taps of the thesis's study (40 cm/s,
#: Fig. 4.13) with margin; encoder counts must not be lost up to it.
MAX_RATED_SPEED_M_S = 0.5
UART_BYTE_CYCLES = 160  # 10 bits at 1 Mbaud
#: Harness paces: ``realtime`` follows the wall clock, ``fast`` runs as fast as the host drains telemetry,
#: ``lockstep`` advances the MCU one host period per host frame (the host paces on the MCU's clock).
PACES = ("lockstep", "realtime", "fast")
#: Lockstep: servo ticks of the firmware (4 kHz) per host period; 4 = 1 ms, a 1 kHz streaming loop. A CURRENT
#: (11 bytes) and its STATE (23 bytes) take 340 us of the 1 Mbaud UART plus the firmware's handling, so a
#: 4 kHz (250 us) streaming loop cannot exist on this link; 2 (2 kHz) is the fastest that fits.
LOCKSTEP_TICKS = 4
#: the fewest servo ticks per lockstep period that leave room for a CURRENT and its STATE on the UART (above)
MIN_LOCKSTEP_TICKS = 2
#: Lockstep: wall-clock seconds the MCU waits at the end of a host period for the host's next frame before it
#: runs free in real time (the firmware's watchdog then zeroes the motor as on a board); 0: it waits for ever.
#: 0 by default: a host's honest pauses (the servo loop's host was silent 10+ s after its first tick on the
#: busy machine) must not cost device time; a host that is gone leaves a frozen MCU, which endangers nothing.
LOCKSTEP_FREE_RUN_S = 0.0
SOURCES = ("hfam_fw.c", "hfam_protocol.c", "hfam_protocol.h", "fw_sim.c", "Makefile")


class FwSimError(RuntimeError):
    """The firmware or its harness could not be built or started (message names the tool and the fix)."""


# -- tools (provisioned .deps first, then the system) -------------------------------------------
def _sysdeps():
    """The provisioning helper (``make test``) that knows where ``.deps/`` keeps the AVR tools."""
    return sysdeps


def _deps_root() -> Path:
    return Path(os.environ.get("HFAM_DEPS_DIR") or REPO / ".deps")


def tool(name: str) -> str | None:
    """Path of program ``name``: ``<repo>/.deps/bin`` first, then ``PATH``.

    Parameters
    ----------
    name : str
        Program name (``"avr-gcc"``, ``"avr-nm"``, ``"cc"``, ``"make"``).

    Returns
    -------
    str or None
        Full path, or None when it is nowhere to be found.
    """
    sd = _sysdeps()
    if sd is not None and name != "make":  # make is a base tool, never provisioned
        return sd.tool(name)
    p = _deps_root() / "bin" / name
    if p.is_file() and os.access(p, os.X_OK):
        return str(p)
    return shutil.which(name)


def _tool_env() -> dict:
    sd = _sysdeps()
    if sd is not None:
        return sd.tool_env()
    env = dict(os.environ)
    deps_bin = _deps_root() / "bin"
    if deps_bin.is_dir():
        env["PATH"] = f"{deps_bin}{os.pathsep}{env.get('PATH', os.defpath)}"
    return env


def simavr_flags() -> tuple[list[str], list[str]]:
    """``-I``/``-L``/rpath flags for libsimavr: ``<repo>/.deps/root/usr/...`` when provisioned, else the system.

    Returns
    -------
    cflags, ldflags : list of str
        ``-I<include>/simavr``; ``-L<lib> -Wl,-rpath,<lib>`` (provisioned only) ``-lsimavr -lm``.

    Raises
    ------
    FwSimError
        No simavr headers anywhere.
    """
    root = _deps_root() / "root" / "usr"
    cflags, ldflags = [], []
    for inc in (root / "include", Path("/usr/include"), Path("/usr/local/include")):
        if (inc / "simavr" / "sim_avr.h").exists():
            cflags = [f"-I{inc / 'simavr'}"]
            break
    else:
        raise FwSimError("simavr headers (simavr/sim_avr.h) not found: run `make deps` (provisions simavr into "
                         ".deps) or install the Debian packages simavr libsimavr-dev libsimavrparts1")
    for lib in (root / "lib" / "x86_64-linux-gnu", root / "lib"):
        if (lib / "libsimavr.so").exists() or (lib / "libsimavr.so.2").exists():
            ldflags += [f"-L{lib}", f"-Wl,-rpath,{lib}"]
            if not (lib / "libsimavr.so").exists():
                ldflags += ["-l:libsimavr.so.2"]
            break
    if not any(f.startswith("-l:") for f in ldflags):
        ldflags.append("-lsimavr")
    return cflags, ldflags + ["-lm"]


# -- build ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Build:
    """What :func:`build` produced: the firmware ELF, the harness program, and RAM addresses of symbols."""

    folder: Path
    elf: Path
    harness: Path
    encoder_count_addr: int
    bss_end_addr: int
    parser_addr: int
    probe_addr: int
    data_bytes: int
    bss_bytes: int
    text_bytes: int
    rx_overruns_addr: int = 0
    po_e_addr: int = 0
    tr_k_addr: int = 0
    ev_kind_addr: int = 0
    heat_n_addr: int = 0


def _cache_base() -> Path:
    base = REPO / "build" / "fw-sim"
    try:
        base.mkdir(parents=True, exist_ok=True)
        probe = base / ".probe"
        probe.write_text("")
        probe.unlink()
        return base
    except OSError:
        return Path(tempfile.gettempdir()) / "hfam-fw-sim"


def _digest() -> str:
    h = hashlib.sha256()
    for name in SOURCES:
        h.update(name.encode())
        h.update((FIRMWARE_DIR / name).read_bytes())
    return h.hexdigest()[:16]


def _run(cmd: list[str], what: str, cwd=None) -> str:
    r = subprocess.run(cmd, capture_output=True, text=True, env=_tool_env(), cwd=cwd, timeout=300)
    if r.returncode != 0:
        raise FwSimError(f"{what} failed ({' '.join(cmd[:3])} ...):\n{r.stdout}{r.stderr}")
    return r.stdout


def build(force: bool = False) -> Build:
    """Compile the firmware (avr-gcc) and the simavr harness (cc) on demand into the cache folder.

    Returns
    -------
    Build
        Paths and symbol addresses (data-space addresses, as simavr's ``avr->data`` indexes them).

    Raises
    ------
    FwSimError
        A tool is missing or a compile fails (the message says which and how to provision it).
    """
    for name in ("avr-gcc", "avr-nm", "cc", "make"):
        if tool(name) is None:
            raise FwSimError(f"{name} not found: run `make deps` (provisions the AVR toolchain and simavr into .deps) "
                             "or install gcc-avr binutils-avr avr-libc simavr libsimavr-dev libsimavrparts1 gcc")
    folder = _cache_base() / _digest()
    folder.mkdir(parents=True, exist_ok=True)
    info = folder / "build.json"
    with open(folder / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # parallel test workers build once
        if info.exists() and not force:
            d = json.loads(info.read_text())
            return Build(**{**d, "folder": Path(d["folder"]), "elf": Path(d["elf"]), "harness": Path(d["harness"])})
        out = _run(["make", "-C", str(FIRMWARE_DIR), f"BUILD={folder}", "all"], "firmware build (avr-gcc)")
        sizes = [line.split() for line in out.splitlines() if line.strip().endswith("hfam_fw.elf")][-1]
        text, data, bss = (int(v) for v in sizes[:3])
        elf = folder / "hfam_fw.elf"
        syms = {}
        for line in _run([tool("avr-nm"), str(elf)], "avr-nm").splitlines():
            parts = line.split()
            if len(parts) == 3:
                syms[parts[2]] = int(parts[0], 16) & 0xFFFF  # 0x800000 + data address
        cflags, ldflags = simavr_flags()
        harness = folder / "fw_sim"
        _run([tool("cc"), "-std=gnu99", "-O2", "-Wall", "-Wextra", "-Werror", *cflags, f"-I{FIRMWARE_DIR}", "-o",
              str(harness), str(FIRMWARE_DIR / "fw_sim.c"), str(FIRMWARE_DIR / "hfam_protocol.c"), *ldflags],
             "simavr harness build (cc + libsimavr)")
        b = Build(folder, elf, harness, syms["encoder_count"], syms["__bss_end"], syms["parser"], syms["tick_probe"],
                  data, bss, text, syms["rx_overruns"], syms.get("po_e", 0), syms.get("tr_k", 0), syms.get("ev_kind", 0),
                  syms.get("heat_n", 0))
        d = {k: (str(v) if isinstance(v, Path) else v) for k, v in b.__dict__.items()}
        info.write_text(json.dumps(d, indent=1))
        return b


# -- running -----------------------------------------------------------------------------------------
def _harness_cmd(b: Build, stats: Path, *, pace="realtime", speed=1.0, taps_m_s=(0.05, 0.1, 0.2), hold_m=None,
                 sweep_m_s=(), grip_N=2.0, faults: str | None = None, seed=0, selfhost=False, decimation=1,
                 max_sim_s=None, tick_log: Path | None = None, lockstep_ticks: int = LOCKSTEP_TICKS,
                 lockstep_free_run_s: float = LOCKSTEP_FREE_RUN_S) -> list[str]:
    if pace not in PACES:
        raise ValueError(f"pace must be one of {', '.join(PACES)}, got {pace!r}")
    if not (isinstance(lockstep_ticks, int) and MIN_LOCKSTEP_TICKS <= lockstep_ticks <= 255):
        raise ValueError(f"lockstep_ticks must be a whole number of servo ticks in {MIN_LOCKSTEP_TICKS}..255 (a "
                         f"CURRENT and its STATE take 340 us of the UART, more than one 250 us tick), "
                         f"got {lockstep_ticks!r}")
    if not lockstep_free_run_s >= 0:
        raise ValueError(f"lockstep_free_run_s must be >= 0 s (0: never), got {lockstep_free_run_s!r}")
    if not speed > 0:
        raise ValueError(f"speed must be > 0 (times real time), got {speed!r}")
    cmd = [str(b.harness), "--elf", str(b.elf), "--stats", str(stats), "--pace", pace, "--speed", str(speed),
           "--sym-encoder", str(b.encoder_count_addr), "--sym-bss-end", str(b.bss_end_addr),
           "--sym-parser", str(b.parser_addr), "--sym-probe", str(b.probe_addr), "--grip-N", str(grip_N),
           "--seed", str(int(seed))]
    if b.rx_overruns_addr:
        cmd += ["--sym-rx-overruns", str(b.rx_overruns_addr)]
    if b.po_e_addr:
        cmd += ["--sym-po-e", str(b.po_e_addr)]
    if b.tr_k_addr and b.ev_kind_addr and b.heat_n_addr:
        cmd += ["--sym-tr-k", str(b.tr_k_addr), "--sym-ev-kind", str(b.ev_kind_addr), "--sym-heat-n", str(b.heat_n_addr)]
    if tick_log is not None:
        cmd += ["--tick-log", str(tick_log)]
    if sweep_m_s:
        cmd += ["--sweep", ",".join(f"{v:g}" for v in sweep_m_s)]
    elif hold_m is not None:
        cmd += ["--hold-m", str(hold_m)]
    elif taps_m_s:
        cmd += ["--taps", ",".join(f"{v:g}" for v in taps_m_s)]
    else:
        cmd += ["--hold-m", "0.01"]
    if faults:
        cmd += ["--fault", faults]
    if selfhost:
        cmd += ["--selfhost", "--decimation", str(int(decimation))]
    if max_sim_s:
        cmd += ["--max-sim-s", str(max_sim_s)]
    if pace == "lockstep":
        cmd += ["--lockstep-ticks", str(lockstep_ticks), "--lockstep-free-run-s", str(lockstep_free_run_s)]
    return cmd


class FwSimHandle:
    """A running harness: ``port`` (the pty), ``stats()`` (latest JSON), ``stop()``; a context manager."""

    def __init__(self, port: str, process: subprocess.Popen, stats_path: Path, tmp: tempfile.TemporaryDirectory,
                 tick_log_path: Path | None = None):
        self.port = port
        self.process = process
        self.stats_path = stats_path
        self._tmp = tmp
        self.tick_log_path = tick_log_path
        self.final_stats: dict | None = None
        self.final_tick_log: dict | None = None

    @property
    def alive(self) -> bool:
        """True while the simavr harness runs."""
        return self.process.poll() is None

    def stats(self, wait_s: float = 0.5) -> dict:
        """The harness's latest measurements (rewritten every 50 ms of wall time; ``final`` after stop)."""
        if self.final_stats is not None:
            return self.final_stats
        deadline = time.monotonic() + wait_s
        while True:
            try:
                return json.loads(self.stats_path.read_text())
            except (OSError, ValueError):
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.01)

    def stats_after(self, t_wall: float, timeout_s: float = 2.0) -> dict:
        """Stats written after wall time ``t_wall`` (time.monotonic), to see what happened since."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                if self.stats_path.stat().st_mtime >= time.time() - (time.monotonic() - t_wall):
                    return self.stats()
            except OSError:
                pass
            time.sleep(0.01)
        return self.stats()

    def stop(self, timeout_s: float = 5.0) -> dict:
        """Stop the simulated MCU; return its final stats."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout_s)
        if self.process.stdout:
            self.process.stdout.close()
        if self.final_stats is None:
            try:
                self.final_stats = json.loads(self.stats_path.read_text())
            except (OSError, ValueError):
                self.final_stats = {}
            if self.tick_log_path is not None:
                self.final_tick_log = read_tick_log(self.tick_log_path)
            self._tmp.cleanup()
        return self.final_stats

    def __enter__(self) -> "FwSimHandle":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


TICK_LOG_DTYPE = np.dtype([("t_us", "<u4"), ("encoder", "<i4"), ("accel_raw", "<u2"), ("grip_raw", "<u2"),
                           ("current_q24", "<i4"), ("po_e", "<i4")])


def read_tick_log(path: Path) -> dict:
    """The harness's per-tick log (``--tick-log``): what the firmware read and commanded in every rendered tick.

    The link carries a STATE frame every ``telemetry_decimation`` ticks only; this log, read from the
    simulated MCU's RAM (the firmware's ``tick_probe``) at the end of each tick, has them all, as a
    logic analyser on a real board would.

    Returns
    -------
    dict
        ``t_us``, ``encoder``, ``accel_raw``, ``grip_raw``, ``po_e`` (int arrays, shape (n_ticks,): ``po_e`` is the
        wall's passivity observer's energy after the tick, Q16 A count as the firmware keeps it) and
        ``current_A`` (float array: the commanded current, Q24 -> A).
    """
    raw = np.fromfile(path, dtype=TICK_LOG_DTYPE) if Path(path).exists() else np.zeros(0, TICK_LOG_DTYPE)
    out = {k: raw[k].astype(np.int64) for k in ("t_us", "encoder", "accel_raw", "grip_raw", "po_e")}
    out["current_A"] = raw["current_q24"].astype(np.float64) / 2.0 ** 24
    return out


def start_fw_sim(pace: str = "realtime", speed: float = 1.0, taps_m_s=(0.05, 0.1, 0.2), hold_m: float | None = None,
                 grip_N: float = 2.0, faults: str | None = None, seed: int = 0,
                 startup_timeout_s: float = 10.0, tick_log: bool = False, lockstep_ticks: int = LOCKSTEP_TICKS,
                 lockstep_free_run_s: float = LOCKSTEP_FREE_RUN_S) -> tuple[str, FwSimHandle]:
    """Build if needed and start the real firmware on simavr behind a new pty; return ``(port, handle)``.

    Parameters
    ----------
    pace : {"realtime", "fast", "lockstep"}
        ``realtime``: simulated time follows the wall clock (``speed`` times real time);
        ``fast``: as fast as the host drains the telemetry (at most 2 kB unread in the pty);
        ``lockstep``: the MCU runs one host period (``lockstep_ticks`` servo ticks) per host frame and then
        waits for the next one; INFO tells the host (flags bit 1), which then paces on the MCU's clock
        (docs/protocol.md "Lockstep"). While the firmware renders on board it runs as ``fast``.
    lockstep_ticks : int
        Lockstep: servo ticks (250 us each) per host period; 4 (1 ms, a 1 kHz loop) by default.
    lockstep_free_run_s : float
        Lockstep: wall-clock seconds the MCU waits for the host's next frame before it runs free in real time
        (the firmware's watchdog then zeroes the motor as on a board); 0 (default): it waits for ever.
    taps_m_s : sequence of float
        The hand taps down through the wall height (0) at these speeds, in turn, forever;
        empty: it holds the handle at ``hold_m`` (default 10 mm).
    faults : str or None
        Device -> host faults as the emulator's ``--fault``: ``drop=P,corrupt=P,garbage=P,duplicate=P,
        disconnect_after_s=T`` (T in simulated seconds after the host's first byte).
    hold_m : float or None
        With no taps: the handle height (m) the hand lifts the paddle to from its power-up position 0.
    grip_N : float
        Grip force the FSR channel (ADC1) reads, N.
    seed : int
        Seed of the fault injection.
    tick_log : bool
        Log every rendered tick's inputs and command (see :func:`read_tick_log`); after ``stop()`` it is
        in ``handle.final_tick_log``.

    Returns
    -------
    port, handle : str, FwSimHandle
        The pty's slave path (open it with ``serial:<port>``) and the running harness.
    """
    b = build()
    tmp = tempfile.TemporaryDirectory(prefix="fw-sim-")
    stats = Path(tmp.name) / "stats.json"
    log = Path(tmp.name) / "ticks.bin" if tick_log else None
    cmd = _harness_cmd(b, stats, pace=pace, speed=speed, taps_m_s=taps_m_s, hold_m=hold_m, grip_N=grip_N,
                       faults=faults, seed=seed, tick_log=log, lockstep_ticks=lockstep_ticks,
                       lockstep_free_run_s=lockstep_free_run_s)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.monotonic() + startup_timeout_s
    fd = proc.stdout.fileno()
    out = b""
    while b"PORT " not in out or not out.split(b"PORT ", 1)[1].count(b"\n"):  # libsimavr prints "Loaded ..." first
        ready, _, _ = select.select((fd,), (), (), max(0.0, deadline - time.monotonic()))
        chunk = os.read(fd, 4096) if ready else b""
        if not chunk:
            break
        out += chunk
    line = ("PORT " + out.split(b"PORT ", 1)[1].split(b"\n")[0].decode()) if b"PORT " in out else out.decode()
    if not line.startswith("PORT ") or "\n" in line:
        proc.kill()
        err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
        proc.wait()
        tmp.cleanup()
        raise FwSimError(f"simavr harness did not report its pty within {startup_timeout_s:g} s: {line!r} {err}")
    proc.stderr.close()  # the harness prints to stderr only on a crash; don't let the pipe fill up
    proc.stderr = None
    port = line.split(None, 1)[1].strip()
    return port, FwSimHandle(port, proc, stats, tmp, log)


class FwSimDevice(SerialDevice):
    """Device string ``fw-sim``: the real firmware on simavr, started on ``open()`` and stopped on ``close()``.

    Options (``fw-sim?mode=on-device&pace=fast``): ``pace`` (lockstep, the default | realtime | fast; see
    :func:`start_fw_sim`), ``lockstep_ticks`` (servo ticks per host period, default 4: a 1 kHz streaming loop),
    ``lockstep_free_run_s`` (see :func:`start_fw_sim`), ``lockstep_timeout_s`` (the driver's wait for a reply,
    :class:`~devices.hardware.serial_device.ProtocolDevice`), ``speed`` (times real time),
    ``taps`` (comma-separated tap speeds in m/s, e.g. ``taps=0.05,0.2``), ``hold_m`` (with ``taps=``: the height
    the hand holds the handle at, default 0.01; below the wall it presses into it), ``grip_N``, ``faults``, ``tick_log``
    (1: keep every rendered tick's inputs and command, in ``last_tick_log`` after ``close()``), plus every
    :class:`~devices.hardware.serial_device.SerialDevice` option (``mode``, ``timeout_s``, ...).
    ``baudrate`` defaults to the firmware's 1 Mbaud UART, so the serial driver's telemetry rule
    (:func:`devices.hardware.serial_device.default_telemetry_decimation`) picks a STATE frame every 2nd
    tick: one (23 bytes) every 250 us tick would need 92 % of the link, more than it carries beside the
    servo tick (devices/firmware/README.md).
    """

    def __init__(self, pace: str = "lockstep", speed: float = 1.0, taps="0.05,0.1,0.2", grip_N: float = 2.0,
                 faults: str | None = None, tick_log=0, hold_m: float | None = None,
                 lockstep_ticks=LOCKSTEP_TICKS, lockstep_free_run_s=LOCKSTEP_FREE_RUN_S, **options) -> None:
        if isinstance(taps, (int, float)):
            taps = str(taps)
        try:
            self.taps_m_s = tuple(float(v) for v in str(taps).split(",") if v.strip()) if taps else ()
        except ValueError:
            raise ValueError(f"fw-sim: taps must be comma-separated speeds in m/s, got {taps!r}") from None
        if pace not in PACES:
            raise ValueError(f"fw-sim: pace must be one of {', '.join(PACES)}, got {pace!r}")
        try:
            self.lockstep_ticks, self.lockstep_free_run_s = int(lockstep_ticks), float(lockstep_free_run_s)
        except ValueError:
            raise ValueError(f"fw-sim: lockstep_ticks must be a whole number of servo ticks and lockstep_free_run_s "
                             f"seconds, got {lockstep_ticks!r}, {lockstep_free_run_s!r}") from None
        if not (MIN_LOCKSTEP_TICKS <= self.lockstep_ticks <= 255 and self.lockstep_free_run_s >= 0):
            raise ValueError(f"fw-sim: lockstep_ticks must be in {MIN_LOCKSTEP_TICKS}..255 (a CURRENT and its STATE "
                             f"take 340 us of the UART, more than one 250 us tick) and lockstep_free_run_s >= 0 s, got "
                             f"{lockstep_ticks!r}, {lockstep_free_run_s!r}")
        self.pace, self.speed, self.grip_N, self.faults = pace, float(speed), float(grip_N), faults
        self.tick_log = bool(int(tick_log))
        try:
            self.hold_m = None if hold_m is None else float(hold_m)
        except ValueError:
            raise ValueError(f"fw-sim: hold_m must be a height in m, got {hold_m!r}") from None
        if self.hold_m is not None and (self.taps_m_s or not abs(self.hold_m) <= 0.05):
            raise ValueError(f"fw-sim: hold_m (|hold_m| <= 0.05 m) needs taps= (no taps), got hold_m={hold_m!r}")
        self.last_tick_log: dict | None = None
        self.handle: FwSimHandle | None = None
        options.setdefault("baudrate", 1_000_000)  # the firmware's UART (the pty itself ignores it)
        on_device = str(options.get("mode", "streaming")).replace("_", "-") == "on-device"
        if (pace == "fast" or (pace == "lockstep" and on_device)) and options.get("watchdog_ms") is None:
            # simulated time outruns the host's clock (keepalives every watchdog_ms/4 of wall time):
            # give the firmware watchdog room, or it trips between two keepalives (lockstep runs as fast while
            # the firmware renders on board; streaming in lockstep keeps the firmware's 100 ms: MCU time)
            options["watchdog_ms"] = 2000
        # the simulated MCU keeps its own pace (it may run slower than wall-clock time on a loaded machine), so
        # a late reply is not a lost frame: strict mode (retransmit with backoff) unless asked otherwise
        options.setdefault("max_consecutive_losses", 0)
        super().__init__("(not started)", **options)

    @property
    def name(self) -> str:
        """``fw-sim:<pty>``: the device string's kind and the harness's pseudo-terminal."""
        return f"fw-sim:{self.port}"

    def _open(self) -> None:
        if self.handle is None or not self.handle.alive:
            try:
                self.port, self.handle = start_fw_sim(self.pace, self.speed, self.taps_m_s, hold_m=self.hold_m,
                                                      grip_N=self.grip_N, faults=self.faults, tick_log=self.tick_log,
                                                      lockstep_ticks=self.lockstep_ticks,
                                                      lockstep_free_run_s=self.lockstep_free_run_s)
            except FwSimError as exc:
                raise DeviceError(f"fw-sim: {exc}") from None
        super()._open()

    def close(self) -> None:
        """Zero the output through the firmware, release the port, stop the simulated MCU."""
        try:
            super().close()
        finally:
            if self.handle is not None:
                self.handle.stop()
                self.last_tick_log = self.handle.final_tick_log
                self.handle = None


# -- timing report ---------------------------------------------------------------------------------
def run_selfhosted(sweep_m_s, decimation: int = 1, timeout_s: float = 120.0) -> dict:
    """The scripted worst case with no pty (see module doc).

    Parameters
    ----------
    sweep_m_s : sequence of float
        Paddle speeds (m/s); the paddle moves down and up through +-5 mm once at each.
    decimation : int
        Telemetry every N servo ticks.
    timeout_s : float
        Wall-clock limit of the run.

    Returns
    -------
    dict
        The harness's final stats (``tick_cycles``, ``isr``, ``sweeps``, ...) and ``build`` sizes.
    """
    b = build()
    with tempfile.TemporaryDirectory(prefix="fw-sim-") as tmp:
        stats = Path(tmp) / "stats.json"
        cmd = _harness_cmd(b, stats, pace="fast", sweep_m_s=tuple(sweep_m_s), selfhost=True, decimation=decimation)
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        if r.returncode != 0 or "error:" in r.stderr:
            raise FwSimError(f"simulated firmware stopped: {r.stderr.strip()}")
        out = json.loads(stats.read_text())
    out["build"] = {"text_bytes": b.text_bytes, "data_bytes": b.data_bytes, "bss_bytes": b.bss_bytes}
    return out


def timing_report(speeds_m_s=(0.1, 0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0), decimation: int = 2) -> dict:
    """Servo tick cycles, ISR worst cases, RAM high-water and encoder counts missed per paddle speed.

    Two runs: the timing run sweeps the paddle only up to :data:`MAX_RATED_SPEED_M_S` (the rated
    operating range), the encoder run continues to ``speeds_m_s`` to find where counts drop.

    Returns
    -------
    dict
        ``tick`` (min/median/p99/max cycles from the Timer1 compare match to the end of the tick), ``tick_body``
        (from the tick's start), ``tick_own`` (its own code: no latency, no nested interrupts), ``budget_cycles``, ``margin_cycles`` (budget - max), ``lost_ticks``, ``isr``
        (per vector max cycles and max latency), ``uart_rx_deadline_cycles`` (two characters at 1 Mbaud),
        ``ram`` (static + stack high-water bytes of 2048), ``encoder`` (per speed: counts, missed),
        ``first_missing_speed_m_s``, ``fw_parser`` (the firmware parser's CRC-error and garbage counts),
        ``fw_rx_overruns`` (received bytes dropped on a full RX ring) and ``selfhost`` (what the scripted host
        got back: ``rearm_acks``, ``rearms`` (re-arm uploads acknowledged to the commit), ``rearm_timeouts``,
        ``events_sinusoid``, ``events_rearm`` (contacts by the transient they played), ``rearm_busy`` (REARM_DATA
        refused while the re-armed transient played), ``rearm_max_ms``), ``worst_tick`` (the longest tick taken
        apart: ``latency`` from the compare match, ``nested`` interrupts [count, cycles] per vector, ``transient_kind``
        it played, -1 none; ``pc_cycles`` per instruction address), ``transient_ticks`` (per kind: ticks that played a
        sample, ``with_rx`` of them while bytes arrived, ``max_cycles``) and ``rearm_data_frames`` (handling cycles
        per REARM_DATA frame, with and without the interrupts meanwhile).

    The timing run's sweeps (each rated speed twice) pass through the wall: every downward pass is a contact; the
    scripted host plays the sinusoid, re-arms a 128-sample transient every 20 ms in the second half and switches
    back to the sinusoid after every second re-arm, so contacts play both while re-arm frames arrive.
    """
    rated = [v for v in speeds_m_s if v <= MAX_RATED_SPEED_M_S] or [MAX_RATED_SPEED_M_S]
    t = run_selfhosted(rated * 2, decimation)
    e = run_selfhosted(speeds_m_s, decimation)
    tick, body = t["tick_cycles"], t["tick_body_cycles"]
    static = t["build"]["data_bytes"] + t["build"]["bss_bytes"]
    first_drop = next((s["v_m_s"] for s in e["sweeps"] if s["missed"]), None)
    return {
        "f_cpu_hz": F_CPU_HZ, "servo_hz": SERVO_HZ, "telemetry_decimation": decimation,
        "budget_cycles": TICK_BUDGET_CYCLES, "tick": tick, "tick_body": body, "tick_own": t["tick_own_cycles"],
        "margin_cycles": TICK_BUDGET_CYCLES - tick["max"],
        "ticks": t["ticks"], "compare_matches": t["compare_matches"],
        "lost_ticks": t["compare_matches"] - t["ticks"], "frame_handling_max_cycles": t["frame_handling_max_cycles"],
        "isr": t["isr"], "uart_rx_deadline_cycles": 2 * UART_BYTE_CYCLES,
        "ram": {"static_bytes": static, "stack_high_water_bytes": t["ram_stack_high_water_bytes"],
                "total_bytes": static + t["ram_stack_high_water_bytes"], "of_bytes": RAM_BYTES},
        "encoder": e["sweeps"], "first_missing_speed_m_s": first_drop, "max_rated_speed_m_s": MAX_RATED_SPEED_M_S,
        "sim_time_s": t["sim_time_s"] + e["sim_time_s"], "telemetry_seq_gaps": t["selfhost"]["seq_gaps"],
        "fw_parser": t.get("fw_parser", {}), "fw_rx_overruns": t.get("fw_rx_overruns"),
        "selfhost": t["selfhost"], "worst_tick": t["worst_tick"], "transient_ticks": t["transient_ticks"],
        "rearm_data_frames": t["rearm_data_frames"],
    }


def format_report(r: dict) -> str:
    """The report as text (what ``python -m devices firmware-report`` prints).

    Parameters
    ----------
    r : dict
        What :func:`timing_report` returned.

    Returns
    -------
    str
        One line per measurement.
    """
    tk, bd, ram = r["tick"], r["tick_body"], r["ram"]
    lines = [
        f"firmware on simavr: ATmega328P at {r['f_cpu_hz'] / 1e6:g} MHz, servo {r['servo_hz']} Hz "
        f"(budget {r['budget_cycles']} cycles), telemetry every {r['telemetry_decimation']} tick(s), "
        f"{r['sim_time_s']:.2f} s simulated",
        f"servo tick, compare match -> done: min {tk['min']} / median {tk['median']} / p99 {tk['p99']} / "
        f"max {tk['max']} cycles; margin {r['margin_cycles']} cycles "
        f"({'fits' if r['margin_cycles'] > 0 else 'OVER BUDGET'})",
        f"servo tick code incl. interrupts: min {bd['min']} / median {bd['median']} / p99 {bd['p99']} / max {bd['max']} cycles",
        f"servo tick code alone (no latency, no nested interrupts): median {r['tick_own']['median']} / p99 "
        f"{r['tick_own']['p99']} / max {r['tick_own']['max']} cycles",
        f"ticks run {r['ticks']} of {r['compare_matches']} timer periods (lost {r['lost_ticks']}); "
        f"longest frame handling {r['frame_handling_max_cycles']} cycles",
    ]
    w, sh, tt, rf = r["worst_tick"], r["selfhost"], r["transient_ticks"], r["rearm_data_frames"]
    kinds = {-1: "no transient", 1: "pulse", 2: "sinusoid", 4: "re-armed transient"}
    lines.append(f"worst tick: {w['cycles']} cycles = compare-match latency {w['latency']} + nested interrupts " +
                 ", ".join(f"{k} {n}x {c}" for k, (n, c) in w["nested"].items() if n) +
                 f" + tick code; it played {kinds.get(w['transient_kind'], w['transient_kind'])}")
    lines.append(f"contacts: {sh['events']} ({sh['events_sinusoid']} sinusoid, {sh['events_rearm']} re-armed); transient "
                 f"ticks: sinusoid {tt['2']['n']} ({tt['2']['with_rx']} while a frame arrived, max {tt['2']['max_cycles']} "
                 f"cycles), re-armed {tt['4']['n']} ({tt['4']['with_rx']}, max {tt['4']['max_cycles']} cycles)")
    lines.append(f"re-arms: {sh['rearms']} committed ({sh['rearm_acks']} frames acknowledged, {sh['rearm_busy']} refused "
                 f"while the re-armed transient played), longest upload {sh['rearm_max_ms']:.1f} ms; REARM_DATA (24 "
                 f"samples) handling mean {rf['own_mean_cycles']:.0f} / max {rf['own_max_cycles']} cycles of its own "
                 f"(incl. interrupts meanwhile mean {rf['mean_cycles']:.0f} / max {rf['max_cycles']})")
    for name, s in r["isr"].items():
        if s["n"]:
            lines.append(f"ISR {name:<13} n {s['n']:>6}  max {s['max_cycles']:>4} cycles  max latency "
                         f"{s['max_latency_cycles']:>5} cycles")
    rx = r["isr"].get("USART_RX", {})
    lines.append(f"UART RX worst case: latency {rx.get('max_latency_cycles')} + {rx.get('max_cycles')} cycles vs "
                 f"{r['uart_rx_deadline_cycles']} cycles before the 2-byte receive FIFO overruns at 1 Mbaud")
    lines.append(f"RAM: {ram['static_bytes']} B static + {ram['stack_high_water_bytes']} B stack high-water "
                 f"(painted) = {ram['total_bytes']} of {ram['of_bytes']} B")
    for s in r["encoder"]:
        lines.append(f"encoder at {s['v_m_s']:5.2f} m/s: {s['counts']} counts, {s['missed']} missed")
    drop = r["first_missing_speed_m_s"]
    lines.append(f"encoder counts first drop at {drop} m/s (rated {r['max_rated_speed_m_s']} m/s)" if drop else
                 f"no encoder count lost up to {max(s['v_m_s'] for s in r['encoder'])} m/s "
                 f"(rated {r['max_rated_speed_m_s']} m/s)")
    return "\n".join(lines)
