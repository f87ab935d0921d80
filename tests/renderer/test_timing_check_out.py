"""``renderer timing-check --out``: staged like every output (an interrupted check never writes a record, earlier
results stay), never over a study's data or a file that is not a check's record, its sizes bounded, and its
busy-loop load processes die with it however it dies.

Once: SIGINT wrote a FAIL record ("stopped early: interrupted") over the earlier one, SIGTERM exited -15 with
no message, ``--out DATA/S01/trials.csv --force`` replaced a subject's trials with JSON, ``--rate-hz 1e9``
had the OOM killer take the process, and a SIGKILLed check left its ``--load-cores`` busy loops spinning.
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from renderer.__main__ import main

ROOT = Path(__file__).resolve().parents[2]
#: the start of plumbing.rtpolicy.warning_line's line
RT_WARNING = "warning: the servo runs without full real-time treatment ("


def _start(tmp_path: Path, *flags) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "renderer", "timing-check", "--duration-s", "60", *flags],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(predicate, proc: subprocess.Popen, what: str, timeout_s: float = 60.0):
    """Poll ``predicate()`` until it is true (the process under test is still running meanwhile)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        assert proc.poll() is None, (what, proc.communicate())
        assert time.monotonic() < deadline, f"timed out waiting for {what}"


def _children(pid: int) -> list[int]:
    out = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            pass
    return out


def _load_processes(pid: int) -> list[int]:
    """The check's load processes that are spinning: past their start-up (their parent-death signal asked for),
    which ends by ignoring SIGINT (renderer.timing_check.LOAD_CODE)."""
    found = []
    for child in _children(pid):
        try:
            cmd = Path(f"/proc/{child}/cmdline").read_bytes()
            ignored = next(int(ln.split()[1], 16) for ln in Path(f"/proc/{child}/status").read_text().splitlines()
                           if ln.startswith("SigIgn:"))
        except (OSError, StopIteration):
            continue
        if b"while True" in cmd and ignored & (1 << (signal.SIGINT - 1)):
            found.append(child)
    return found


def _earlier_record(tmp_path: Path) -> tuple[Path, bytes]:
    out = tmp_path / "tc.json"
    assert main(["timing-check", "--duration-s", "0.3", "--rate-hz", "2000", "--out", str(out),
                 "--max-p99-us", "1e6", "--max-p999-us", "1e6", "--max-period-ms", "1e6"]) == 0
    return out, out.read_bytes()


@pytest.mark.parametrize("sig, code, line", [(signal.SIGINT, 130, "interrupted"),
                                             (signal.SIGTERM, 143, "stopped by SIGTERM")])
def test_a_stopped_check_leaves_the_earlier_record_and_says_one_line(tmp_path, sig, code, line):
    out, before = _earlier_record(tmp_path)
    assert json.loads(before)["verdict"]["met"] is not False
    proc = _start(tmp_path, "--rate-hz", "2000", "--out", str(out), "--force")
    try:
        # the check runs inside its staging folder, with its servo process started
        _wait_for(lambda: list(tmp_path.glob(".tc.json.staging-*")) and _children(proc.pid), proc, "the check")
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == code, stderr
    # one line says how it stopped; a user without real-time privileges also gets the servo's warning about
    # them, when the servo process got that far before the signal (under load it does)
    said = [ln for ln in stderr.splitlines() if ln and not ln.startswith(RT_WARNING)]
    assert "Traceback" not in stderr and said == [line], stderr
    assert "verdict" not in stdout                              # an interrupted check has no verdict
    assert out.read_bytes() == before                           # the earlier record, byte for byte
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tc.json"]   # no staging folder, no lock


def _gone(pid: int) -> bool:
    """The process ``pid`` has ended (no longer listed, or a zombie waiting for its new parent to reap it)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] in ("Z", "X")
    except (OSError, IndexError):
        return True


def _killed_by(pid: int) -> int | None:
    """The signal that ended the zombie ``pid`` (its wait status, the last field of its stat), if still listed."""
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().split()[-1]) & 0x7F
    except (OSError, ValueError):
        return None


def test_load_processes_die_with_a_killed_check(tmp_path):
    proc = _start(tmp_path, "--rate-hz", "2000", "--load-cores", "2")
    loads = []
    try:
        loads = _wait_for(lambda: len(_load_processes(proc.pid)) == 2 and _load_processes(proc.pid), proc,
                          "two load processes")
        proc.kill()
        proc.wait()
        deadline = time.monotonic() + 30.0
        while not all(_gone(pid) for pid in loads):   # the kernel kills them as their parent dies
            assert time.monotonic() < deadline, "a load process outlived the killed check"
        assert {_killed_by(pid) for pid in loads} <= {signal.SIGKILL, None}
    finally:
        proc.kill()
        for pid in loads:
            if not _gone(pid):
                os.kill(pid, signal.SIGKILL)


def _subject(root: Path) -> Path:
    folder = root / "DATA" / "S01"
    folder.mkdir(parents=True)
    (folder / "session.json").write_text('{"subject": "S01"}\n')
    (folder / "trials.csv").write_text("subject,trial\nS01,1\n")
    return folder


@pytest.mark.parametrize("target, message", [
    ("DATA/S01/trials.csv", "lies inside the subject folder"),
    ("DATA/S01/new.json", "lies inside the subject folder"),
    ("DATA/report.json", "lies inside the study folder"),
    ("notes.txt", "exists and is not a timing-check record (what this command writes); not replacing it, with or "
                  "without --force"),
])
def test_force_never_replaces_study_data_or_a_file_that_is_not_a_record(tmp_path, capsys, target, message):
    folder = _subject(tmp_path)
    (tmp_path / "notes.txt").write_text("mine")
    before = {p: p.read_bytes() for p in [*folder.iterdir(), tmp_path / "notes.txt"]}
    assert main(["timing-check", "--duration-s", "0.2", "--out", str(tmp_path / target), "--force"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: --out {tmp_path / target} ") and message in err, err
    assert {p: p.read_bytes() for p in before} == before
    assert not (tmp_path / target).exists() or target in ("DATA/S01/trials.csv", "notes.txt")


@pytest.mark.parametrize("flags, message", [
    (["--rate-hz", "1e9"], "error: --rate-hz must be > 0 and at most 100000 Hz, got 1e+09"),
    (["--duration-s", "1e9"], "error: --duration-s must be > 0 and at most 3600 s, got 1e+09"),
    (["--duration-s", "3000", "--rate-hz", "10000"], "error: --duration-s x --rate-hz must be at most 3000000 ticks"),
])
def test_sizes_are_bounded_naming_the_flag(tmp_path, capsys, flags, message):
    assert main(["timing-check", *flags, "--out", str(tmp_path / "tc.json")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(message) and err.count("\n") == 1, err
    assert list(tmp_path.iterdir()) == []
