"""Servo timing on this machine: timing-check quiet and beside two busy loops, with and without the RT policy.

Each figure is a ``renderer timing-check`` run (``renderer.timing_check.run_check``: the servo loop in its own
process, paced at 10 kHz, motor off). Targets as root beside two busy loops: period error p99 <= 20 us,
p99.9 <= 50 us, no period above 1 ms. ``HFAM_BENCH_TIMING_S`` sets each run's length (default 60 s).
"""

from __future__ import annotations

import os

from renderer.timing_check import run_check


def _line(label: str, rec: dict) -> str:
    f, pol, v = rec["figures"], rec["policy"] or {}, rec["verdict"]
    return (f"{label}: {pol.get('policy')} prio {pol.get('priority')} mlockall {pol.get('mlockall')} CPU "
            f"{pol.get('affinity')}; {f['periods']} periods, error p50/p99/p99.9/max {f['period_error_p50_us']:.1f}/"
            f"{f['period_error_p99_us']:.1f}/{f['period_error_p999_us']:.1f}/{f['period_error_max_us']:.0f} us, "
            f"longest period {f['period_max_us']:.0f} us, overruns {f['overruns']} "
            f"({100.0 * f['overruns'] / max(1, f['periods']):.2f} %); verdict "
            f"{'PASS' if v['met'] else 'FAIL: ' + '; '.join(v['failed'])}")


def main() -> None:
    duration = float(os.environ.get("HFAM_BENCH_TIMING_S", "60"))
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; uid {os.getuid()}; "
          f"{duration:g} s per run at 10 kHz", flush=True)
    for label, load, policy in (("quiet, RT policy", 0, True), ("2 busy loops, RT policy", 2, True),
                                ("2 busy loops, no RT policy", 2, False)):
        rec = run_check(duration_s=duration, rate_hz=10000.0, load_cores=load, realtime_policy=policy)
        print(_line(label, rec), flush=True)


if __name__ == "__main__":
    main()
