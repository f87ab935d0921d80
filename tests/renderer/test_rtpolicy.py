"""Issue 40: the servo's real-time policy (plumbing.rtpolicy), the timing verdict and ``renderer timing-check``.

These tests hold as root (SCHED_FIFO, mlockall granted) and as an ordinary user without rtprio (the run goes
on at normal priority and one warning line names the remedy): each branch asserts what the OS actually
granted, read back from the kernel. The verdicts are driven by thresholds, never by the machine's load.
"""

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np

from plumbing import rtpolicy
from renderer.process import run_in_process
from renderer.timing_check import QuietDevice, _QuietFactory
from renderer.timing_verdict import TimingThresholds, period_figures, verdict
from renderer.config import RendererConfig

ROOT = Path(__file__).resolve().parents[2]


def _may_fifo() -> bool:
    """Whether this process may ask for SCHED_FIFO 80: CAP_SYS_NICE in its effective set (root, or an interpreter
    given it with setcap) or an rtprio limit that allows it."""
    soft = resource.getrlimit(resource.RLIMIT_RTPRIO)[0]
    with open("/proc/self/status") as fh:
        cap_eff = int(next(ln for ln in fh if ln.startswith("CapEff:")).split()[1], 16)
    return bool(cap_eff >> 23 & 1) or soft == resource.RLIM_INFINITY or soft >= rtpolicy.RT_PRIORITY


