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

Every way out zeroes the output (``plumbing.stopsignals``):

* SIGTERM or SIGHUP to the parent (main thread): it sets the stop event, waits
  for the child's zeroed partial result, then raises
  :class:`plumbing.stopsignals.Terminated` (exit status 128 + the signal's number
  if uncaught) with the result as ``partial_result``.
* SIGTERM to the child: an orderly stop (the loop's zeroing path), as for Ctrl-C.
* The parent dies (even by SIGKILL): the kernel sends the child SIGTERM
  (Linux ``PR_SET_PDEATHSIG``); elsewhere the loop's stop check notices the
  new parent id within ~1000 ticks.
* ``timeout_s``: the child is asked to stop (stop event), then sent SIGTERM,
  and killed only if it still has not exited.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal
import time
from typing import Callable

from devices.base import DeviceError
from devices.registry import make_device
from plumbing.stopsignals import (STOP_SIGNALS, ParentWatch, Terminated, die_with_parent, holding, signals_blocked,
                                  stop_in, stop_on_signals)

from plumbing import rtpolicy
from .config import RendererConfig
from .loop import ServoLoop


#: s the parent waits for the child at each step of ending it (stop event, SIGTERM, SIGKILL)
STOP_GRACE_S = 5.0
#: the start method of every servo process (this module's, the hardware demo's, the study's apparatus): "spawn",
#: because forking a process that runs audio or UI threads is unsafe
SPAWN = mp.get_context("spawn")


def shared_sync(make):
    """``make()`` (a :data:`SPAWN` Event, Queue, Lock...) with Ctrl-C and the stop signals held back.

    multiprocessing registers each semaphore with its resource tracker, then gives it its finalizer: a
    signal between the two ended the program with a "leaked semaphore objects" warning after its own last
    line. Every servo process's shared objects are made here."""
    with signals_blocked():
        return make()


def servo_process(target, args: tuple, name: str, duplex: bool = False):
    """A servo child process, not yet started, and both ends of its pipe: ``target(child_conn, *args)``.

    The one way every servo process of the project is made (``run_in_process``, the hardware demo's taps, the
    study's apparatus): spawned (:data:`SPAWN`), a daemon. Start it, then close ``child_conn`` in the parent.

    Returns
    -------
    (multiprocessing.Process, Connection, Connection)
        The process, the parent's end and the child's end of the pipe.
    """
    parent_conn, child_conn = SPAWN.Pipe(duplex=duplex)
    proc = SPAWN.Process(target=target, name=name, args=(child_conn, *args), daemon=True)
    return proc, parent_conn, child_conn


@contextlib.contextmanager
def servo_child(parent_pid: int):
    """The child side of every servo process, around its work: Ctrl-C is ignored (the parent decides and tells
    it), SIGTERM and SIGHUP raise :class:`plumbing.stopsignals.Terminated` (the work's own ``finally`` zeroes
    and closes the device; uncaught, the exit status is 128 + the signal's number), and the kernel sends SIGTERM
    when the parent dies (``PR_SET_PDEATHSIG``; where that is missing the work polls
    :class:`plumbing.stopsignals.ParentWatch`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    with stop_on_signals(own_process=True):
        if hasattr(signal, "pthread_sigmask"):   # started with them blocked (run_in_process): take them now
            signal.pthread_sigmask(signal.SIG_UNBLOCK, (signal.SIGINT, *STOP_SIGNALS))
        die_with_parent(parent_pid)
        yield


@contextlib.contextmanager
def replying(conn, failure: Callable[[BaseException], tuple]):
    """The servo child's way out: whatever ends the block, the parent gets one message and the pipe is closed.

    The block sends its own success message; an exception sends ``failure(exc)`` instead (the partial result
    the loop kept, and what went wrong) and ends there -- the child's work is over, the parent decides -- except
    a stop by SIGTERM/SIGHUP (:class:`plumbing.stopsignals.Terminated`, also when Python wrapped it in an
    import's error), which is raised again once the pipe is closed: exit status 128 + the signal's number.
    """
    terminated = None
    try:
        yield
    except BaseException as exc:  # report everything, including partial results
        exc = stop_in(exc) or exc   # a stop that Python wrapped (a signal inside an import) is a stop
        if isinstance(exc, Terminated):
            terminated = exc
        try:
            conn.send(failure(exc))
        except Exception:
            pass
    finally:
        conn.close()
    if terminated is not None:
        raise terminated


def _child(conn, device, device_options, cfg, transient, duration_s, max_ticks, realtime, stop_event,
           nice, parent_pid, rt_request=None) -> None:
    loop = None

    def failed(exc):
        return ("error", loop.result if loop is not None else None, type(exc).__name__, str(exc))

    with replying(conn, failed):
        # SIGTERM (the parent's timeout path, the parent's death) and SIGHUP: the loop's zeroing path
        with servo_child(parent_pid):
            if nice:
                try:  # a higher CFS priority until the loop asks for SCHED_FIFO around its paced ticks (rtpolicy)
                    os.nice(nice)
                except OSError:
                    pass
            if isinstance(device, str):
                dev = make_device(device, **(device_options or {}))
            else:
                dev = device()
            with dev:
                loop = ServoLoop(dev, cfg, transient)
                loop.rt_request = rt_request  # SCHED_FIFO, mlockall, its own core around the paced ticks
                parent_gone = ParentWatch(parent_pid)  # where PR_SET_PDEATHSIG is missing: ~every 1000 ticks
                result = loop.run(duration_s=duration_s, max_ticks=max_ticks, realtime=realtime,
                                  until=lambda lp: parent_gone() or stop_event.is_set())
        conn.send(("ok", result, "", ""))


def end_child(proc, conn, want_message: bool):
    """Wait for a servo child to exit: ``STOP_GRACE_S``, then SIGTERM (an orderly stop that zeroes the device)
    and as long again, SIGKILL last. Returns the child's message if ``want_message`` and one arrives meanwhile.
    Used by :func:`run_in_process` and the hardware demo's servo process."""
    message = None
    for step in (None, proc.terminate, proc.kill):  # the kill: last resort, the device's watchdog must zero
        if step is not None:
            if not proc.is_alive():
                break
            step()
        deadline = time.monotonic() + STOP_GRACE_S
        while proc.is_alive() and time.monotonic() < deadline:
            if want_message and conn.poll(0.05):  # read while waiting: a large result blocks the child's send
                try:
                    message = conn.recv()
                except (EOFError, OSError):
                    pass
                want_message = False
            else:
                proc.join(0.05)
    if want_message:
        try:
            if conn.poll(0):
                message = conn.recv()
        except (EOFError, OSError):
            pass
    return message


def run_in_process(device: str | Callable, cfg: RendererConfig | None = None, transient=None, *,
                   duration_s: float | None = None, max_ticks: int | None = None, realtime: bool | None = None,
                   device_options: dict | None = None, stop_event=None, timeout_s: float | None = None,
                   nice: int = -10, realtime_policy: bool = True):
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
    realtime_policy : bool
        Ask for real-time treatment around the paced ticks (``plumbing.rtpolicy``: SCHED_FIFO at
        ``RT_PRIORITY``, ``mlockall``, the servo pinned to ``servo_core()``, which this process avoids while
        the child runs); what was granted is in the result's ``timing["policy"]``, and a refusal prints one
        warning line with the remedy (once per process).
    timeout_s : float, optional
        After this long the child is asked to stop (the stop event), then, if it
        has not answered within ``STOP_GRACE_S``, sent SIGTERM (an orderly stop
        that zeroes the device), and killed only as a last resort.

    SIGTERM and SIGHUP to this process (called in the main thread) stop the
    child the same way and then raise :class:`plumbing.stopsignals.Terminated`
    (module doc); the handlers in place before the call are back afterwards.

    Raises
    ------
    ValueError
        If the child rejected the configuration (message preserved).
    RuntimeError
        If the child failed otherwise or died without a result.
    plumbing.stopsignals.Terminated
        On SIGTERM/SIGHUP, after the child zeroed and stopped (``partial_result``: its result).
    """
    core = rtpolicy.servo_core() if realtime_policy else None
    rt_request = {"core": core} if realtime_policy else None
    with rtpolicy.avoid_core(core):  # the rest of the program keeps off the servo's core
        result = _run_child(device, cfg, transient, duration_s, max_ticks, realtime, device_options, stop_event,
                            timeout_s, nice, rt_request)
    rtpolicy.warn_once(result.timing.get("policy"))
    return result


def _run_child(device, cfg, transient, duration_s, max_ticks, realtime, device_options, stop_event, timeout_s,
               nice, rt_request):
    """The body of :func:`run_in_process`: start the child, wait for its result, end it."""
    stop = stop_event if stop_event is not None else shared_sync(SPAWN.Event)
    proc, parent_conn, child_conn = servo_process(_child, (device, device_options, cfg or RendererConfig(), transient,
                                                           duration_s, max_ticks, realtime, stop, nice, os.getpid(),
                                                           rt_request), "renderer-servo")
    message = None
    interrupted = False
    terminated = None
    with stop_on_signals():
        try:
            # started whole: a stop signal during the start, which writes the child its pickled work, cut that
            # short and the child printed an EOFError traceback; held back, it is raised once the child has it
            with signals_blocked():
                proc.start()
            child_conn.close()
            t_end = None if timeout_s is None else time.monotonic() + timeout_s
            while message is None:
                try:
                    if parent_conn.poll(0.05):
                        with holding():  # a signal must not cut a message in two
                            message = parent_conn.recv()
                        break
                    if not proc.is_alive():
                        if parent_conn.poll(0.2):
                            with holding():
                                message = parent_conn.recv()
                        break
                    if t_end is not None and time.monotonic() > t_end:
                        stop.set()  # end_child waits for the zeroed result, then escalates
                        break
                except KeyboardInterrupt:
                    interrupted = True
                    stop.set()
                except Terminated as exc:  # stop the child as for Ctrl-C, then re-raise with its result
                    terminated = exc
                    stop.set()
                    break
                except EOFError:
                    break
        except Terminated as exc:  # during start(): the child, if it started, is ended below
            terminated = exc
            stop.set()
        finally:
            if proc.pid is not None:
                try:
                    with holding():  # a signal now is raised once the child is gone
                        late = end_child(proc, parent_conn, message is None)
                        if message is None:
                            message = late
                except Terminated as exc:
                    terminated = terminated or exc
    if terminated is not None:
        partial = message[1] if message is not None else None
        if partial is not None and partial.stop_reason == "until":
            partial.stop_reason = "interrupted"
        terminated.partial_result = partial
        raise terminated
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
