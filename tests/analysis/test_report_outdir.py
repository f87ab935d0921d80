"""``analysis report`` writes its folder whole or not at all, one writer at a time, and Ctrl-C is one line
(issue 38, items 1 and 12: SIGTERM mid-report left S2's tables and figures beside S1's report.md and stray
``*.tmp.svg``; two reports into one new --out both exited 0; Ctrl-C printed a KeyboardInterrupt traceback)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from analysis.synthetic import write_synthetic_study
from tests.support.files import tree_hashes

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def studies(tmp_path_factory):
    root = tmp_path_factory.mktemp("studies")
    write_synthetic_study(root / "S1", 4, seed=3)
    write_synthetic_study(root / "S2", 6, seed=7)
    return root


@pytest.fixture(scope="module")
def earlier_report(studies, tmp_path_factory):
    """S1's report, made once in this process by the command's own ``main``; each test copies it."""
    from analysis.__main__ import main

    out = tmp_path_factory.mktemp("earlier") / "R"
    assert main(["report", str(studies / "S1"), "--out", str(out)]) == 0
    return out


def _report(data: Path, out: Path, *extra) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "analysis", "report", str(data), "--out", str(out), *extra],
                            cwd=out.parent, env=dict(os.environ, PYTHONPATH=str(ROOT)), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _writing(parent: Path, name: str) -> bool:
    """A report is writing into its staging folder (a table or figure is there)."""
    return any(any(d.iterdir()) for d in parent.glob(f".{name}.staging-*"))


@pytest.mark.parametrize("sig, code, last_line", [
    (signal.SIGTERM, 143, None),
    (signal.SIGINT, 130, "interrupted"),
])
def test_a_stopped_forced_report_leaves_the_earlier_one_exactly(earlier_report, tmp_path, studies, sig, code,
                                                               last_line):
    out = tmp_path / "R"
    shutil.copytree(earlier_report, out)          # S1's report (the process stopped is the forced second one)
    before = tree_hashes(out)
    second = _report(studies / "S2", out, "--force")
    try:
        while not _writing(tmp_path, "R"):
            assert second.poll() is None, second.communicate()
        second.send_signal(sig)
        _, err = second.communicate(timeout=300)
    finally:
        second.kill()
    assert second.returncode == code, err
    assert "Traceback" not in err
    if last_line:
        assert err.strip().splitlines()[-1] == last_line
    assert tree_hashes(out) == before                        # S1's report, byte for byte, nothing of S2's
    assert sorted(p.name for p in tmp_path.iterdir()) == ["R"]   # no staging folder, no lock, no *.tmp.svg


def test_two_reports_into_one_new_out_the_second_is_refused(studies, tmp_path):
    out = tmp_path / "R"
    first = _report(studies / "S1", out)
    try:
        while not _writing(tmp_path, "R"):
            assert first.poll() is None, first.communicate()
        second = _report(studies / "S2", out)
        _, err = second.communicate(timeout=300)
        assert second.returncode == 2, err
        assert err.startswith(f"error: {out} is being written by another run: pid {first.pid} on host")
        assert first.wait(timeout=300) == 0, first.communicate()
    finally:
        first.kill()
    assert "| report folder | " + str(out) + " |" in (out / "report.md").read_text()   # the first's, named right
    assert "S2" not in (out / "report.md").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["R"]