def test_acquire_gets_or_reports_each_part_and_the_kernel_agrees():
    code = ("import json, os\nfrom plumbing import rtpolicy\n"
            "core = rtpolicy.servo_core()\nrec = rtpolicy.acquire(core=core)\n"
            "rec['kernel'] = {'fifo': os.sched_getscheduler(0) == os.SCHED_FIFO,"
            " 'prio': os.sched_getparam(0).sched_priority, 'cpus': sorted(os.sched_getaffinity(0)),"
            " 'core': core}\n"
            "rec['line'] = rtpolicy.warning_line(rec)\nprint(json.dumps(rec))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    rec = json.loads(out.stdout)
    k = rec["kernel"]
    assert (rec["policy"] == "SCHED_FIFO") == k["fifo"] and rec["priority"] == k["prio"]
    # pinned to the servo core only with SCHED_FIFO (unpinned, a busy core could hold the servo)
    pinned = k["core"] is not None and k["fifo"]
    assert rec["affinity"] == k["cpus"] == ([k["core"]] if pinned else k["cpus"])
    with open("/proc/sys/kernel/sched_rt_runtime_us") as fh:
        assert rec["rt_runtime_us"] == int(fh.read())
    if _may_fifo():
        assert k["fifo"] and k["prio"] == rtpolicy.RT_PRIORITY
        assert not any(m.startswith("SCHED_FIFO") for m in rec["missing"])
    else:  # an ordinary user without rtprio: refused, reported, and the remedy is named
        assert not k["fifo"] and any(m.startswith("SCHED_FIFO") for m in rec["missing"])
        line = rec["line"]
        assert "\n" not in line and line.startswith("warning:")
        assert f"rtprio {rtpolicy.RT_PRIORITY}" in line and "/etc/security/limits.conf" in line
        assert "setcap cap_sys_nice" in line


def test_servo_process_records_the_policy_restores_the_parent_and_warns_at_most_once(capsys):
    before = os.sched_getaffinity(0)
    cfg = RendererConfig(motor_enabled=False, stiffness_N_m=0.0, rate_hz=2000.0)
    results = [run_in_process(_QuietFactory(2000.0), cfg, duration_s=0.6, realtime=True) for _ in range(2)]
    assert os.sched_getaffinity(0) == before              # the parent left the servo's core only meanwhile
    err = capsys.readouterr().err
    for r in results:
        pol = r.timing["policy"]
        assert r.stop_reason == "duration" and r.timing["ticks"] == 1200
        assert pol["requested"]["policy"] == "SCHED_FIFO" and pol["requested"]["core"] == rtpolicy.servo_core()
        pinned = rtpolicy.servo_core() is not None and pol["policy"] == "SCHED_FIFO"
        assert pol["affinity"] == ([rtpolicy.servo_core()] if pinned else sorted(before))
        assert r.timing["timing_verdict"]["met"] in (True, False)
        assert r.log["current_A"].max() == 0.0 == r.log["current_A"].min()     # motor off: zero every tick
    warnings = [ln for ln in err.splitlines() if ln.startswith("warning: the servo runs without")]
    if _may_fifo():
        assert all(r.timing["policy"]["policy"] == "SCHED_FIFO" for r in results) and not warnings
        # under SCHED_FIFO the loop spins only a throttling-safe margin before each deadline
        assert results[0].timing["policy"]["spin_margin_us"] <= rtpolicy.FIFO_SPIN_MARGIN_S * 1e6
    else:
        assert all(r.timing["policy"]["policy"] == "SCHED_OTHER" for r in results)
        assert len(warnings) <= 1 and (len(warnings) == 1 or rtpolicy._warned)   # once per process


def test_period_figures_and_verdict_of_a_known_clock():
    rate = 10000.0
    periods_ns = np.full(5000, 100_000, dtype=np.int64)
    periods_ns[::100] += 60_000          # 1 % of the periods 60 us late
    periods_ns[1234] = 1_500_000         # one 1.5 ms stall (51 overruns: > half a period late)
    wall = np.concatenate([[0], np.cumsum(periods_ns)])
    f = period_figures(wall, rate)
    err = np.abs(periods_ns / 1000.0 - 100.0)
    assert f["periods"] == 5000 and f["period_max_us"] == 1500.0 and f["period_error_max_us"] == 1400.0
    assert f["period_error_p99_us"] == np.percentile(err, 99) and f["period_error_p999_us"] == np.percentile(err, 99.9)
    assert f["overruns"] == 51 and sum(f["histogram"]["counts"]) == 5000
    assert f["histogram"]["counts"][0] == 5000 - 51                              # 0-2 us: the exact periods
    v = verdict(f)
    assert v["met"] is False and len(v["failed"]) == 3                           # p99, p99.9, longest period
    assert verdict(f, TimingThresholds(period_error_p99_us=70, period_error_p999_us=70, max_period_ms=2.0))["met"]
    link = {"rtt_p99_s": 0.003, "longest_gap_s": 0.002, "losses": 2, "crc_errors": 0}
    loose = TimingThresholds(period_error_p99_us=1e6, period_error_p999_us=1e6, max_period_ms=1e6)
    assert verdict(f, loose, link=link)["failed"] == ["link round trip p99 3.00 ms > 2 ms", "2 lost frames on the link"]
    assert verdict(period_figures(wall[:500], rate))["met"] is None               # too few periods to judge


def _check(tmp_path, *flags):
    out = tmp_path / "tc.json"
    proc = subprocess.run([sys.executable, "-m", "renderer", "timing-check", "--duration-s", "0.5", "--rate-hz", "4000",
                           "--out", str(out), "--force", *flags], cwd=ROOT, capture_output=True, text=True, timeout=120)
    return proc, (json.loads(out.read_text()) if out.exists() else None)


def test_timing_check_fails_and_passes_by_its_thresholds(tmp_path):
    # p99.9 of |period error| <= 1e-9 us: every period would have to be exact to the nanosecond
    proc, rec = _check(tmp_path, "--max-p99-us", "1e-9", "--max-p999-us", "1e-9")
    assert proc.returncode == 1, proc.stderr
    assert "verdict: FAIL: period error p99" in proc.stdout and "period error histogram (us):" in proc.stdout
    assert rec["verdict"]["met"] is False and rec["figures"]["periods"] == 1999
    assert sum(rec["figures"]["histogram"]["counts"]) == 1999
    assert rec["policy"]["requested"]["policy"] == "SCHED_FIFO"
    proc, rec = _check(tmp_path, "--max-p99-us", "1e6", "--max-p999-us", "1e6", "--max-period-ms", "1e6")
    assert proc.returncode == 0, proc.stderr
    assert "verdict: PASS" in proc.stdout and rec["verdict"]["met"] is True
    warn = [ln for ln in proc.stderr.splitlines() if ln.startswith("warning:")]
    assert len(warn) == (0 if _may_fifo() else 1)


def test_timing_check_refuses_bad_flags_with_one_line(tmp_path):
    for flags in (["--duration-s", "0"], ["--rate-hz", "nan"], ["--load-cores", "-1"]):
        proc = subprocess.run([sys.executable, "-m", "renderer", "timing-check", *flags], cwd=ROOT,
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr and flags[0] in proc.stderr


def test_quiet_device_is_a_device_that_zeroes():
    dev = QuietDevice(1000.0)
    with dev:
        s = dev.read()
        dev.command(float("nan"))         # the Device base class never passes a NaN on
        assert dev.last_command_A == 0.0 and s.t_s == 0.001
