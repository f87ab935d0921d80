"""SIGTERM to `renderer run` on a (pty-emulated) serial device: the host's last CURRENT frame is 0 A.

The emulator runs in a thread of this process and records every current the host commands; the
command runs in its own process, as from a shell or a service manager, streaming at 1 kHz with no
``--duration-s`` ("until Ctrl-C"), the emulated hand pressing the stylus into the wall (a steady
current). Both the in-process loop and the servo child (renderer.process) are checked.
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.support.emulated import drain, recording_emulator
from tests.support.procs import running
from tests.support.stalls import run_stalled

ROOT = Path(__file__).resolve().parents[2]


def _servo_children(pid: int) -> list[int]:
    """The multiprocessing children of ``pid`` that run a target (not its resource tracker)."""
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    ppid = int(fh.read().rsplit(")", 1)[1].split()[1])
                with open(f"/proc/{entry}/cmdline", "rb") as fh:
                    cmdline = fh.read()
            except (OSError, IndexError, ValueError):
                continue
            if ppid == pid and b"spawn_main" in cmdline:
                out.append(int(entry))
    return out


@pytest.mark.parametrize("in_process", [True, False], ids=["in-process", "servo-process"])
def test_sigterm_to_renderer_run_zeroes_the_serial_device(in_process, tmp_path):
    cfg = tmp_path / "cfg.toml"
    cfg.write_text("watchdog_overrun_s = 0.2\n")  # a loaded machine's stalls are not what is tested here
    for attempt in range(3):
        if _sigterm_run(in_process, tmp_path, cfg, attempt):
            return
        # the machine stalled the run for longer still before the signal (a 224 ms tick period, seen with two
        # suites on 2 cores): its watchdog or the link's stop rule, tested apart, rightly ended it first; run again
    raise AssertionError("each of 3 runs was stopped by a stall of the machine before the signal")


def _sigterm_run(in_process: bool, tmp_path: Path, cfg: Path, attempt: int) -> bool:
    """One run, SIGTERMed once its current is steady; False when it ended before that with a stall in its
    records (:func:`tests.support.stalls.run_stalled`), which is only allowed before the last attempt."""
    port, handle, sent = recording_emulator(-0.01)
    out = tmp_path / f"run{attempt}"
    # a reply later than 0.2 s is lost: the emulator (in this process) once answered nothing for about 0.2 s on a
    # loaded machine, 10 replies in a row later than 0.02 s, and the link's stop rule (tested apart) ended the run
    # before the signal was sent
    cmd = [sys.executable, "-m", "renderer", "run", "--device", f"serial:{port}?loss_timeout_s=0.2",
           "--config", str(cfg), "--out", str(out)] + (["--in-process"] if in_process else [])
    log = tmp_path / f"output{attempt}.txt"
    with open(log, "w") as fh:  # a file, not a pipe: an orphaned servo child would hold a pipe open
        p = subprocess.Popen(cmd, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=fh,
                             stderr=subprocess.STDOUT)
    kids = []
    try:
        t_end = time.monotonic() + 120.0  # a spawned interpreter's start-up on a loaded machine
        # 1,200 commands: the run's own ticks then exceed 1,000 (a few of the frames are its set-up zeros)
        while not (len(sent) > 1200 and all(sent[-50:])):
            if p.poll() is not None:
                if attempt < 2 and run_stalled(out):
                    return False
                raise AssertionError(log.read_text())
            assert time.monotonic() < t_end, f"no steady current within 120 s ({len(sent)} frames)"
            time.sleep(0.05)
        kids = _servo_children(p.pid)
        assert len(kids) == (0 if in_process else 1)
        p.send_signal(signal.SIGTERM)
        p.wait(timeout=60)
        err = log.read_text()
        drain(port, handle)   # every frame the command wrote before it exited is recorded
        n = len(sent)
        time.sleep(1.0)  # the link stays quiet
        assert p.returncode == 128 + signal.SIGTERM, err
        # the host's own last command is 0 A (the device watchdog, 100 ms later, is only the last line of defence)
        assert sent[-1] == 0.0 and max(abs(i) for i in sent) > 0.05
        assert len(sent) == n, f"{len(sent) - n} frames after the command exited"
        assert not any(running(k) for k in kids), "the servo child outlived the command"
        run = json.loads((out / "run.json").read_text())  # the partial run is kept, as after Ctrl-C
        assert run["stop_reason"] == "interrupted" and run["ticks"] > 1000
        return True
    finally:
        for pid in [p.pid] + kids:  # nothing is left behind, whatever failed
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        handle.stop()
