"""``python -m renderer timing-check``: check this machine's servo timing as the loop would run.

Runs the servo loop in its own process with the real-time policy (SCHED_FIFO, mlockall, its own core) for
``--duration-s`` at ``--rate-hz``, optionally beside ``--load-cores`` busy processes, and prints the period
error histogram, p99 / p99.9 / max, overruns, the policy the OS granted and a verdict against the thresholds
(p99 <= 20 us, p99.9 <= 50 us, no period above 1 ms). Exit status 0 on PASS, 1 on FAIL.

The body; the parser is :mod:`renderer.cli_timing_check_parser`.
"""

from __future__ import annotations

import json

from plumbing.fileio import atomic_write_text
from plumbing.outdir import output_file

from .timing_check import check_size, format_report, run_check
from .timing_verdict import TimingThresholds


def is_timing_record(path) -> bool:
    """Whether the file ``path`` is a check's record (what ``--out`` writes): ``--force`` replaces only those."""
    try:
        rec = json.loads(open(path, encoding="utf-8").read(1 << 22))
    except (OSError, ValueError, UnicodeDecodeError, RecursionError):
        return False
    return isinstance(rec, dict) and {"figures", "verdict", "stop_reason"} <= set(rec)


def run_command(args) -> int:
    """Run the check, print its report (and write ``--out``); 0 on PASS (or not judged), 1 on FAIL.

    ``--out`` is written beside and renamed into place once the check has its verdict, one writer at a time
    (:func:`plumbing.outdir.output_file`): Ctrl-C or SIGTERM during the check leaves an earlier record as it
    was (an interrupted check has no verdict), and ``--force`` replaces only an earlier check's record.
    """
    check_size(args.duration_s, args.rate_hz, args.load_cores)
    th = TimingThresholds(period_error_p99_us=args.max_p99_us, period_error_p999_us=args.max_p999_us,
                          max_period_ms=args.max_period_ms)
    if not args.out:
        rec = run_check(duration_s=args.duration_s, rate_hz=args.rate_hz, load_cores=args.load_cores,
                        device=args.device, thresholds=th)
        print(format_report(rec))
        return 1 if rec["verdict"]["met"] is False else 0
    with output_file(args.out, args.force, own=is_timing_record, results="a timing-check record") as out:
        rec = run_check(duration_s=args.duration_s, rate_hz=args.rate_hz, load_cores=args.load_cores,
                        device=args.device, thresholds=th)
        atomic_write_text(out.path, json.dumps(rec, indent=2) + "\n")   # fsynced before it is renamed into place
    print(format_report(rec))
    print(f"saved {args.out}")
    return 1 if rec["verdict"]["met"] is False else 0
