"""Real-time treatment of the servo process: ask the OS for what it allows, record what was obtained.

The thesis ran its loops under RTAI; here the servo process (``renderer.process``, the study's
``study.isolated``) asks Linux for

* ``SCHED_FIFO`` at :data:`RT_PRIORITY` (80: above every ordinary process and the kernel's threaded
  interrupt handlers at 50, below the kernel's own watchdog/migration threads at 99; ``chrt -f 80``
  gave p99 102.7 us in our measurement);
* ``mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT)``: no page of the loop is paged out or faulted in
  from disk;
* CPU affinity to :func:`servo_core` (the last allowed CPU), which the rest of the program avoids
  while the servo runs (:func:`avoid_core` in the parent);
* the cyclic garbage collector frozen and disabled for the loop (:func:`gc_paused`);

and reads ``/proc/sys/kernel/sched_rt_runtime_us`` (RT throttling). Where a privilege is missing the run goes
on at normal priority and the parent prints ONE warning line naming the remedy (:func:`warn_once`).

RT throttling: Linux gives all SCHED_FIFO tasks of a CPU at most ``rt_runtime_us`` of every ``rt_period_us``
(default 950 000 of 1 000 000 us) and then stalls them for the rest of the period (~50 ms each second). A loop
that busy-waits its whole period under SCHED_FIFO therefore stalls 50 ms every second. The paced loop
(``renderer.loop``, ``pacing="sleep_spin"``) sleeps to an absolute deadline (``time.sleep`` is
``clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)`` since Python 3.11) and spins only the last
``spin_margin_s``; under SCHED_FIFO the wake-up is prompt, so :func:`fifo_spin_margin_s` shortens the spin to
:data:`FIFO_SPIN_MARGIN_S` and checks that the loop's duty (spin + compute per period) stays well under the
throttling budget. Pure spinning (``pacing="spin"``) is never run under SCHED_FIFO: the policy falls back to
the default one for it. With throttling disabled (``-1``) the same short spin keeps the core's other
(kernel) threads alive.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import os
import sys

try:  # POSIX only; this module must import everywhere
    import resource
except ImportError:  # pragma: no cover - Windows
    resource = None

#: SCHED_FIFO priority of the servo process (1..99; docs/renderer.md, "Real-time scheduling")
RT_PRIORITY = 80
#: spin before a deadline under SCHED_FIFO (s): the wake-up from clock_nanosleep is then prompt (measured
#: p99 wake-up lateness a few us on this machine, benchmarks/bench_timing.py), so 20 us of spin suffices
FIFO_SPIN_MARGIN_S = 20e-6
#: the highest fraction of the RT throttling budget the loop's busy part may use
MAX_THROTTLE_SHARE = 0.5

MCL_CURRENT, MCL_FUTURE, MCL_ONFAULT = 1, 2, 4
RT_RUNTIME_PATH = "/proc/sys/kernel/sched_rt_runtime_us"
RT_PERIOD_PATH = "/proc/sys/kernel/sched_rt_period_us"

_warned: set = set()


def read_rt_throttling() -> dict:
    """Linux's RT throttling settings.

    Returns
    -------
    dict
        ``rt_runtime_us`` (int, -1 = throttling off, None = unknown), ``rt_period_us`` (int or None) and
        ``rt_share`` (runtime / period, 1.0 when off, None when unknown).
    """
    out = {"rt_runtime_us": None, "rt_period_us": None, "rt_share": None}
    try:
        with open(RT_RUNTIME_PATH, encoding="ascii") as fh:
            out["rt_runtime_us"] = int(fh.read().strip())
        with open(RT_PERIOD_PATH, encoding="ascii") as fh:
            out["rt_period_us"] = int(fh.read().strip())
    except (OSError, ValueError):
        return out
    if out["rt_runtime_us"] < 0:
        out["rt_share"] = 1.0
    elif out["rt_period_us"]:
        out["rt_share"] = out["rt_runtime_us"] / out["rt_period_us"]
    return out


def allowed_cores() -> list[int]:
    """The CPUs this process may run on (sorted), or ``[]`` where the OS does not say."""
    getter = getattr(os, "sched_getaffinity", None)
    return sorted(getter(0)) if getter is not None else []


def servo_core(cores: list[int] | None = None) -> int | None:
    """The CPU the servo process is pinned to: the last allowed one (CPU 0 takes most interrupts), or None
    with a single CPU (nothing to set apart)."""
    cores = allowed_cores() if cores is None else sorted(cores)
    return cores[-1] if len(cores) > 1 else None


def fifo_spin_margin_s(period_s: float, spin_margin_s: float, compute_s: float = 15e-6) -> float:
    """The spin before each deadline under SCHED_FIFO (s), within the RT throttling budget.

    Parameters
    ----------
    period_s : float
        Servo period (s).
    spin_margin_s : float
        The configured spin (``RendererConfig.spin_margin_s``, s); the result never exceeds it.
    compute_s : float
        Budgeted compute time per tick (s).

    Returns
    -------
    float
        ``min(spin_margin_s, FIFO_SPIN_MARGIN_S)``, further shortened so spin + compute use at most
        :data:`MAX_THROTTLE_SHARE` of the throttling budget (module doc).
    """
    share = read_rt_throttling()["rt_share"] or 0.95
    budget = MAX_THROTTLE_SHARE * min(share, 1.0) * period_s - compute_s
    return max(0.0, min(spin_margin_s, FIFO_SPIN_MARGIN_S, budget))


def _libc():
    try:
        return ctypes.CDLL(None, use_errno=True)
    except OSError:
        return None


def _limits() -> dict:
    """RLIMIT_RTPRIO and RLIMIT_MEMLOCK (soft), where the platform has them."""
    out = {}
    if resource is None:
        return out
    for name in ("RLIMIT_RTPRIO", "RLIMIT_MEMLOCK"):
        key = getattr(resource, name, None)
        if key is not None:
            soft = resource.getrlimit(key)[0]
            out[name.lower()] = "unlimited" if soft == resource.RLIM_INFINITY else int(soft)
    return out


def acquire(priority: int = RT_PRIORITY, core: int | None = None, lock_memory: bool = True,
            fifo: bool = True) -> dict:
    """Ask the OS for real-time treatment of this process; return what was obtained.

    Parameters
    ----------
    priority : int
        SCHED_FIFO priority (1..99).
    core : int or None
        CPU to pin this process to (None: leave the affinity).
    lock_memory : bool
        Call ``mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT)`` (without ``MCL_ONFAULT`` where the kernel
        lacks it).
    fifo : bool
        Ask for SCHED_FIFO (False: a busy-waiting pacing that must not run under it, module doc).

    Returns
    -------
    dict
        The policy record of ``run.json`` (docs/renderer.md, "Real-time scheduling"): ``policy``
        ("SCHED_FIFO" or "SCHED_OTHER"), ``priority``, ``nice``, ``mlockall``, ``affinity``, the RT
        throttling settings, the resource limits, and ``missing``: a list of what was refused and why
        (empty when everything was granted). Never raises for a refusal.
    """
    rec = {"platform": sys.platform, "requested": {"policy": "SCHED_FIFO" if fifo else "SCHED_OTHER",
                                                   "priority": priority if fifo else 0, "core": core,
                                                   "mlockall": bool(lock_memory)},
           "policy": "SCHED_OTHER", "priority": 0, "mlockall": False, "affinity": allowed_cores(),
           "missing": []}
    rec.update(read_rt_throttling())
    rec.update(_limits())
    before = rec["affinity"]
    if core is not None and hasattr(os, "sched_setaffinity"):
        try:
            os.sched_setaffinity(0, {core})
        except OSError as exc:
            rec["missing"].append(f"affinity to CPU {core}: {exc.strerror}")
        rec["affinity"] = allowed_cores()
        rec["affinity_before"] = before
    if lock_memory:
        libc = _libc()
        if libc is not None and hasattr(libc, "mlockall"):
            # MCL_ONFAULT (Linux >= 4.4): lock what is resident now and every page as it is touched, without
            # reading in the never-used parts of mapped libraries (numba's: ~0.1-1 s on a loaded machine, all of
            # it before the first tick); the loop's pages are resident after its priming cycle
            if libc.mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT) == 0 or libc.mlockall(MCL_CURRENT | MCL_FUTURE) == 0:
                rec["mlockall"] = True
            else:
                rec["missing"].append(f"mlockall: {os.strerror(ctypes.get_errno())}")
    if fifo and hasattr(os, "sched_setscheduler"):
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            rec["policy"], rec["priority"] = "SCHED_FIFO", priority
        except OSError as exc:
            rec["missing"].append(f"SCHED_FIFO priority {priority}: {exc.strerror}")
    if rec["policy"] != "SCHED_FIFO":
        try:  # the next best thing: a higher CFS priority (needs privilege too)
            os.nice(-10)
        except OSError:
            pass
        if rec.get("affinity_before") and fifo:
            # without SCHED_FIFO a pinned servo could not move off a core that other processes keep busy (measured:
            # the study's 1 kHz loop then ran mostly behind, median period 0.1 ms of catch-up ticks): unpin
            # every CPU (the kernel keeps it within this process's cpuset): a servo process started by a
            # parent that already avoids the servo core inherited that narrower set
            for cpus in (set(range(os.cpu_count() or 1)), set(rec["affinity_before"])):
                try:
                    os.sched_setaffinity(0, cpus)
                    break
                except OSError:
                    continue
            rec["affinity"] = allowed_cores()
            rec["missing"].append(f"affinity to CPU {core}: dropped without SCHED_FIFO")
    try:
        rec["nice"] = os.getpriority(os.PRIO_PROCESS, 0)
    except (OSError, AttributeError):
        rec["nice"] = None
    if not hasattr(os, "sched_setscheduler"):
        rec["missing"].append(f"SCHED_FIFO: not available on {sys.platform}")
    return rec


def _memory_locked() -> bool | None:
    """Whether this process has locked memory (``VmLck`` of /proc/self/status > 0), None where unknown."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmLck:"):
                    return int(line.split()[1]) > 0
    except (OSError, ValueError, IndexError):
        pass
    return None


