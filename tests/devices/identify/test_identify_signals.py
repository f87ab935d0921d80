"""A stop signal to ``devices identify`` orphans no worker process and leaves no staging folder (issue 38,
item 5: SIGTERM left its pool workers in a futex wait under init, for ever, and its ``.I.identify-*``
folder, which no later run removed)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.support.files import tree_hashes
from tests.support.procs import kill, running

ROOT = Path(__file__).resolve().parents[3]
ARGS = ["--device", "sim", "--grips-N", "1,2,3", "--trials", "2", "--duration-s", "1", "--workers", "2"]


def _children(pid: int) -> set[int]:
    """The live child processes of ``pid`` (Linux /proc)."""
    kids = set()
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/children") as fh:
                kids.update(int(k) for k in fh.read().split())
    except OSError:
        pass
    return {k for k in kids if running(k)}


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_a_signal_to_identify_leaves_no_worker_and_no_staging(tmp_path, sig):
    out = tmp_path / "I"
    out.mkdir()
    (out / "model_set.json").write_text('{"earlier": true}')
    before = tree_hashes(out)
    proc = subprocess.Popen([sys.executable, "-m", "devices", "identify", *ARGS, "--out", str(out), "--force"],
                            cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(ROOT)), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    workers: set[int] = set()
    try:
        # wait for the recorder and a fitting worker (forked when the first grip's recordings arrive)
        deadline = time.monotonic() + 300
        while len(workers) < 2 and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            workers |= _children(proc.pid)
            time.sleep(0.02)
        assert len(workers) >= 2, "the recorder and a pool worker never started"
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
        gone = time.monotonic() + 60             # SIGKILL of the parent: the kernel kills the workers next
        while any(running(w) for w in workers) and time.monotonic() < gone:
            time.sleep(0.02)
        assert not [w for w in workers if running(w)], f"orphaned workers: {workers}"
        if sig == signal.SIGTERM:
            assert proc.returncode == 143, err
            assert "Traceback" not in err
            assert err.strip().splitlines()[-1] == f"stopped by SIGTERM: identification stopped; nothing in {out} was replaced"
            assert sorted(p.name for p in tmp_path.iterdir()) == ["I"]           # no staging, no lock
        else:   # SIGKILL: the staging folder stays until the next run that writes I
            assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".I.staging-")) \
                == [".I.lock", "I"]
        assert tree_hashes(out) == before
    finally:
        for w in workers | {proc.pid}:
            kill(w)
