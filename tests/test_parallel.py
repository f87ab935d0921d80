"""How the suite spreads over the machine (tests/support/parallel.py): the worker count of ``-n auto``, the work
units and the order in which they are handed out."""

import json
import os
import subprocess
import sys
from pathlib import Path

from benchmarks.bench_suite import cost_table, unit_walls
from tests.support.parallel import (FOLDER_GROUPS, WORKER_MEMORY_BYTES, auto_workers, cost_order, running_others,
                                    unit_costs, unit_of)

ROOT = Path(__file__).resolve().parents[1]


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


def test_a_folder_group_is_one_unit_and_a_module_its_own():
    assert unit_of("tests/renderer/teleop/test_teleop.py::test_servo_gains_follow_the_stated_rule") == \
        unit_of("tests/renderer/teleop/test_teleop_eq58.py::test_beyond_the_limit_contact_breaks[x]") == \
        FOLDER_GROUPS["tests/renderer/teleop/"]
    assert unit_of("tests/renderer/test_loop.py::test_a[1]") == "tests/renderer/test_loop.py"
    assert unit_of("tests/renderer/test_loop.py::test_a[x@y]") == "tests/renderer/test_loop.py"   # '@' in an id
    assert unit_of("tests/renderer/test_loop.py::test_a@grp") == "grp"           # xdist's suffix, where it adds one


def test_units_are_handed_out_longest_first_as_measured(tmp_path):
    units = {"a.py": {"t1": False}, "b.py": {f"t{i}": False for i in range(10)}, "c.py": {"t1": False, "t2": False},
             "grp": {"t1": False}}
    # measured: a 30 s and grp 12 s; b and c not measured: 10 and 2 tests at 2 s a test
    costs = {"units": {"a.py": 30.0, "grp": 12.0, "gone.py": 99.0}, "seconds_per_test": 2.0}
    (tmp_path / "costs.json").write_text(json.dumps(costs))
    table = unit_costs(tmp_path / "costs.json")
    assert cost_order(units, table) == ["a.py", "b.py", "grp", "c.py"]
    # no readable table: by the number of tests, as xdist orders them (ties by name)
    (tmp_path / "bad.json").write_text("{")
    for path in (tmp_path / "bad.json", tmp_path / "missing.json"):
        assert cost_order(units, unit_costs(path)) == ["b.py", "c.py", "a.py", "grp"]
    # the shipped table is readable and measures the longest units of this suite
    walls, per_test = unit_costs()
    assert len(walls) > 100 and 0.1 < per_test < 5.0 and walls[FOLDER_GROUPS["tests/renderer/teleop/"]] > 10.0


def test_the_cost_table_is_the_median_of_the_runs_logs(tmp_path):
    logs = []
    for k, walls in enumerate(([1.0, 2.0, 4.0], [3.0, 2.0, 2.0], [2.0, 9.0, 1.0])):
        log = tmp_path / f"run{k}.jsonl"
        rows = [{"nodeid": "tests/x/test_a.py::t1", "phase": "setup", "wall_s": walls[0]},
                {"nodeid": "tests/x/test_a.py::t1", "phase": "call", "wall_s": walls[1]},
                {"nodeid": "tests/renderer/teleop/test_t.py::t", "phase": "call", "wall_s": walls[2]},
                {"nodeid": "tests/x/test_a.py::t1", "phase": "call", "failed": True, "worker": "gw0"}]
        log.write_text("".join(json.dumps(r) + "\n" for r in rows))
        logs.append(unit_walls(log))
    assert logs[0] == {"tests/x/test_a.py": (3.0, 1), "teleop-cimm-model": (4.0, 1)}
    table = cost_table(logs)
    assert table["units"] == {"tests/x/test_a.py": 5.0, "teleop-cimm-model": 2.0}   # medians of 3/5/11, 4/2/1
    assert table["seconds_per_test"] == 3.5                                          # 7 s over 2 tests


def test_pytest_runs_a_folder_group_on_one_worker(tmp_path):
    """A real xdist run: the two teleop modules' tests on one worker, the other module on another (each of 3
    workers gets one unit first: ungrouped, the 3 modules would run on 3 workers)."""
    log = tmp_path / "cpu.jsonl"
    env = {**os.environ, "HFAM_TEST_CPU_LOG": str(log), "HFAM_TEST_JIT_WARMUP": "0"}
    env.pop("PYTEST_XDIST_WORKER", None)
    tests = ["tests/renderer/teleop/test_teleop.py::test_servo_gains_follow_the_stated_rule",
             "tests/renderer/teleop/test_teleop_eq58.py::test_largest_stable_mu_lambda_follows_mass_ratio",
             "tests/test_parallel.py::test_two_workers_per_core_as_memory_and_load_allow"]
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "3",
                           "--basetemp", str(tmp_path / "base"), *tests], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    worker = {}
    for line in log.read_text().splitlines():
        row = json.loads(line)
        worker.setdefault(row["nodeid"], set()).add(row["worker"])
    assert set(worker) == set(tests) and all(len(w) == 1 for w in worker.values())
    assert worker[tests[0]] == worker[tests[1]] != worker[tests[2]], worker
