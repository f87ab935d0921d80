"""plumbing.pools.worker_pool: a pool left with an error kills its workers and never hangs its process."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# the worker is busy with a first task; a second task of 4 MB is queued, so the executor's feeder thread is
# blocked writing it into the call queue's 64 kB pipe when the block fails (what identify's recordings did
# when a grip's recording failed: the command printed its error and then never exited)
SCRIPT = textwrap.dedent('''
    import fcntl, multiprocessing, sys, termios, time
    from plumbing.pools import worker_pool

    def busy(path):
        open(path, "w").close()      # the worker has taken its first task
        time.sleep(600)

    def take(payload):
        return len(payload)

    started = sys.argv[1]
    try:
        with worker_pool(1, multiprocessing.get_context("fork")) as pool:
            pool.submit(busy, started)
            while not __import__("os").path.exists(started):
                time.sleep(0.01)
            pool.submit(take, b"x" * (4 << 20))
            pool.submit(take, b"y" * (4 << 20))
            # wait until the feeder thread is writing into the call queue's pipe (it then blocks writing the rest of
            # the 4 MB task, which no worker reads): the state in which the block used to hang
            reader = pool._call_queue._reader.fileno()
            while int.from_bytes(fcntl.ioctl(reader, termios.FIONREAD, b"\\0\\0\\0\\0"), sys.byteorder) < 4096:
                time.sleep(0.01)
            raise RuntimeError("a recording failed")
    except RuntimeError as exc:
        print("caught:", exc, flush=True)
''')


def test_a_failed_pool_block_with_a_large_task_in_flight_lets_the_process_exit(tmp_path):
    script = tmp_path / "pool.py"
    script.write_text(SCRIPT)
    proc = subprocess.run([sys.executable, str(script), str(tmp_path / "started")], cwd=tmp_path,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "caught: a recording failed"
    assert "Traceback" not in proc.stderr


def _disposition(_):
    import signal

    from plumbing import stopsignals
    return signal.getsignal(signal.SIGTERM) is signal.SIG_DFL, stopsignals._active is None


def test_a_worker_forked_inside_a_stop_on_signals_block_takes_sigterm_by_default():
    """A pool worker forked inside the caller's :class:`stop_on_signals` block (the demo's taps run inside its
    output folder's) takes SIGTERM with the default action and holds no copy of the caller's block, so a
    pool's ``terminate()`` ends it whatever it was doing (one kept the handler and waited for ever, in CI)."""
    import multiprocessing

    from plumbing.pools import worker_dies_with_parent
    from plumbing.stopsignals import stop_on_signals

    with stop_on_signals() as block:
        assert block.installed
        with multiprocessing.get_context("fork").Pool(2, initializer=worker_dies_with_parent,
                                                      initargs=(os.getpid(),)) as pool:
            assert pool.map(_disposition, range(4)) == [(True, True)] * 4
