"""Worker pools whose workers die with their parent: a SIGKILLed or signalled parent leaves no
orphaned worker waiting forever. Apart from :mod:`plumbing.stopsignals` because it loads multiprocessing's
pool machinery (~26 ms), which only the commands that start a pool need."""

from __future__ import annotations

import os
import signal
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager

from . import stopsignals
from .stopsignals import _BLOCKED, STOP_SIGNALS, _prctl_pdeathsig, signals_blocked

# how long a failed block waits for the executor's manager thread to wind up after its workers are killed
_MANAGER_WAIT_S = 10.0


def worker_dies_with_parent(parent_pid: int, initializer=None, initargs=()) -> None:
    """Initializer of a worker process (pool worker, recording process) that holds nothing to save or zero.

    The worker is killed (SIGKILL) when its parent dies, however it dies (Linux ``PR_SET_PDEATHSIG``; a
    worker of a parent already gone ends at once); it ignores Ctrl-C (the terminal sends it to the whole
    process group: the parent stops the workers, which then print no traceback of their own) and takes
    SIGTERM/SIGHUP with their default action (a fork inherits the parent's :class:`stop_on_signals`
    handlers). Then runs ``initializer(*initargs)``.

    Parameters
    ----------
    parent_pid : int
        ``os.getpid()`` of the parent, taken there before the fork.
    """
    stopsignals._active = None   # the parent's block, copied by the fork: not this process's (holding() reads it)
    if hasattr(signal, "pthread_sigmask"):  # forked inside signals_blocked (see worker_pool): take them again
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _BLOCKED)
    if hasattr(signal, "SIGINT"):
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_DFL)
    _prctl_pdeathsig(signal.SIGKILL)
    if os.getppid() != parent_pid:  # the parent died before the request took effect
        os._exit(1)
    if initializer is not None:
        initializer(*initargs)


@contextmanager
def worker_pool(max_workers: int, mp_context, initializer=None, initargs=()):
    """A :class:`concurrent.futures.ProcessPoolExecutor` whose workers die with this process (module doc).

    Leaving the block normally waits for the workers as the executor does; leaving it with an exception
    (an error, Ctrl-C, :class:`Terminated`) cancels what is queued and kills the workers at once instead
    of waiting for their tasks, so that no worker outlives the command. Start the workers from the
    thread that lives as long as the pool (the kernel's parent-death signal follows the thread that
    forked them): submit from the main thread.

    Parameters
    ----------
    max_workers : int
    mp_context : multiprocessing context
        e.g. ``multiprocessing.get_context("fork")``.
    initializer, initargs
        Run in each worker after :func:`worker_dies_with_parent`.

    Yields
    ------
    ProcessPoolExecutor
    """
    class Pool(ProcessPoolExecutor):
        def submit(self, fn, /, *args, **kwargs):
            # the executor forks its workers in submit: a stop signal then would be raised in the fork's
            # after-fork hooks, where Python prints and drops it; held back over the fork, it is raised here
            with signals_blocked():
                return super().submit(fn, *args, **kwargs)

    pool = Pool(max_workers=max_workers, mp_context=mp_context, initializer=worker_dies_with_parent,
                initargs=(os.getpid(), initializer, tuple(initargs)))
    try:
        yield pool
    except BaseException:
        procs = list((getattr(pool, "_processes", None) or {}).values())  # the executor offers no public kill
        queue = getattr(pool, "_call_queue", None)   # taken before shutdown(), which drops them
        manager = getattr(pool, "_executor_manager_thread", None)
        # The executor's feeder thread may be writing a large queued task (identify's recordings: ~1 MB) into
        # the call queue's pipe, which no worker will read once they are killed, and the manager thread,
        # seeing them killed, joins that thread: the command hung after its error line. Cancel the join
        # first, before the manager can start it (cancelling a join already under way does not end it).
        if queue is not None:
            queue.cancel_join_thread()
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in procs:
            if proc.is_alive():
                proc.kill()
        for proc in procs:
            proc.join()
        if manager is not None:
            manager.join(timeout=_MANAGER_WAIT_S)
        # Then end the feeder's write by closing this process's read end: CPython 3.11.7 and later close it in
        # the manager (gh-94777), 3.11.2 does not. Only after the manager has wound up: closing it while the
        # manager closes it too raced (EBADF in CI; the second close could also hit a descriptor number
        # opened since).
        reader = getattr(queue, "_reader", None) if queue is not None else None
        if reader is not None and not reader.closed:
            try:
                reader.close()
            except OSError:   # the feeder thread closed it in between, after its last item
                pass
        raise
    else:
        pool.shutdown(wait=True)