def describe_current() -> dict:
    """The policy record (as :func:`acquire` returns) of this thread as it is, without asking for anything:
    what a loop run without ``rt_request`` records (e.g. the study's servo process, which asked once)."""
    rec = {"platform": sys.platform, "requested": None, "policy": "SCHED_OTHER", "priority": 0,
           "mlockall": _memory_locked(), "affinity": allowed_cores(), "missing": []}
    if hasattr(os, "sched_getscheduler"):
        try:
            pol = os.sched_getscheduler(0)
            names = {getattr(os, n): n for n in ("SCHED_OTHER", "SCHED_FIFO", "SCHED_RR", "SCHED_BATCH", "SCHED_IDLE")
                     if hasattr(os, n)}
            rec["policy"] = names.get(pol, str(pol))
            rec["priority"] = os.sched_getparam(0).sched_priority
        except OSError:
            pass
    try:
        rec["nice"] = os.getpriority(os.PRIO_PROCESS, 0)
    except (OSError, AttributeError):
        rec["nice"] = None
    rec.update(read_rt_throttling())
    return rec


def release(rec: dict | None) -> None:
    """Undo :func:`acquire` for the rest of the process (back to SCHED_OTHER, memory unlocked, the CPUs it
    had before). Safe to call with any record."""
    if not rec:
        return
    if rec.get("affinity_before") and hasattr(os, "sched_setaffinity"):
        try:
            os.sched_setaffinity(0, set(rec["affinity_before"]))
        except OSError:
            pass
    if rec.get("policy") == "SCHED_FIFO":
        try:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        except OSError:
            pass
    if rec.get("mlockall"):
        libc = _libc()
        if libc is not None:
            libc.munlockall()


