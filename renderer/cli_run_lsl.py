"""``python -m renderer run --lsl``: the run of :mod:`renderer.cli_run`, its servo's state (decimated to
``--lsl-rate-hz``), contacts and start and end published as Lab Streaming Layer streams (:mod:`plumbing.lsl`).

A body of its own (the parser's ``--lsl`` chooses it), so a run without ``--lsl`` never loads pylsl. Without
pylsl the run goes ahead without streams and says so in one warning line. The streams' record (their names,
the clock pair of the run's start, the counts) goes into ``run.json`` under ``timing.lsl``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from plumbing.lsl import ServoStream, open_publisher

from . import cli_run


def run_command(args) -> int:
    """``renderer run`` with its streams; returns the exit code."""
    if not 0 < args.lsl_rate_hz <= 100_000:
        raise ValueError(f"--lsl-rate-hz must be in (0, 100000] Hz, got {args.lsl_rate_hz}")
    name = Path(args.out).name or "run"
    publisher, why = open_publisher(f"hfam renderer {name}", f"hfam-renderer-{name}", args.lsl_rate_hz)
    if publisher is None:
        print(f"warning: --lsl: the run goes ahead without Lab Streaming Layer streams: {why}", file=sys.stderr)
    else:
        args.servo_stream = ServoStream(publisher)
    try:
        return cli_run.run_command(args)
    finally:
        if publisher is not None:
            publisher.close()
