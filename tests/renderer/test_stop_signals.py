"""SIGTERM, SIGHUP and the parent's death stop a servo loop with the output zeroed (plumbing.stopsignals).

Real processes, real signals: a :class:`tests.renderer.fakes.RecordingMassDevice` pressed into the wall
(a steady ~0.3 A) appends every current it is sent to a file, so the tests read what reached the
"motor" last after the process driving it was signalled or its parent killed. Every wait is for an
observed state (currents on file, a process gone) with a generous bound: a loaded 2-core machine can
take seconds to start a spawned interpreter.
"""

import functools
import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from renderer import RendererConfig, run_in_process
from tests.support.procs import kill
from tests.renderer.fakes import make_recording_device, recorded_currents

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
START_S = 120.0  # bound on a spawned interpreter's start-up plus the loop's set-up on a loaded machine


def _wait_driving(path: str, procs=(), timeout_s: float = START_S) -> np.ndarray:
    """Wait until the loop has sent 2000 currents and its latest are not zero (it is pressing the wall)."""
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        cur = recorded_currents(path)
        if len(cur) >= 2000 and np.all(cur[-100:] != 0.0):
            return cur
        for p in procs:
            if p.poll() is not None:
                pytest.fail(f"process exited early with {p.returncode}")
        time.sleep(0.05)
    pytest.fail(f"the loop did not drive the device within {timeout_s} s ({len(recorded_currents(path))} currents)")


def _gone(pid: int) -> bool:
    """True once ``pid`` has exited (a zombie counts: it runs no more code)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] == "Z"
    except (FileNotFoundError, ProcessLookupError):
        return True


SEMANTICS = textwrap.dedent("""
    import os, signal, time
    from plumbing.stopsignals import Terminated, holding, stop_on_signals
    signal.signal(signal.SIGHUP, signal.SIG_DFL)  # as under a terminal, whatever the test runner's
    # a signal raises Terminated at once; the previous handlers are back afterwards
    try:
        with stop_on_signals():
            os.kill(os.getpid(), signal.SIGHUP)
            time.sleep(30)
        print("not raised")
    except Terminated as exc:
        print("raised", exc.signum, exc.code)
    print("restored", signal.getsignal(signal.SIGTERM) is signal.SIG_DFL,
          signal.getsignal(signal.SIGHUP) is signal.SIG_DFL)
    # a caller's own handler, and an ignored SIGHUP (nohup), are left alone
    def mine(signum, frame):
        print("own handler", signum)
    signal.signal(signal.SIGTERM, mine)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    with stop_on_signals() as block:
        print("installed", block.installed)
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGHUP)
        time.sleep(0.2)
    print("kept", signal.getsignal(signal.SIGTERM) is mine, signal.getsignal(signal.SIGHUP) is signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    # held: the section runs to its end, then Terminated; a second signal is ignored
    try:
        with stop_on_signals():
            with holding():
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.2)
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.2)
                print("section finished")
    except Terminated as exc:
        print("raised after it", exc.signum)
    # uncaught: the exit status is 128 + the signal's number, no traceback
    with stop_on_signals():
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(30)
""")


def test_stop_signals_in_a_real_process():
    p = subprocess.run([sys.executable, "-c", SEMANTICS], cwd=ROOT, env=ENV, capture_output=True, text=True,
                       timeout=120)
    assert p.stdout.split("\n") == [
        "raised 1 129", "restored True True",
        "installed False", "own handler 15", "kept True True",
        "section finished", "raised after it 15", ""], p.stderr
    assert p.returncode == 128 + signal.SIGTERM and "Traceback" not in p.stderr


SWALLOWED = textwrap.dedent("""
    import ctypes, os, signal, sys
    from plumbing.stopsignals import Terminated, holding, stop_if_signalled, stop_on_signals
    # a Python function C calls back: an exception raised in it is printed ("Exception ignored") and dropped
    callback = ctypes.CFUNCTYPE(None)(lambda: os.kill(os.getpid(), signal.SIGTERM))
    others = []
    mine = lambda u: others.append(type(u.exc_value).__name__)
    sys.unraisablehook = mine
    with stop_on_signals() as block:
        stop_if_signalled()                      # no signal: nothing
        try:
            callback()
            print("survived the callback", block.signum, block.lost)
            stop_if_signalled()
            print("not raised")
        except Terminated as exc:
            print("raised", exc.signum, exc.code)
        stop_if_signalled()                      # raised once only
        ctypes.CFUNCTYPE(None)(lambda: 1 / 0)()  # not a stop: the hook that was in place sees it
    print("hook back", others, sys.unraisablehook is mine)
    try:
        with stop_on_signals():
            callback()
            with holding():
                stop_if_signalled()              # held: not here, at the section's end
                print("held")
    except Terminated as exc:
        print("raised after the section", exc.signum)
    try:
        with stop_on_signals():
            callback()
            print("never checked")
    except Terminated as exc:
        print("raised at the block's end", exc.signum)
