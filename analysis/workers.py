"""The report's second process, used where it may have died: submit work to it, take its result.

``analysis.cli_report.figure_process`` forks one process that reads the session files and draws two
figures while the main process loads the study and computes the statistics. A process that died (killed,
out of memory) or a pool already shut down must not lose the report: each caller does the work itself.
"""

from __future__ import annotations

from concurrent.futures.process import BrokenProcessPool


def submit(pool, fn, *args):
    """``pool.submit(fn, *args)``, or None without a pool or when its process is gone (died, or the pool
    was shut down)."""
    if pool is None:
        return None
    try:
        return pool.submit(fn, *args)
    except (BrokenProcessPool, RuntimeError):
        return None


def result(future):
    """``future``'s result (raising the work's own error, if any), or None without a future or when the
    process running it died: the caller then does the work itself."""
    if future is None:
        return None
    try:
        return future.result()
    except BrokenProcessPool:
        return None
