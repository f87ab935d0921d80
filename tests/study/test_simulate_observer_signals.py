"""``study simulate-observer`` writes its folder staged: SIGTERM or Ctrl-C during the simulation ends with one line
and exit 143 / 130, the earlier results exactly as they were and nothing beside them.

Once: it wrote straight into ``--out`` (a stop left new tables beside old figures, or an empty folder) and
SIGTERM exited -15 with no message.
"""

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from study.__main__ import main
from tests.support.files import tree_hashes

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("sig, code, line", [(signal.SIGINT, 130, "interrupted"),
                                             (signal.SIGTERM, 143, "stopped by SIGTERM")])
def test_a_stopped_simulation_keeps_the_earlier_results(tmp_path, sig, code, line):
    out = tmp_path / "SIM"
    assert main(["simulate-observer", "--method", "updown", "--threshold", "2", "--trials", "10",
                 "--out", str(out)]) == 0
    before = tree_hashes(out)
    # a long run (many repeats of Psi): stopped while it computes inside its staging folder
    proc = subprocess.Popen([sys.executable, "-m", "study", "simulate-observer", "--method", "psi", "--threshold",
                             "2", "--trials", "400", "--repeat", "5000", "--out", str(out), "--force"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob(".SIM.staging-*")):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "timed out waiting for the staging folder"
            time.sleep(0.01)
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == code, stderr
    assert "Traceback" not in stderr and stderr.strip().splitlines() == [line], stderr
    assert tree_hashes(out) == before                                   # the earlier results, byte for byte
    assert sorted(p.name for p in tmp_path.iterdir()) == ["SIM"]        # no staging folder, no lock
