"""``python -m devices firmware-report`` (timing of the real firmware on simavr) and ``python -m devices fw-sim``."""

from __future__ import annotations

import json
import signal
import sys
import threading

from devices.firmware import fw_sim


def run_report(args) -> int:
    """Build, run and print the timing report (see :func:`devices.firmware.fw_sim.timing_report`)."""

    if args.decimation < 1:
        raise ValueError(f"--decimation must be >= 1, got {args.decimation}")
    try:
        report = fw_sim.timing_report(args.speeds, args.decimation)
    except fw_sim.FwSimError as exc:
        raise ValueError(str(exc)) from None
    print(json.dumps(report, indent=1) if args.json else fw_sim.format_report(report))
    return 0


def run_fw_sim(args) -> int:
    """Start the harness, print its port, wait for Ctrl-C / SIGTERM, print the final timing numbers."""

    taps = tuple(float(v) for v in args.taps.split(",") if v.strip()) if args.taps else ()
    try:
        port, handle = fw_sim.start_fw_sim(args.pace, args.speed, taps, faults=args.fault,
                                           lockstep_ticks=args.lockstep_ticks)
    except fw_sim.FwSimError as exc:
        raise ValueError(str(exc)) from None
    print(f"PORT {port}", flush=True)
    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        while not stop.wait(0.2) and handle.alive:
            pass
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)  # a caller in this process keeps its own SIGTERM handling
    stats = handle.stop()
    print(f"simulated {stats.get('sim_time_s', 0):.2f} s; servo tick cycles {stats.get('tick_cycles')}",
          file=sys.stderr)
    return 0