""")


def test_a_stop_swallowed_in_a_ctypes_callback_is_raised_where_the_run_can_stop():
    """The raise inside a C callback (llvmlite's, during numba's compile) is lost to Python; the block keeps it
    and raises it at the next check, at a holding's end or at the block's end, once, without the noise."""
    p = subprocess.run([sys.executable, "-c", SWALLOWED], cwd=ROOT, env=ENV, capture_output=True, text=True,
                       timeout=120)
    assert p.stdout.split("\n") == [
        "survived the callback 15 True", "raised 15 143", "hook back ['ZeroDivisionError'] True",
        "held", "raised after the section 15", "never checked", "raised at the block's end 15", ""], p.stderr
    assert p.returncode == 0 and "Exception ignored" not in p.stderr and "Traceback" not in p.stderr


# the child: numba's compiler sends itself SIGTERM from inside llvmlite's object-cache callback (the ctypes
# callback LLVM calls when it has compiled a module), so the signal lands there every time, not by timing
IN_COMPILE = textwrap.dedent("""
    import os, runpy, signal, sys
    from numba.core.codegen import JITCodeLibrary
    compiled = JITCodeLibrary._object_compiled_hook.__func__
    sent = []
    def hook(cls, ll_module, buf):
        if not sent:
            sent.append(1)
            print("SIGTERM inside numba's compiler", file=sys.stderr, flush=True)
            os.kill(os.getpid(), signal.SIGTERM)
        return compiled(cls, ll_module, buf)
    JITCodeLibrary._object_compiled_hook = classmethod(hook)
    sys.argv = ["renderer", *sys.argv[1:]]
    runpy.run_module("renderer", run_name="__main__", alter_sys=True)
