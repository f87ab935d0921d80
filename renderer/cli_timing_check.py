"""``python -m renderer timing-check``: check this machine's servo timing as the loop would run.

Runs the servo loop in its own process with the real-time policy (SCHED_FIFO, mlockall, its own core) for
``--duration-s`` at ``--rate-hz``, optionally beside ``--load-cores`` busy processes, and prints the period
error histogram, p99 / p99.9 / max, overruns, the policy the OS granted and a verdict against the thresholds
(p99 <= 20 us, p99.9 <= 50 us, no period above 1 ms). Exit status 0 on PASS, 1 on FAIL.

The body; the parser is :mod:`renderer.cli_timing_check_parser`.
"""

from __future__ import annotations

import json

from plumbing.fileio import atomic_write_text, check_output_file

from .timing_check import format_report, run_check
from .timing_verdict import TimingThresholds


def run_command(args) -> int:
    """Run the check, print its report (and write ``--out``); 0 on PASS (or not judged), 1 on FAIL."""


    if args.out:
        check_output_file(args.out, args.force)
    th = TimingThresholds(period_error_p99_us=args.max_p99_us, period_error_p999_us=args.max_p999_us,
                          max_period_ms=args.max_period_ms)
    rec = run_check(duration_s=args.duration_s, rate_hz=args.rate_hz, load_cores=args.load_cores,
                    device=args.device, thresholds=th)
    print(format_report(rec))
    if args.out:
        atomic_write_text(args.out, json.dumps(rec, indent=2) + "\n")
        print(f"saved {args.out}")
    return 1 if rec["verdict"]["met"] is False else 0
