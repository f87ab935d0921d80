"""The emulator process exits on SIGTERM every time, releases its pty and says what it was doing (issue 15)."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from devices.hardware.serial_device import SerialDevice

ROOT = Path(__file__).resolve().parents[3]


def _spawn():
    return subprocess.Popen([sys.executable, "-m", "devices", "emulate", "--pty"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.parametrize("when", ["while loading", "idle", "streaming to a host"])
def test_sigterm_ends_the_emulator_and_releases_its_pty(when):
    proc = _spawn()
    port = None
    dev = None
    try:
        if when == "while loading":
            time.sleep(0.5)  # interpreter up, physics still loading: the handler must already be there
        else:
            line = proc.stdout.readline()
            assert line.startswith("PORT "), line
            port = line.split()[1]
            if when == "streaming to a host":
                dev = SerialDevice(port)
                dev.open()
                for _ in range(50):
                    dev.read()
                    dev.command(0.05)
            st = os.stat(port)
            ours = (st.st_uid, st.st_ctime_ns)
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=5)
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if dev is not None:
            dev.close()
    err = proc.stderr.read()
    assert proc.returncode in (0, -signal.SIGTERM), err
    assert took < 3.0
    if when != "while loading" or proc.returncode == 0:
        assert "emulator: SIGTERM after" in err, err
    if when == "streaming to a host":
        assert "serving /dev/pts/" in err and "frames in/out" in err and "pty released" in err
    if port is not None and dev is None:
        # the pty pair is gone; its number may already name another process's new pty (a busy machine):
        # then it is a different node (owner or creation time)
        try:
            st = os.stat(port)
        except FileNotFoundError:
            pass
        else:
            assert (st.st_uid, st.st_ctime_ns) != ours, port
