"""A full disk gives one ``error:`` line, leaves the earlier results as they were and no temporary or empty
file (issue 38, item 9: tracebacks, a ``log.tmp.npz`` keeping the disk full, a 0-byte ``sample_summary.csv``).

The disk is "full" for one process by a file-size limit (``RLIMIT_FSIZE``, as ``ulimit -f``), which needs no
root, unlike a small tmpfs: a write past the limit fails with EFBIG (Python ignores SIGXFSZ), as one past
the end of a full disk fails with ENOSPC; both reach the same code."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

from analysis.synthetic import write_synthetic_study
from tests.support.cli import run_cli
from tests.support.files import tree_hashes

ROOT = Path(__file__).resolve().parents[2]


def _limited(limit_bytes: int):
    def set_limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
    return set_limit


def _run(args, cwd: Path, limit_bytes: int) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], cwd=cwd, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                          capture_output=True, text=True, timeout=600, preexec_fn=_limited(limit_bytes))


def _no_debris(folder: Path, kept: list[str]) -> None:
    assert sorted(p.name for p in folder.iterdir()) == kept
    for p in folder.rglob("*"):
        assert not p.name.endswith((".tmp", ".tmp.npz", ".tmp.svg")), p
        assert not (p.is_file() and p.stat().st_size == 0), p


def test_renderer_run_on_a_full_disk(tmp_path):
    res = _run(["renderer", "run", "--device", "sim", "--taps", "2", "--out", "X"], tmp_path, 1 << 20)
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr
    assert res.stderr.strip().splitlines()[-1] == ("error: X: cannot write: File too large (full disk, quota or "
                                                   "file-size limit); earlier results were left as they were")
    _no_debris(tmp_path, [])                                   # no X, no staging, no log.tmp.npz, no lock


def test_forced_analysis_report_on_a_full_disk_keeps_the_earlier_report(tmp_path, capsys):
    write_synthetic_study(tmp_path / "S1", 4, seed=3)
    write_synthetic_study(tmp_path / "S2", 6, seed=7)
    # the earlier report (no limit): made in this process; the forced one on the "full disk" is a process
    ok = run_cli(capsys, "analysis", "report", "S1", "--out", "R", "--no-figures", cwd=tmp_path)
    assert ok.returncode == 0, ok.stderr
    before = tree_hashes(tmp_path / "R")
    res = _run(["analysis", "report", "S2", "--out", "R", "--force", "--no-figures"], tmp_path, 1000)
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr
    assert res.stderr.strip().splitlines()[-1].endswith("cannot write: File too large (full disk, quota or "
                                                        "file-size limit); earlier results were left as they were")
    assert tree_hashes(tmp_path / "R") == before               # S1's report, byte for byte
    _no_debris(tmp_path, ["R", "S1", "S2"])
