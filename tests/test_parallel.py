"""How the suite spreads over the machine (tests/support/parallel.py): the worker count of ``-n auto``, and the
background numba warm-up the workers wait for (tests/support/jitwarm.py)."""

import os
import subprocess
import sys

from tests.support import jitwarm
from tests.support.parallel import WORKER_MEMORY_BYTES, _running_threads, auto_workers, running_others


def test_two_workers_per_core_as_memory_and_load_allow(monkeypatch):
    monkeypatch.delenv("HFAM_TEST_WORKERS_PER_CORE", raising=False)
    assert auto_workers(2, 24 << 30, others=0) == 4
    assert auto_workers(2, 24 << 30, others=1) == 4                  # one core busy already: 4 measured fastest
    assert auto_workers(2, 24 << 30, others=2) == 2                  # as many running as cores: one per core
    assert auto_workers(16, 6 * WORKER_MEMORY_BYTES + 1, others=0) == 6     # memory for 6 workers only
    assert auto_workers(1, WORKER_MEMORY_BYTES // 2, others=0) == 1         # never fewer than one
    assert auto_workers(3, None, others=0) == 6                       # no /proc/meminfo: cores decide
    monkeypatch.setenv("HFAM_TEST_WORKERS_PER_CORE", "1")
    assert auto_workers(2, 24 << 30, others=0) == 2


def test_the_processes_running_besides_this_one_are_counted():
    # a process spinning beside this one is counted (the median of 9 samples: a moment's blip is not)
    spin = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdout.write('go\\n'); sys.stdout.flush()\n"
                             "while True: pass"], stdout=subprocess.PIPE, text=True)
    try:
        assert spin.stdout.readline() == "go\n"
        before = running_others(exclude=[])
        assert before >= 1
        # this run's own warm-up is not counted: a spinning process's one thread is runnable at every sample
        assert _running_threads([spin.pid]) == 1
        assert _running_threads([spin.pid, 2 ** 22 + 1]) == 1          # a process that does not exist counts 0
    finally:
        spin.kill()
        spin.wait()


def test_pytest_n_auto_asks_this_suite(pytestconfig, monkeypatch):
    # pytest-xdist's controller turns "-n auto" into the first answer of this hook (tests/conftest.py answers);
    # the running processes held still between the two calls
    monkeypatch.setattr("tests.support.parallel.running_others", lambda: 0)
    assert pytestconfig.hook.pytest_xdist_auto_num_workers(config=pytestconfig) == auto_workers()


def test_the_workers_wait_for_a_background_warm_up_until_both_parts_end_and_hear_of_a_failure(tmp_path):
    # each part blocks on a FIFO of its own until the test opens it: the test decides when each part ends
    fifos = [tmp_path / f"go-{part}" for part in (0, 1)]
    for fifo in fifos:
        os.mkfifo(fifo)
    codes = {0: "0", 1: "3"}

    def command(part, status):
        return [sys.executable, "-c", "import sys; open(sys.argv[1]).read(); open(sys.argv[2], 'w').write(sys.argv[3])",
                str(fifos[part]), str(status), codes[part]]

    folder = tmp_path / "warm"
    assert not jitwarm.running(folder)                   # no lock file yet
    assert jitwarm.start(folder, command)
    assert jitwarm.running(folder)                       # the lock is held before start returns
    pids = [int(p) for p in (folder / jitwarm.PIDS).read_text().split()]
    assert len(pids) == 2 and jitwarm._started[-2:] == pids and set(pids) <= set(jitwarm.own_pids())
    assert not jitwarm.start(folder, command)            # one warm-up at a time: a second finds it running
    open(fifos[0], "w").close()                          # part 0 ends...
    assert jitwarm.running(folder)                       # ...but part 1 still holds the lock
    open(fifos[1], "w").close()
    jitwarm.wait(folder)
    assert not jitwarm.running(folder)
    lines = jitwarm.failures(folder)
    assert len(lines) == 1 and "part 1 failed (exit 3)" in lines[0] and "jitwarm-1.log" in lines[0]
    # a part stopped before it wrote its status is reported too
    (folder / "jitwarm-0.status").unlink()
    assert [line.split(";")[0] for line in jitwarm.failures(folder)] == [
        "numba warm-up part 0 failed (exit none: it was stopped)", "numba warm-up part 1 failed (exit 3)"]
    jitwarm.wait(tmp_path / "nothing here")              # no warm-up there: at once
