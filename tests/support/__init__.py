"""Helpers the tests share. ``make test`` runs the suite on every core, two workers per core (pytest-xdist); for a new test:

* a command whose process is not what the test is about (a refusal, an error line, a set-up run): call it in
  the test's process with :func:`tests.support.cli.run_cli` (the package's ``main``: 1-3 s of imports less);
  signals, exits, the environment and what a process imports stay tests of a real process;
* a costly product several modules read (a demo, a pipeline, an identification): build it once per run for
  every worker with :func:`tests.support.shared.shared_folder` / ``shared_value`` (a file lock in the run's
  base temporary folder); within one module a module-scoped fixture is enough (a module runs on one worker);
* a session-scoped fixture that must exist once for several modules: their folder in ``FOLDER_GROUPS``
  (``tests/support/parallel.py``: one work unit, on one worker);
* never a fixed port, path or user cache: ``--port 0``/``tmp_path``; timing is driven by events, not sleeps.

``HFAM_TEST_CPU_LOG=<file>`` logs each test's CPU time, child processes included (:mod:`tests.support.cpuprofile`);
``python -m benchmarks suite`` times ``make test`` on a fresh clone with it.
"""
