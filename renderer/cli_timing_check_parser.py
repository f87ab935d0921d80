"""``python -m renderer timing-check``: check this machine's servo timing as the loop would run.

Runs the servo loop in its own process with the real-time policy (SCHED_FIFO, mlockall, its own core) for
``--duration-s`` at ``--rate-hz``, optionally beside ``--load-cores`` busy processes, and prints the period
error histogram, p99 / p99.9 / max, overruns, the policy the OS granted and a verdict against the thresholds
(p99 <= 20 us, p99.9 <= 50 us, no period above 1 ms). Exit status 0 on PASS, 1 on FAIL.

The parser (light: imported for ``--help``); the body is :mod:`renderer.cli_timing_check`.
"""

from __future__ import annotations

from plumbing.cliargs import integer, positive, with_examples
from plumbing.dispatch import Body


def register(subparsers) -> None:
    """Add the ``timing-check`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m renderer`` sub-command parsers.
    """
    p = subparsers.add_parser("timing-check", help="check this machine's servo timing (cyclictest-like)",
                              description=__doc__.split("\n\n")[1].replace("\n", " ").replace("``", ""))
    p.add_argument("--duration-s", type=positive("--duration-s"), default=30.0, help="length of the check in s (default 30)")
    p.add_argument("--rate-hz", type=positive("--rate-hz"), default=10000.0, help="servo rate in Hz (default 10000)")
    p.add_argument("--load-cores", type=integer("--load-cores", 0, 64), default=0,
                   help="busy-looping processes to run beside the loop, the worst case of a busy PC (default 0)")
    p.add_argument("--device", default="quiet",
                   help="quiet (default: the loop alone) or a device string such as serial:/dev/ttyACM0 (motor "
                        "off, zero current; the link's round trip and gaps join the verdict)")
    p.add_argument("--max-p99-us", type=positive("--max-p99-us"), default=20.0,
                   help="threshold: period error p99 in us (default 20)")
    p.add_argument("--max-p999-us", type=positive("--max-p999-us"), default=50.0,
                   help="threshold: period error p99.9 in us (default 50)")
    p.add_argument("--max-period-ms", type=positive("--max-period-ms"), default=1.0,
                   help="threshold: longest period in ms (default 1; at least two nominal periods)")
    p.add_argument("--out", help="also write the check's numbers (period-error histogram, p99, p99.9, max, "
                                     "overruns, the policy granted) and its verdict to this JSON file; no plot is drawn")
    p.add_argument("--force", action="store_true", help="replace --out if it exists")
    with_examples(p, "hfam-renderer timing-check --duration-s 10",
                  "hfam-renderer timing-check --duration-s 30 --rate-hz 10000 --load-cores 2 --out timing.json")
    p.set_defaults(func=Body('renderer.cli_timing_check', 'run_command'))
