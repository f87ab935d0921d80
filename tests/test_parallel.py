"""How the suite spreads over the machine (tests/support/parallel.py): the worker count of ``-n auto``."""

import subprocess
import sys

from tests.support.parallel import WORKER_MEMORY_BYTES, auto_workers, running_others


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
        before = running_others()
        assert before >= 1
    finally:
        spin.kill()
        spin.wait()


def test_pytest_n_auto_asks_this_suite(pytestconfig, monkeypatch):
    # pytest-xdist's controller turns "-n auto" into the first answer of this hook (tests/conftest.py answers);
    # the running processes held still between the two calls
    monkeypatch.setattr("tests.support.parallel.running_others", lambda: 0)
    assert pytestconfig.hook.pytest_xdist_auto_num_workers(config=pytestconfig) == auto_workers()
