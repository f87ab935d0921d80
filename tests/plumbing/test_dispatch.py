"""plumbing.dispatch: preloaded command modules and the fast exit, in processes of their own."""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
import textwrap
from pathlib import Path

from plumbing.dispatch import Command

ROOT = Path(__file__).resolve().parents[2]

# a package with one command that registers an exit handler, may start a thread that outlives it, and
# reports whether its preload module was imported (and frozen out of the collector) before it ran
COMMAND = '''
import atexit, gc, os, sys, threading, time

def register(sub):
    p = sub.add_parser("go")
    p.add_argument("--thread", action="store_true")
    p.add_argument("--out", required=True)
    p.set_defaults(func=run, fast_exit=True)

def run(args):
    print("PRELOADED", "json" in sys.modules and "fakecmd_pre" in sys.modules, gc.get_freeze_count() > 0,
          gc.isenabled(), flush=True)
    atexit.register(lambda: open(os.path.join(args.out, "atexit"), "w").close())
    if args.thread:
        def late():
            time.sleep(0.3)
            open(os.path.join(args.out, "thread"), "w").close()
        threading.Thread(target=late).start()
    return 3
'''
MAIN = '''
import sys
from plumbing.dispatch import Command, main, run_as_script
run_as_script(lambda: main("fake", "fake", (Command("go", "fakecmd", "go", preload=("fakecmd_pre",)),)))
'''


def _run(tmp_path, *extra):
    (tmp_path / "fakecmd.py").write_text(textwrap.dedent(COMMAND))
    (tmp_path / "fakecmd_pre.py").write_text("import json\n")
    out = tmp_path / "out"
    out.mkdir(exist_ok=True)
    proc = subprocess.run([sys.executable, "-c", MAIN, "go", "--out", str(out), *extra], cwd=ROOT,
                          env={"PYTHONPATH": f"{ROOT}:{tmp_path}", "PATH": "/usr/bin:/bin"}, capture_output=True,
                          text=True, timeout=60)
    return proc, out


def test_preload_is_imported_before_the_command_and_the_fast_exit_runs_the_exit_handlers(tmp_path):
    proc, out = _run(tmp_path)
    assert proc.returncode == 3, proc.stderr       # the command's exit code, also through os._exit
    assert "PRELOADED True True True" in proc.stdout  # imported, frozen, the collector back on for the command
    assert (out / "atexit").exists()                # the exit handlers ran before the process ended


def test_no_fast_exit_while_a_thread_of_the_command_still_runs(tmp_path):
    proc, out = _run(tmp_path, "--thread")
    assert proc.returncode == 3, proc.stderr
    assert (out / "thread").exists() and (out / "atexit").exists()  # the interpreter waited for the thread


BLAS = '''
import os, sys
from plumbing.dispatch import Command, main, run_as_script

def register(sub):
    sub.add_parser("blas").set_defaults(func=run)

def run(args):
    import numpy  # the command's own import: numpy and its BLAS load here
    print("BLAS", os.environ.get("OPENBLAS_NUM_THREADS"), len(os.listdir("/proc/self/task")), flush=True)

if __name__ == "__main__":
    run_as_script(lambda: main("fake", "fake", (Command("blas", "blascmd", "blas", blas_threads=int(os.environ["FAKE_BLAS_THREADS"])),),
                                   sys.argv[1:]))
'''


