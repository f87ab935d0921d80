"""``python -m devices emulate`` (firmware emulator on a pty) and ``python -m devices latency``."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time

import numpy as np

from plumbing import rtpolicy

from .base import DeviceError
from .firmware.emulator import FaultSpec, build_emulator
from .registry import open_device


@contextlib.contextmanager
def realtime_priority(priority: int | None):
    """SCHED_FIFO at ``priority`` for the block (:func:`plumbing.rtpolicy.realtime`: asked for, recorded, undone
    after it), the start-up objects kept out of the collector (:func:`plumbing.rtpolicy.freeze_startup_objects`);
    the block gets a note for the user. Our loops block in select(), so FIFO cannot starve the machine.

    Raises
    ------
    ValueError
        ``priority`` outside 1..99.
    """
    rtpolicy.freeze_startup_objects()
    if priority is None:
        yield "default scheduling"
        return
    if not 1 <= priority <= 99:
        raise ValueError(f"--rt-priority must be within 1..99, got {priority}")
    with rtpolicy.realtime(priority, lock_memory=False) as rec:
        if rec["policy"] == "SCHED_FIFO":
            yield f"SCHED_FIFO priority {priority}"
        else:
            yield f"SCHED_FIFO refused ({'; '.join(rec['missing'])}); default scheduling"


def run_emulate(args) -> int:
    """Serve the emulator on a pty until SIGTERM/SIGINT or ``--duration-s``; always release the pty and say why.

    The signal handlers are installed first (before the physics kernel loads), so a SIGTERM at any moment
    ends the process: within the serve loop's next pass (<= 20 ms), or, if that loop does not get there
    within 2 s, by a forced exit after the report. On return the previous handlers are back and a pending
    forced exit is cancelled, so a caller in the same process (a test, a script) keeps its own signal
    handling, and processes it forks later do not inherit a handler that ignores SIGTERM.
    """
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT)}
    timers: list = []
    try:
        return _serve_emulator(args, timers)
    finally:
        for t in timers:
            t.cancel()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _serve_emulator(args, timers: list) -> int:
    """The body of :func:`run_emulate`; forced-exit timers it starts are appended to ``timers``."""

    stop = threading.Event()
    started = time.monotonic()
    state = {"doing": "starting (loading the physics)", "emu": None, "signal": None}

    def report() -> str:
        emu = state["emu"]
        what = state["doing"]
        if emu is not None:
            what += (f"; rendering on board: {'yes' if emu.rendering else 'no'}, watchdog "
                     f"{'tripped' if emu.tripped else 'ok'}, last current {emu.applied_A:+.3f} A, frames in/out "
                     f"{emu.stats['frames_in']}/{emu.stats['frames_out']}, dropped {emu.stats['dropped']}, "
                     f"corrupted {emu.stats['corrupted']}")
        return f"emulator: {state['signal'] or 'stopped'} after {time.monotonic() - started:.1f} s while {what}"

    def _force_exit() -> None:
        print(report() + " (forced exit: the serve loop did not stop within 2 s)", file=sys.stderr, flush=True)
        emu = state["emu"]
        if emu is not None:
            try:
                emu.close()
            except Exception:
                pass
        os._exit(0)

    def _stop(signum, _frame):
        state["signal"] = signal.Signals(signum).name
        stop.set()
        t = threading.Timer(2.0, _force_exit)
        t.daemon = True
        timers.append(t)
        t.start()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    faults = FaultSpec.parse(args.fault)
    emu = build_emulator(args.mode, faults, args.sim, args.taps, args.grip_N, args.sample, args.watchdog_ms,
                         args.pace, args.seed, args.t0_us, args.rate_hz)
    state["emu"] = emu
    if stop.is_set():  # terminated while loading: nothing was opened yet
        print(report(), file=sys.stderr, flush=True)
        return 0
    port = emu.open_pty()
    with realtime_priority(args.rt_priority) as sched:
        return _serve_pty(args, emu, port, faults, sched, stop, state, report)


def _serve_pty(args, emu, port: str, faults, sched: str, stop, state: dict, report) -> int:
    """Serve the emulator on ``port`` until ``stop`` (or ``--duration-s``); release the pty and say why."""
    print(f"PORT {port}", flush=True)
    print(f"emulating {emu.wire.info.name} ({args.mode}, watchdog {args.watchdog_ms} ms"
          f"{', faults ' + faults.to_text() if faults.to_text() else ''}, {sched}) on {port}", file=sys.stderr,
          flush=True)
    state["doing"] = f"serving {port}"
    timer = None
    if args.duration_s is not None:
        timer = threading.Timer(args.duration_s, stop.set)
        timer.daemon = True
        timer.start()
    try:
        emu.serve(stop)
    finally:
        emu.close()  # releases the pty (both ends)
        if timer is not None:
            timer.cancel()
    if emu.disconnected:
        print("emulator: disconnect fault fired, pty closed", file=sys.stderr)
    print(report() + "; pty released", file=sys.stderr, flush=True)
    return 0


def percentiles_us(samples_s) -> dict:
    """Median, p90, p99 and maximum of ``samples_s`` (s), in microseconds, as a dict."""

    a = np.asarray(samples_s) * 1e6
    return {"median_us": float(np.median(a)), "p90_us": float(np.percentile(a, 90)),
            "p99_us": float(np.percentile(a, 99)), "max_us": float(a.max())}


def measure_latency(dev, n: int = 2000, warmup: int = 100) -> dict:
    """Round trips of CURRENT->STATE on an open streaming device, and PING->PONG; SI seconds in, us out."""
    if n < 10:
        raise ValueError(f"--n must be at least 10, got {n}")
    perf = time.perf_counter
    for _ in range(warmup):
        dev.read()
        dev.command(0.0)
    rtt = [0.0] * n
    dev.read()
    t_start = perf()
    for k in range(n):
        t0 = perf()
        dev.command(0.0)
        dev.read()
        rtt[k] = perf() - t0
    elapsed = perf() - t_start
    out = {"n": n, "rate_hz": n / elapsed, **percentiles_us(rtt)}
    if hasattr(dev, "ping"):
        pings = [dev.ping() for _ in range(min(n, 500))]
        out["ping"] = percentiles_us(pings)
    if hasattr(dev, "link_stats"):
        out["link"] = dev.link_stats()
    return out


def run_latency(args) -> int:
    """The ``latency`` command: round trips over the link; a device error becomes a clear error line (exit 2)."""

    try:
        return _run_latency(args)
    except DeviceError as exc:  # no such port, no answer, disconnect: a clear message, exit status 2
        raise ValueError(str(exc)) from None


def _run_latency(args) -> int:
    with open_device(args.device) as dev:
        if getattr(dev, "on_device_rendering", False):
            raise ValueError("latency measures streaming round trips; open the device in streaming mode")
        with realtime_priority(args.rt_priority) as sched:
            res = measure_latency(dev, args.n, args.warmup)
    print(f"device {args.device}: {res['n']} command->state round trips ({sched})")
    print(f"  round trip: median {res['median_us']:.0f} us, p90 {res['p90_us']:.0f} us, p99 {res['p99_us']:.0f} us, "
          f"max {res['max_us']:.0f} us")
    print(f"  achieved update rate: {res['rate_hz']:.0f} Hz")
    if "ping" in res:
        pg = res["ping"]
        print(f"  ping (no physics): median {pg['median_us']:.0f} us, p99 {pg['p99_us']:.0f} us")
    if "link" in res:
        bad = {k: v for k, v in res["link"].items() if v and k not in ("frames_rx", "frames_tx")}
        print(f"  link: {res['link']['frames_tx']} frames out, {res['link']['frames_rx']} in"
              + (", faults: " + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in bad.items()) if bad
                 else ", no faults"))
    return 0
