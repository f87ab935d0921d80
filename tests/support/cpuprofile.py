"""Per-test CPU of the suite, child processes included: where ``make test``'s CPU time goes.

``HFAM_TEST_CPU_LOG=<file>`` makes each pytest process (each xdist worker) append one JSON line per test
phase: ``{"nodeid", "phase", "wall_s", "self_s", "children_s", "worker", "end_unix_s"}`` (and ``{"nodeid", "phase",
"failed": true, "worker"}`` for a phase that failed), where ``self_s`` is the user
plus system time of the pytest process itself (``RUSAGE_SELF``) and ``children_s`` that of the child
processes it started and reaped during the phase (``RUSAGE_CHILDREN``: a child still running when the phase
ends is counted in the phase that reaps it), and ``end_unix_s`` the phase's end (``time.time()``: the run's
timeline, so the set-up before the first test and a last worker's tail show). Session-scoped fixtures count in the setup of the first test
that uses them. ``python -m benchmarks suite`` reads these lines (benchmarks/bench_suite.py).
"""

from __future__ import annotations

import json
import os
import resource
import time

import pytest


def _cpu(who: int) -> float:
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


class CpuLog:
    """The pytest plugin: registered by ``tests/conftest.py`` when ``HFAM_TEST_CPU_LOG`` is set."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.worker = os.environ.get("PYTEST_XDIST_WORKER", "main")

    def _write(self, row: dict) -> None:
        # one short write per line with O_APPEND: lines of two workers never interleave
        with open(self.path, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(row) + "\n")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_setup(self, item):
        yield from self._measure(item, "setup")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_call(self, item):
        yield from self._measure(item, "call")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_teardown(self, item):
        yield from self._measure(item, "teardown")

    def pytest_runtest_logreport(self, report):
        if report.failed:                # a failure is known at once, before the run's summary
            self._write({"nodeid": report.nodeid, "phase": report.when, "failed": True, "worker": self.worker})

    def _measure(self, item, phase: str):
        t0, s0, c0 = time.perf_counter(), _cpu(resource.RUSAGE_SELF), _cpu(resource.RUSAGE_CHILDREN)
        yield
        self._write({"nodeid": item.nodeid, "phase": phase, "wall_s": round(time.perf_counter() - t0, 4),
                     "self_s": round(_cpu(resource.RUSAGE_SELF) - s0, 4),
                     "children_s": round(_cpu(resource.RUSAGE_CHILDREN) - c0, 4), "worker": self.worker,
                     "end_unix_s": round(time.time(), 3)})


def register(config) -> None:
    """Register :class:`CpuLog` on ``config`` if ``HFAM_TEST_CPU_LOG`` names a file."""
    path = os.environ.get("HFAM_TEST_CPU_LOG")
    if path:
        config.pluginmanager.register(CpuLog(path), "hfam-cpu-log")