def _blas(tmp_path, threads, **env):
    (tmp_path / "blascmd.py").write_text(textwrap.dedent(BLAS))
    proc = subprocess.run([sys.executable, str(tmp_path / "blascmd.py"), "blas"], cwd=ROOT,
                          env={"PYTHONPATH": f"{ROOT}:{tmp_path}", "PATH": "/usr/bin:/bin",
                               "FAKE_BLAS_THREADS": str(threads), **env},
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    _, var, tasks = proc.stdout.split()
    return var, int(tasks)


def test_blas_threads_keep_the_blas_from_starting_worker_threads(tmp_path):
    """OpenBLAS starts a worker per core when numpy loads (each spins ~0.1 s for work); a command that
    declares ``blas_threads=1`` gets none: its process has a single thread (its /proc/self/task entries)."""
    var, tasks = _blas(tmp_path, 1)
    assert (var, tasks) == ("1", 1)
    # the control, no limit declared: OpenBLAS starts a worker for each further core this process may use
    var, tasks = _blas(tmp_path, 0)
    assert var == "None"
    assert tasks >= 2 if len(os.sched_getaffinity(0)) >= 2 else tasks == 1
    # a user's own setting is kept
    var, tasks = _blas(tmp_path, 1, OPENBLAS_NUM_THREADS="2")
    assert (var, tasks) == ("2", 2)


def test_every_command_has_one_blas_thread_unless_it_says_otherwise():
    """No command here gains from a second BLAS thread (module doc): one is the default, and every package's
    commands keep it."""
    assert Command("x", "m", "h").blas_threads == 1
    for package in ("devices", "renderer", "stimuli", "study", "analysis"):
        for c in importlib.import_module(f"{package}.__main__").COMMANDS:
            assert c.blas_threads == 1, (package, c.name)


# a command split in two: the parser module (imported for --help) names its body, a module that fails to
# import (as a heavy library would cost time): --help must not import it; running the command must
PARSER = '''
from plumbing.dispatch import Body

def register(sub):
    sub.add_parser("go").set_defaults(func=Body("fakebody", "run"))
'''
BODY = '''
import sys
if "FAKE_BODY_BROKEN" in __import__("os").environ:
    raise ImportError("the body was imported")

def run(args):
    print("BODY RAN", "fakebody" in sys.modules, flush=True)
    return 5
'''
SPLIT_MAIN = '''
import sys
from plumbing.dispatch import Command, main, run_as_script
run_as_script(lambda: main("fake", "fake", (Command("go", "fakeparser", "go"),)))
'''


def _run_split(tmp_path, *argv, **env):
    (tmp_path / "fakeparser.py").write_text(textwrap.dedent(PARSER))
    (tmp_path / "fakebody.py").write_text(textwrap.dedent(BODY))
    return subprocess.run([sys.executable, "-c", SPLIT_MAIN, *argv], cwd=ROOT, capture_output=True, text=True,
                          env={"PYTHONPATH": f"{ROOT}:{tmp_path}", "PATH": "/usr/bin:/bin", **env}, timeout=60)


def test_a_commands_body_is_imported_only_when_it_runs(tmp_path):
    helped = _run_split(tmp_path, "go", "--help", FAKE_BODY_BROKEN="1")
    assert helped.returncode == 0 and "usage:" in helped.stdout, helped.stderr   # the body was never imported
    ran = _run_split(tmp_path, "go")
    assert ran.returncode == 5, ran.stderr
    assert "BODY RAN True" in ran.stdout
    broken = _run_split(tmp_path, "go", FAKE_BODY_BROKEN="1")
    assert broken.returncode != 0 and "the body was imported" in broken.stderr


def test_the_projects_warnings_are_warning_lines_and_other_libraries_keep_their_format(tmp_path):
    """A command run as a program prints the project's own warnings as ``warning: <message>`` (no source path,
    line or category: they are meant for the user), and a library's warning in Python's format (its location
    is how one finds the cause)."""
    script = textwrap.dedent('''
        import sys, warnings
        from plumbing.dispatch import run_as_script

        def main():
            # raised "from" a module of the project (what renderer/loop.py's stiffness check does) ...
            warnings.warn_explicit("stiffness_N_m=1e+06 N/m is beyond one count per limit", RuntimeWarning,
                                   "%s/renderer/loop.py", 349)
            # ... and from a library outside the project tree
            warnings.warn_explicit("divide by zero encountered", RuntimeWarning, "/usr/lib/python3/numpy/core.py", 7)
            return 0

        run_as_script(main)
    ''' % ROOT)
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert "warning: stiffness_N_m=1e+06 N/m is beyond one count per limit" in lines
    assert not any("loop.py" in ln for ln in lines)
    assert any(ln.startswith("/usr/lib/python3/numpy/core.py:7: RuntimeWarning: divide by zero") for ln in lines)



# Ctrl-C inside an exec() of source text, as scipy's imports run one (array_api_compat: exec("from numpy import *"))
CTRLC_PARSER = '''
from plumbing.dispatch import Body

def register(sub):
    sub.add_parser("at-import").set_defaults(func=Body("ctrlc.body_at_import", "run"))
    sub.add_parser("at-run").set_defaults(func=Body("ctrlc.body", "run"))
'''
CTRLC_BODY = '''
def run(args):
    exec("raise KeyboardInterrupt")
'''
CTRLC_MAIN = '''
import sys
from plumbing.dispatch import Command, main, run_as_script

def uncaught():
    exec("raise KeyboardInterrupt")

run_as_script(uncaught if sys.argv[1:] == ["uncaught"] else lambda: main("ctrlc", "ctrlc", (
    Command("at-import", "ctrlc.parser", "Ctrl-C while the body loads"), Command("at-run", "ctrlc.parser", "Ctrl-C in the body"))))
'''


def test_ctrl_c_exits_130_with_one_line_also_in_the_imports_and_inside_an_exec_of_source_text(tmp_path):
    """Ctrl-C while a command's body loads or runs: ``interrupted`` and status 130, no traceback. CPython ends a
    ``python -m`` process by SIGINT when a KeyboardInterrupt left an ``exec()`` of source text, even a caught one
    (a report stopped in scipy's imports printed ``interrupted`` and died by SIGINT, status -2); an uncaught
    Ctrl-C still ends the process by SIGINT, as a shell expects."""
    pkg = tmp_path / "ctrlc"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "parser.py").write_text(CTRLC_PARSER)
    (pkg / "body.py").write_text(CTRLC_BODY)
    (pkg / "body_at_import.py").write_text('exec("raise KeyboardInterrupt")\n' + CTRLC_BODY)
    (pkg / "__main__.py").write_text(CTRLC_MAIN)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), str(ROOT)]))
    for command in ("at-import", "at-run"):
        proc = subprocess.run([sys.executable, "-m", "ctrlc", command], cwd=tmp_path, env=env, capture_output=True,
                              text=True, timeout=60)
        assert (proc.returncode, proc.stderr) == (130, "\ninterrupted\n"), (command, proc.returncode, proc.stderr)
    proc = subprocess.run([sys.executable, "-m", "ctrlc", "uncaught"], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == -2 and "KeyboardInterrupt" in proc.stderr, (proc.returncode, proc.stderr)
