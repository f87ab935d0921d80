"""``python -m devices firmware-report`` (timing of the real firmware on simavr) and ``python -m devices fw-sim``.

The parser (light: imported for ``--help``); the body is :mod:`devices.cli_firmware`.
"""

from __future__ import annotations

from plumbing.cliargs import positive_numbers, with_examples
from plumbing.dispatch import Body


def register(subparsers) -> None:
    """Add the ``firmware-report`` and ``fw-sim`` commands.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m devices`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "firmware-report", help="timing of the real AVR firmware on simavr (tick cycles, ISRs, RAM, encoder)",
        description="Build the firmware (avr-gcc) and the simavr harness (cc), run the worst case (on-device "
                    "rendering of a decaying sinusoid, telemetry every 2nd tick, host re-arm uploads, the paddle swept "
                    "at the given speeds) on a simulated ATmega328P at 16 MHz, and print cycles per servo tick "
                    "against the 4,000-cycle budget, interrupt worst cases, RAM high-water (stack painting) and "
                    "encoder counts missed per speed.")
    p.add_argument("--speeds", type=positive_numbers("speeds", "m/s", items="speeds in m/s"), default=[0.1, 0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0],
                   help="paddle speeds to sweep, m/s (default 0.1,...,6)")
    p.add_argument("--decimation", type=int, default=2,
                   help="telemetry every N servo ticks (default 2: a STATE every 250 us tick needs 92 %% of the "
                        "1 Mbaud link; with 1 the report shows the frames the link could not carry)")
    p.add_argument("--json", action="store_true", help="print the numbers as JSON")
    with_examples(p, "hfam-devices firmware-report", "hfam-devices firmware-report --speeds 0.5,4 --json")
    p.set_defaults(func=Body('devices.cli_firmware', 'run_report'))

    q = subparsers.add_parser(
        "fw-sim", help="run the real firmware on simavr behind a pty (connect with serial:<pty>)",
        description="Print 'PORT <pty>' and run the AVR firmware on a simulated ATmega328P whose paddle a "
                    "simulated hand taps; a host connects with serial:<pty>. Stop with Ctrl-C / SIGTERM.")
    q.add_argument("--pace", choices=("lockstep", "realtime", "fast"), default="lockstep",
                   help="lockstep (default: the MCU runs one host period per host frame and the host paces on its "
                        "clock, so a slow simulator never trips a watchdog), realtime (on the wall clock; "
                        "slower than real time on a loaded machine), or fast (as fast as the host reads telemetry)")
    q.add_argument("--lockstep-ticks", type=int, default=4,
                   help="lockstep: 250 us servo ticks per host period, 2..255 (default 4: a 1 kHz streaming loop)")
    q.add_argument("--speed", type=float, default=1.0, help="realtime pace: times real time (default 1)")
    q.add_argument("--taps", default="0.05,0.1,0.2", help="tap speeds, m/s, cycled ('' : hold at 10 mm)")
    q.add_argument("--fault", default=None, help="device->host faults: drop=P,corrupt=P,garbage=P,duplicate=P,"
                                                 "disconnect_after_s=T")
    with_examples(q, "hfam-devices fw-sim --taps 0.05,0.1   # prints PORT /dev/pts/N",
                  "hfam-renderer run --device serial:/dev/pts/N --duration-s 10 --out runs/fw")
    q.set_defaults(func=Body('devices.cli_firmware', 'run_fw_sim'))

