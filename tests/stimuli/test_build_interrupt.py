"""Ctrl-C or SIGTERM in ``build-library``: one line, no traceback, the earlier library as it was and no
temporary file (issue 38, items 1 and 12: Ctrl-C printed a KeyboardInterrupt traceback)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.files import sha256
from tests.support.stimuli import minimum_phase_model, synthetic_taps, write_taps_csv

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("sig, code, last", [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, None)])
def test_a_stopped_build_keeps_the_earlier_library_and_prints_no_traceback(tmp_path, sig, code, last):
    rec = tmp_path / "rec.csv"
    write_taps_csv(rec, synthetic_taps((0.04, 0.06, 0.08, 0.1, 0.13, 0.16, 0.2, 0.25), noise=0.02))
    model = minimum_phase_model(grip_N=1.0).save(tmp_path / "grip1.json")
    lib = tmp_path / "lib.npz"
    lib.write_bytes(b"the earlier library")
    before = sha256(lib)
    proc = subprocess.Popen([sys.executable, "-m", "stimuli", "build-library", "--recordings", str(rec), "--model",
                             str(model), "--device", "none", "--force-per-amp-N-A", "2.35", "--out", str(lib),
                             "--force"], cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().startswith("reading ")     # under way: the output lock is held
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == code, err
    assert "Traceback" not in err
    if last:
        assert err.strip().splitlines()[-1] == last
    assert sha256(lib) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["grip1.json", "lib.npz", "rec.csv"]
