"""How the suite spreads over the machine (tests/support/parallel.py): the worker count of ``-n auto``."""

from tests.support.parallel import WORKER_MEMORY_BYTES, auto_workers


def test_two_workers_per_core_as_memory_and_load_allow(monkeypatch):
    monkeypatch.delenv("HFAM_TEST_WORKERS_PER_CORE", raising=False)
    assert auto_workers(2, 24 << 30, load=0.0) == 4
    assert auto_workers(2, 24 << 30, load=1.1) == 3                  # one core busy already
    assert auto_workers(2, 24 << 30, load=6.0) == 2                  # never fewer than one per core
    assert auto_workers(16, 6 * WORKER_MEMORY_BYTES + 1, load=0.0) == 6     # memory for 6 workers only
    assert auto_workers(1, WORKER_MEMORY_BYTES // 2, load=0.0) == 1         # never fewer than one
    assert auto_workers(3, None, load=0.0) == 6                       # no /proc/meminfo: cores decide
    monkeypatch.setenv("HFAM_TEST_WORKERS_PER_CORE", "1")
    assert auto_workers(2, 24 << 30, load=0.0) == 2


def test_pytest_n_auto_asks_this_suite(pytestconfig, monkeypatch):
    # pytest-xdist's controller turns "-n auto" into the first answer of this hook (tests/conftest.py answers);
    # the load average held still between the two calls
    monkeypatch.setattr("os.getloadavg", lambda: (0.4, 0.4, 0.4))
    assert pytestconfig.hook.pytest_xdist_auto_num_workers(config=pytestconfig) == auto_workers()
