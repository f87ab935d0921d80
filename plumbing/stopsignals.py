"""SIGTERM and SIGHUP as an orderly stop, so a process that drives a motor zeroes it on its way out.

By default SIGTERM and SIGHUP end a Python process at once: no ``finally`` block runs, so a servo
loop's last current stays on the motor until the device's own watchdog (if it has one) drops it.
Within :class:`stop_on_signals` either signal instead raises :class:`Terminated` in the main thread,
as Ctrl-C raises KeyboardInterrupt: the servo loops' ``finally`` blocks and ``Device.__exit__`` zero
the output, and, uncaught, the process exits with the conventional status 128 + the signal's number
(143 for SIGTERM, 129 for SIGHUP), without a traceback (``Terminated`` is a ``SystemExit``).

* Handlers are installed only in the main thread (the only one Python runs signal handlers in) and
  only where the disposition is the default: a caller's own handler stays, and so does a SIGHUP
  ignored under ``nohup``. The previous handlers come back when the block ends; a block inside
  another uses the outer one.
* The first signal raises; later ones (a second SIGTERM while the output is being zeroed) are
  ignored until the block ends.
* A raise that Python swallows is not lost: a signal handled while C code calls back into Python
  (numba's compiler runs LLVM through llvmlite, whose ctypes callbacks print "Exception ignored" and
  go on) reaches ``sys.unraisablehook``, which the block takes over while it is installed: it records
  the stop (quietly) and :func:`stop_if_signalled`, called where a long-running caller can stop (a
  servo loop after its JIT compile, between its compiled chunks), raises it there.
* A raise that Python wraps in another exception (in a ``__set_name__`` while a class is made, as numba's
  import does) is still a stop: :func:`stop_in` finds it, and the block ends with it.
* :class:`holding` defers the raise over a short critical section (the zeroing itself, building a
  partial result): a signal that arrives inside it is raised when the section ends.
* :func:`die_with_parent` stops a servo child process the same way when its parent dies (Linux:
  ``prctl(PR_SET_PDEATHSIG, SIGTERM)``); :class:`ParentWatch` is the portable fallback a loop polls.
* :class:`signals_blocked` holds SIGINT, SIGTERM and SIGHUP back over a few system calls that must not
  be cut in two (a folder swap, a fork: a signal raised in a fork's after-fork hooks is dropped).
* :func:`worker_pool` is a process pool whose workers hold no output and nothing to zero: they are
  killed (SIGKILL) when the parent dies of any signal, and stopped at once, not awaited, when the
  parent leaves the pool with an exception (Ctrl-C, SIGTERM, an error).
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading

#: the signals turned into :class:`Terminated` (those this platform has)
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))

_PR_SET_PDEATHSIG = 1  # linux/prctl.h
#: what :class:`signals_blocked` holds back: Ctrl-C and the stop signals
_BLOCKED = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))


def signal_name(signum: int) -> str:
    """``"SIGTERM"`` for 15 (the number as text if this platform has no name for it)."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