@contextlib.contextmanager
def realtime(priority: int = RT_PRIORITY, core: int | None = None, lock_memory: bool = True, fifo: bool = True):
    """:func:`acquire` for the block and :func:`release` after it; the block gets the policy record."""
    rec = acquire(priority, core=core, lock_memory=lock_memory, fifo=fifo)
    try:
        yield rec
    finally:
        release(rec)


def freeze_startup_objects() -> None:
    """Collect once, then keep every object now alive out of later collections (``gc.freeze``): a full
    collection walks every object numba and numpy created at import (milliseconds), a pause a loop that runs
    for the whole process (an emulator, a latency measurement) does not need. The collector stays on."""
    gc.collect()
    gc.freeze()


@contextlib.contextmanager
def gc_paused():
    """Freeze every object now alive out of the collector's generations and disable the cyclic collector for
    the block (a collection walks ~10^5 objects: milliseconds at a random tick); restored afterwards."""
    was = gc.isenabled()
    gc.freeze()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


@contextlib.contextmanager
def avoid_core(core: int | None):
    """Keep this process (the rest of the program) off the servo's ``core`` for the block; the previous
    affinity is back afterwards. No-op for None, a single CPU, or where affinity cannot be set."""
    if core is None or not hasattr(os, "sched_setaffinity"):
        yield
        return
    before = os.sched_getaffinity(0)
    others = before - {core}
    changed = False
    if others:
        try:
            os.sched_setaffinity(0, others)
            changed = True
        except OSError:
            pass
    try:
        yield
    finally:
        if changed:
            try:
                os.sched_setaffinity(0, before)
            except OSError:
                pass


def remedy() -> str:
    """The exact remedy for a missing real-time privilege (Linux), as one sentence."""
    user = os.environ.get("USER") or os.environ.get("LOGNAME") or "USER"
    exe = os.path.realpath(sys.executable)
    return (f"add '{user} - rtprio {RT_PRIORITY}' and '{user} - memlock unlimited' to /etc/security/limits.conf "
            f"and log in again, or run 'sudo setcap cap_sys_nice,cap_ipc_lock+ep {exe}'")


def warning_line(rec: dict) -> str | None:
    """The one warning line for a policy record that lacks something, else None."""
    if not rec or not rec.get("missing"):
        return None
    got = rec.get("policy", "SCHED_OTHER")
    text = "; ".join(rec["missing"])
    return (f"warning: the servo runs without full real-time treatment ({text}; running {got}): its timing may "
            f"suffer on a busy machine; to allow it, {remedy()}")


def warn_once(rec: dict | None, stream=None) -> bool:
    """Print :func:`warning_line` to stderr once per process (the same refusal is not repeated); returns
    whether it printed."""
    line = warning_line(rec) if rec else None
    if line is None:
        return False
    key = tuple(sorted(m.split(":")[0] for m in rec["missing"]))
    if key in _warned:
        return False
    _warned.add(key)
    print(line, file=stream or sys.stderr, flush=True)
    return True