""")


def test_a_sigterm_inside_numbas_compile_stops_the_run(tmp_path):
    """Cold numba cache, no ahead-of-time build: the run compiles its law and physics, and a SIGTERM delivered
    inside the compiler (where llvmlite's callback swallowed it: the run went on to exit 0) stops it before its
    first tick, with exit status 143 and its (empty) partial run saved, as any SIGTERM."""
    env = {**ENV, "NUMBA_CACHE_DIR": str(tmp_path / "numba"), "HFAM_SIM_AOT": "off"}
    p = subprocess.run([sys.executable, "-c", IN_COMPILE, "run", "--device", "sim", "--taps", "3", "--out",
                        str(tmp_path / "X")], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert p.returncode == 143, p.stderr
    assert p.stderr == f"SIGTERM inside numba's compiler\nstopped by SIGTERM: partial run saved to {tmp_path / 'X'}\n"
    assert list((tmp_path / "numba").rglob("*.nbi"))                  # it was compiling (a cold cache, filled)
    run = json.loads((tmp_path / "X" / "run.json").read_text())
    assert (run["stop_reason"], run["ticks"], run["error"]) == ("interrupted", 0, "Terminated: stopped by SIGTERM")
    assert (tmp_path / "X" / "events.csv").read_text().count("\n") == 1     # the header: no tap was rendered


# the child: a class made as the run's first command is sent (where the sim's kernel, and numba with it, is
# imported: numba's import makes many) gets a descriptor whose __set_name__ sends SIGTERM, so the signal lands where
# Python wraps the raise ("RuntimeError: Error calling __set_name__"), every time, not by timing
IN_CLASS = textwrap.dedent("""
    import os, runpy, signal, sys
    import devices.sim.device as D
    kernel_tick = D._kernel_tick
    class Stop:
        def __set_name__(self, owner, name):
            print("SIGTERM inside a class being made", file=sys.stderr, flush=True)
            os.kill(os.getpid(), signal.SIGTERM)
    def tick():
        type("Made", (), {"attr": Stop()})
        return kernel_tick()
    D._kernel_tick = tick
    sys.argv = ["renderer", *sys.argv[1:]]
    runpy.run_module("renderer", run_name="__main__", alter_sys=True)
""")


def test_a_sigterm_that_python_wraps_in_another_error_still_stops_the_run(tmp_path):
    """A SIGTERM inside a ``__set_name__`` (numba's import, seen on a loaded machine) reached the run as a
    RuntimeError: exit 1 with a traceback, ``stop_reason`` "exception". It is a stop like any other: exit status
    143, one line, the (empty) partial run saved as interrupted."""
    env = {**ENV, "HFAM_SIM_AOT": "off"}
    p = subprocess.run([sys.executable, "-c", IN_CLASS, "run", "--device", "sim", "--taps", "3", "--out",
                        str(tmp_path / "X")], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert p.returncode == 143, p.stderr
    assert p.stderr == f"SIGTERM inside a class being made\nstopped by SIGTERM: partial run saved to {tmp_path / 'X'}\n"
    run = json.loads((tmp_path / "X" / "run.json").read_text())
    assert (run["stop_reason"], run["ticks"], run["error"]) == ("interrupted", 0, "Terminated: stopped by SIGTERM")


def test_handlers_only_in_the_main_thread_and_restored():
    from plumbing.stopsignals import stop_on_signals

    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP)}
    with stop_on_signals() as block:
        if before[signal.SIGTERM] is signal.SIG_DFL:
            assert block.installed and signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL
        with stop_on_signals() as inner:  # nested: the outer block's handlers serve
            assert not inner.installed
    assert {s: signal.getsignal(s) for s in before} == before
    seen = []
    t = threading.Thread(target=lambda: seen.append(stop_on_signals().__enter__().installed))
    t.start()
    t.join(30.0)
    assert seen == [False]
    assert {s: signal.getsignal(s) for s in before} == before


IN_PROCESS = textwrap.dedent("""
    import signal, sys
    from renderer import RendererConfig, ServoLoop
    from tests.renderer.fakes import RecordingMassDevice
    signal.signal(signal.SIGHUP, signal.SIG_DFL)  # as under a terminal, whatever the test runner's
    dev = RecordingMassDevice(sys.argv[1])
    loop = ServoLoop(dev, RendererConfig())
    try:
        with dev:
            loop.run(duration_s=600.0, realtime=True)
    finally:
        print("stop_reason", loop.result.stop_reason if loop.result is not None else None, flush=True)
""")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_signal_to_an_in_process_run_zeroes_the_output(sig, tmp_path):
    path = str(tmp_path / "currents.bin")
    p = subprocess.Popen([sys.executable, "-c", IN_PROCESS, path], cwd=ROOT, env=ENV, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    try:
        _wait_driving(path, [p])
        p.send_signal(sig)
        out, err = p.communicate(timeout=60)
    finally:
        kill(p.pid)
    cur = recorded_currents(path)
    assert np.count_nonzero(cur) > 1000  # it was pushing on the wall ...
    assert cur[-1] == 0.0  # ... and the last current sent is zero (before the fix: ~0.3 A, exit -15)
    assert p.returncode == 128 + sig, err
    assert "stop_reason interrupted" in out and "Traceback" not in err


PARENT = textwrap.dedent("""
    import functools, signal, sys
    from renderer import RendererConfig, run_in_process
    from tests.renderer.fakes import make_recording_device
    if __name__ == "__main__":
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
        run_in_process(functools.partial(make_recording_device, sys.argv[1]), RendererConfig(), None,
                       realtime=True, nice=0)
""")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_servo_child_stops_with_zero_output_when_its_parent_is_signalled_or_dies(sig, tmp_path):
    """SIGTERM: the parent stops the child, then exits 143. SIGKILL: the kernel's parent-death signal
    (PR_SET_PDEATHSIG) stops the child. Either way the child is gone within seconds, its output zero."""
    path = str(tmp_path / "currents.bin")
    script = tmp_path / "parent.py"
    script.write_text(PARENT)
    log = tmp_path / "stderr.txt"
    with open(log, "w") as fh:  # a file, not a pipe: an orphaned child would hold a pipe open
        p = subprocess.Popen([sys.executable, str(script), path], cwd=ROOT, env=ENV, stderr=fh)
    child = None
    try:
        _wait_driving(path, [p])
        child = int(Path(path + ".pid").read_text())
        assert child != p.pid
        t0 = time.monotonic()
        p.send_signal(sig)
        p.wait(timeout=60)
        err = log.read_text()
        while not _gone(child) and time.monotonic() - t0 < 60:
            time.sleep(0.02)
        gone_s = time.monotonic() - t0
        n = len(recorded_currents(path))
        time.sleep(0.5)
        cur = recorded_currents(path)
    finally:
        kill(p.pid)
        if child is not None:
            kill(child)  # before the fix the orphan kept driving the device
    assert gone_s < 10.0, f"the servo child outlived its parent by {gone_s:.1f} s"
    assert p.returncode == (128 + sig if sig == signal.SIGTERM else -sig), err
    assert len(cur) == n  # nothing sent after it exited
    assert np.count_nonzero(cur) > 1000 and cur[-1] == 0.0


def test_parent_watch_notices_the_parent_is_gone(tmp_path):
    """The portable fallback to PR_SET_PDEATHSIG: a grandchild polls ParentWatch until its parent exits."""
    out = tmp_path / "watch.txt"
    grandchild = textwrap.dedent("""
        import os, sys, time
        from plumbing.stopsignals import ParentWatch
        watch = ParentWatch(os.getppid(), every=10)
        print("ready", flush=True)
        t_end = time.monotonic() + 60
        while not watch() and time.monotonic() < t_end:
            time.sleep(0.001)
        open(sys.argv[1], "w").write("gone" if watch.gone else "timeout")
    """)
    middle = textwrap.dedent("""
        import os, subprocess, sys
        g = subprocess.Popen([sys.executable, "-c", sys.argv[1], sys.argv[2]], stdout=subprocess.PIPE)
        assert g.stdout.readline().strip() == b"ready"
        os._exit(0)
    """)
    subprocess.run([sys.executable, "-c", middle, grandchild, str(out)], cwd=ROOT, env=ENV, timeout=120, check=True)
    t_end = time.monotonic() + 90
    while not out.exists() and time.monotonic() < t_end:
        time.sleep(0.05)
    time.sleep(0.1)
    assert out.read_text() == "gone"


def test_timeout_stops_a_stuck_child_with_sigterm_and_zero_output(tmp_path, monkeypatch):
    """The timeout path: the stop event first; a child stuck in read() (a stalled link) cannot see it, so
    after STOP_GRACE_S it is sent SIGTERM, which now zeroes the device and returns the partial run."""
    from renderer import process

    # generous: the SIGTERM must find the child running (a spawned interpreter takes 0.5-5 s to start here)
    monkeypatch.setattr(process, "STOP_GRACE_S", 10.0, raising=False)
    path = str(tmp_path / "currents.bin")
    t0 = time.monotonic()
    with pytest.raises(RuntimeError, match="Terminated") as info:
        run_in_process(functools.partial(make_recording_device, path, hang_at=10), RendererConfig(), None,
                       realtime=True, timeout_s=1.0, nice=0)
    elapsed = time.monotonic() - t0
    cur = recorded_currents(path)
    assert np.count_nonzero(cur) >= 5  # it drove the wall before read() stalled ...
    assert cur[-1] == 0.0  # ... and the SIGTERM zeroed it (before the fix: killed with the current on)
    assert info.value.partial_result.stop_reason == "interrupted"
    assert elapsed < 1.0 + 2 * 10.0 + 10.0  # asked, SIGTERMed, never killed