class Terminated(SystemExit):
    """Raised in the main thread by SIGTERM or SIGHUP inside :class:`stop_on_signals` (module doc).

    A ``SystemExit`` whose ``code`` is 128 + ``signum``: uncaught, the process exits with that status
    and no traceback; ``except Exception`` does not swallow it. Callers that keep a partial result
    attach it as ``partial_result``.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(128 + int(signum))
        self.signum = int(signum)
        self.partial_result = None

    def __str__(self) -> str:
        return f"stopped by {signal_name(self.signum)}"


def stop_in(exc: BaseException | None) -> Terminated | None:
    """The :class:`Terminated` that ``exc`` is, or that it was raised from (its ``__cause__``, followed); else None.

    Python wraps an exception raised in some places where a stop signal can land: in a descriptor's
    ``__set_name__`` while a class is made (numba's import makes many), it becomes ``RuntimeError: Error calling
    __set_name__``, raised from it. Such a stop is still a stop: the callers that tell a stop from a failure
    (a servo loop's stop reason, the block's exit status) ask here. An error raised while a stop was being
    handled (a stop only in its ``__context__``) stays an error.
    """
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, Terminated):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__
    return None


#: the block whose handlers are installed now (at most one per process)
_active = None


class stop_on_signals:
    """Context manager: SIGTERM and SIGHUP raise :class:`Terminated` in the main thread inside it (module doc).

    Parameters
    ----------
    own_process : bool
        The caller owns the whole process (a servo child): SIGTERM is taken over even where it was
        ignored or handled, since it is how the parent, and the kernel on the parent's death, stop it.

    Attributes
    ----------
    installed : bool
        False where nothing was installed (not the main thread, an outer block's handlers in place,
        or the caller's own handlers kept).
    signum : int or None
        The first stop signal received inside the block (of the outermost block that installed them).
    """

    def __init__(self, own_process: bool = False) -> None:
        self.own_process = bool(own_process)
        self.installed = False
        self.signum = None
        self.raised = False
        #: the raise of ``signum`` was swallowed (sys.unraisablehook saw it): :func:`stop_if_signalled` raises it
        self.lost = False
        self._holds = 0
        self._previous: dict = {}
        self._unraisable = None
        self._thread = None

    def __enter__(self) -> "stop_on_signals":
        global _active
        if _active is not None or threading.current_thread() is not threading.main_thread():
            return self
        self._thread = threading.get_ident()
        _active = self  # before the first handler: a signal at once finds its block
        for sig in STOP_SIGNALS:
            try:
                current = signal.getsignal(sig)
                take = current is signal.SIG_DFL or (self.own_process and sig == signal.SIGTERM)
                if take:
                    signal.signal(sig, self._handle)
                    self._previous[sig] = current
            except (ValueError, OSError):  # not settable here (e.g. an embedded interpreter)
                pass
        self.installed = bool(self._previous)
        if not self.installed:
            _active = None
        else:
            self._unraisable = sys.unraisablehook
            sys.unraisablehook = self._swallowed
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        global _active
        if not self.installed:
            return False
        for sig, previous in self._previous.items():
            try:
                signal.signal(sig, previous if previous is not None else signal.SIG_DFL)
            except (ValueError, OSError):
                pass
        self._previous = {}
        if self._unraisable is not None:
            if sys.unraisablehook == self._swallowed:   # (a hook installed after ours stays)
                sys.unraisablehook = self._unraisable
            self._unraisable = None
        self.installed = False
        _active = None
        self._raise_pending(exc_type)   # also one swallowed and not raised since: the block ends with it
        stop = stop_in(exc)
        if stop is not None and stop is not exc:   # a stop Python wrapped on its way out (stop_in): raised as itself
            raise stop from None
        return False

    def _swallowed(self, unraisable) -> None:
        """``sys.unraisablehook`` while installed: this block's :class:`Terminated`, raised where Python could
        only print it ("Exception ignored", e.g. in a ctypes callback), is recorded for :func:`stop_if_signalled`
        instead; anything else goes to the hook that was in place."""
        if isinstance(unraisable.exc_value, Terminated) and self.signum is not None:
            self.lost = True
            self.raised = False     # pending again: raised by stop_if_signalled, a holding's end or the block's
            return
        previous = self._unraisable if self._unraisable is not None else sys.__unraisablehook__
        previous(unraisable)

    def _handle(self, signum, frame) -> None:
        if self.signum is not None:
            return  # already stopping: a second signal must not cut the zeroing short
        self.signum = signum
        if self._holds == 0:
            self.raised = True
            raise Terminated(signum)

    def _raise_pending(self, exc_type) -> None:
        """Raise a signal that arrived while held (or whose raise was swallowed), unless another exception
        (not a Ctrl-C) is on its way out."""
        if self.signum is None or self.raised:
            return
        if exc_type is None or issubclass(exc_type, KeyboardInterrupt):
            self.raised = True
            self.lost = False
            raise Terminated(self.signum)


def stop_if_signalled() -> None:
    """Raise :class:`Terminated` for a stop signal whose raise was swallowed (module doc); else nothing.

    For the places a long-running caller can stop cleanly, in the thread of the :class:`stop_on_signals`
    block: a servo loop calls it after its one-time JIT compile (before the first tick) and between its
    compiled chunks, so a SIGTERM that landed inside numba's compiler stops the run there, with the exit
    status and the zeroed output of any SIGTERM. Cheap (a few attribute reads); a no-op outside a block,
    in another thread and inside :class:`holding` (which raises it when it ends).
    """
    block = _active
    if block is None or not block.lost or block._holds or block._thread != threading.get_ident():
        return
    block.lost = False
    block.raised = True
    raise Terminated(block.signum)


class signals_blocked:
    """Context manager: SIGINT, SIGTERM and SIGHUP wait (are blocked) inside, then are delivered.

    For the few system calls that must not be cut in two: the swap of an output folder, the removal
    of a staging folder, a fork (a child forked inside starts with them blocked:
    :func:`worker_dies_with_parent` unblocks them). Blocks them in the calling thread (the kernel then
    delivers them to another thread or when the block ends; Python runs the handlers in the main thread).
    """

    def __enter__(self) -> "signals_blocked":
        self._old = None
        if hasattr(signal, "pthread_sigmask"):
            self._old = signal.pthread_sigmask(signal.SIG_BLOCK, _BLOCKED)
        return self

    def __exit__(self, *exc) -> bool:
        if self._old is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, self._old)
        return False


class holding:
    """Context manager: a stop signal arriving inside is raised (as :class:`Terminated`) when it ends.

    For short critical sections that must not be cut in two: zeroing the output, building the partial
    result. A no-op outside :class:`stop_on_signals` and in any thread but the one that installed it.
    """

    __slots__ = ("_block",)

    def __enter__(self) -> "holding":
        block = _active
        if block is not None and block._thread == threading.get_ident():
            block._holds += 1
            self._block = block
        else:
            self._block = None
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        block = self._block
        if block is not None:
            self._block = None
            block._holds -= 1
            if block._holds == 0:
                block._raise_pending(exc_type)
        return False


def die_with_parent(parent_pid: int) -> bool:
    """Make this (child) process receive SIGTERM when its parent dies; raise :class:`Terminated` if it already has.

    Linux only (``prctl(PR_SET_PDEATHSIG, SIGTERM)``; elsewhere poll a :class:`ParentWatch`). Call it
    inside :class:`stop_on_signals`, so the signal becomes an orderly stop. The kernel sends the
    signal when the *thread* that started the child ends: the parent's call that started it must wait
    for it in that thread (as :func:`renderer.run_in_process` does).

    Parameters
    ----------
    parent_pid : int
        ``os.getpid()`` of the parent, taken there before the child was started: if the parent died
        before the request took effect, this process already has another parent.

    Returns
    -------
    bool
        True if the kernel will send the signal.
    """
    armed = False
    if sys.platform.startswith("linux"):

        try:
            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent_pid:  # the parent died before the request: nobody would send it now
        raise Terminated(signal.SIGTERM)
    return armed


class ParentWatch:
    """Portable check that the parent process is gone: call it often, it asks the OS every ``every`` calls.

    ``watch()`` returns True once ``os.getppid()`` differs from ``parent_pid`` (the child was
    re-parented: its parent died). A servo loop's ``until`` predicate (every ``until_every`` ticks)
    calls it; with the default 64 that is one system call per ~1000 ticks.
    """

    __slots__ = ("parent_pid", "every", "gone", "_left")

    def __init__(self, parent_pid: int, every: int = 64) -> None:
        self.parent_pid = int(parent_pid)
        self.every = max(1, int(every))
        self.gone = False
        self._left = 1  # the first call asks

    def __call__(self) -> bool:
        self._left -= 1
        if self._left <= 0:
            self._left = self.every
            if os.getppid() != self.parent_pid:
                self.gone = True
        return self.gone


def _prctl_pdeathsig(sig: int) -> bool:
    """``prctl(PR_SET_PDEATHSIG, sig)`` (Linux; False elsewhere or when refused)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        return ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False
