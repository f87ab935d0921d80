"""Run the servo loop in its own process, so it never shares an interpreter lock with UI, audio or disk work.

Why a process: CPython's GIL is handed between threads every
``sys.getswitchinterval()`` (5 ms), so a busy UI/audio/disk thread in the same
interpreter delays a 10 kHz loop by whole milliseconds (measured in
``benchmarks/bench_renderer.py``: "gil" figures). A separate process has its
own interpreter; only the kernel scheduler stands between it and its deadline.

The child creates and opens the device itself (serial ports and HID handles do
not survive pickling), runs :class:`renderer.ServoLoop`, and sends the
:class:`RunResult` back through a pipe. SIGINT is ignored in the child: Ctrl-C
in the parent sets a stop event, the child finishes the tick, zeroes the
device and returns the partial result. The "spawn" start method is used
because forking a process that runs audio/UI threads is unsafe.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import time
from typing import Callable

from devices.base import DeviceError
from devices.registry import make_device

from .config import RendererConfig
from .loop import ServoLoop


def _child(conn, device, device_options, cfg, transient, duration_s, max_ticks, realtime, stop_event,
           nice) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if nice:
        try:  # a higher CFS priority (not SCHED_FIFO: busy-waiting under it trips real-time throttling)
            os.nice(nice)
        except OSError:
            pass

    loop = None
    try:
        if isinstance(device, str):
            dev = make_device(device, **(device_options or {}))
        else:
            dev = device()
        with dev:
            loop = ServoLoop(dev, cfg, transient)
            result = loop.run(duration_s=duration_s, max_ticks=max_ticks, realtime=realtime,
                              until=lambda lp: stop_event.is_set())
        conn.send(("ok", result, "", ""))
    except BaseException as exc:  # report everything, including partial results
        partial = loop.result if loop is not None else None
        try:
            conn.send(("error", partial, type(exc).__name__, str(exc)))
        except Exception:
            pass
    finally:
        conn.close()


def run_in_process(device: str | Callable, cfg: RendererConfig | None = None, transient=None, *,
                   duration_s: float | None = None, max_ticks: int | None = None, realtime: bool | None = None,
                   device_options: dict | None = None, stop_event=None, timeout_s: float | None = None,
                   nice: int = -10):
    """Run a servo loop in a child process and return its :class:`renderer.RunResult`.

    Parameters
    ----------
    device : str or callable
        A device string for :func:`devices.registry.make_device`, or a picklable
        zero-argument callable returning an (unopened) Device.
    cfg, transient : as for :class:`renderer.ServoLoop` (must be picklable).
    duration_s, max_ticks, realtime : as for :meth:`ServoLoop.run`.
    device_options : dict, optional
        Keyword options for ``make_device``.
    stop_event : multiprocessing Event, optional
        Set it (from any thread) to stop the loop; create it with
        ``multiprocessing.get_context("spawn").Event()``.
    nice : int
        ``os.nice`` increment for the servo process (negative = higher
        priority; needs privileges, silently skipped without them; 0 = leave).
    timeout_s : float, optional
        Give up waiting (the child is terminated; the device's own watchdog
        must then zero it) after this long.

    Raises
    ------
    ValueError
        If the child rejected the configuration (message preserved).
    RuntimeError
        If the child failed otherwise or died without a result.
    """
    ctx = mp.get_context("spawn")
    stop = stop_event if stop_event is not None else ctx.Event()
    parent_conn, child_conn = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, name="renderer-servo",
                       args=(child_conn, device, device_options, cfg or RendererConfig(), transient,
                             duration_s, max_ticks, realtime, stop, nice), daemon=True)
    proc.start()
    child_conn.close()

    t_end = None if timeout_s is None else time.monotonic() + timeout_s
    message = None
    interrupted = False
    while message is None:
        try:
            if parent_conn.poll(0.05):
                message = parent_conn.recv()
                break
            if not proc.is_alive():
                if parent_conn.poll(0.2):
                    message = parent_conn.recv()
                break
            if t_end is not None and time.monotonic() > t_end:
                stop.set()
                if parent_conn.poll(2.0):
                    message = parent_conn.recv()
                break
        except KeyboardInterrupt:
            interrupted = True
            stop.set()
        except EOFError:
            break
    proc.join(timeout=5.0)
    if proc.is_alive():
        proc.terminate()
        proc.join(timeout=2.0)
    if message is None:
        raise RuntimeError(f"servo process exited (code {proc.exitcode}) without a result")
    status, result, exc_type, text = message
    if status == "ok":
        if interrupted and result.stop_reason == "until":
            result.stop_reason = "interrupted"
        return result
    if exc_type in ("ValueError", "FileNotFoundError"):
        raise ValueError(text)
    if exc_type == "DeviceError":  # e.g. a missing port: a user error, reported as such by __main__

        err = DeviceError(text)
    else:
        err = RuntimeError(f"servo process failed: {exc_type}: {text}")
    err.partial_result = result
    raise err
