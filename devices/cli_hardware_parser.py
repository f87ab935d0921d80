"""``python -m devices emulate`` (firmware emulator on a pty) and ``python -m devices latency``.

The parser (light: imported for ``--help``); the body is :mod:`devices.cli_hardware`.
"""

from __future__ import annotations

from plumbing.cliargs import positive_numbers, with_examples
from plumbing.dispatch import Body


def register(subparsers) -> None:
    """Add the ``emulate`` and ``latency`` commands.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m devices`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "emulate", help="firmware emulator on a pseudo-terminal (speaks docs/protocol.md, sim physics)",
        description="Open a pty pair, print 'PORT <slave path>', and emulate the reference firmware on it, "
                    "driven by the simulated device's physics. Stop with Ctrl-C / SIGTERM.")
    p.add_argument("--pty", action="store_true", help="use a pseudo-terminal pair (the only transport; default)")
    p.add_argument("--mode", choices=("streaming", "on-device"), default="streaming",
                   help="streaming: host commands every tick; on-device: also offers on-board rendering")
    p.add_argument("--fault", default="", metavar="SPEC",
                   help="fault injection, e.g. drop=0.01,corrupt=0.01,delay=0.01,delay_s=0.005,duplicate=0.01,"
                        "garbage=0.01,disconnect_after_s=5,silent=1,protocol_major=2; a broken device: "
                        "bad_length_every=100, bad_type_every=100, clock_back_at=N, clock_freeze_at=N, "
                        "info_servo_rate_hz=1e9, stall_at=N,stall_s=0.05 (devices.firmware.emulator.FaultSpec)")
    p.add_argument("--watchdog-ms", type=int, default=100, help="device watchdog period (default 100 ms)")
    p.add_argument("--pace", choices=("realtime", "host"), default="realtime",
                   help="on-device tick pacing: wall clock, or as fast as the host reads telemetry")
    p.add_argument("--sim", default=None, help="sim parameters: omitted (Table 3.1), 'lti', or a TOML/JSON file")
    p.add_argument("--taps", type=positive_numbers("tap velocities", "m/s", none=True), default=[0.05, 0.1, 0.2],
                   help="velocities (m/s) the simulated hand taps with, cycled forever (default 0.05,0.1,0.2); "
                        "'none': the hand holds the handle still 1 cm above the surface (identify, calibration)")
    p.add_argument("--grip-N", type=float, default=2.0, help="simulated grip force (N)")
    p.add_argument("--sample", default="placeholder", help="real sample under the stylus (sim sample name)")
    p.add_argument("--rate-hz", type=float, default=None,
                   help="firmware servo rate (default: 1000 in streaming mode, the sim's 10000 on-device)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--t0-us", type=int, default=0, help="device clock at power-up (us), e.g. near 2**32 to test wrap")
    p.add_argument("--duration-s", type=float, default=None, help="exit after this long (default: run until killed)")
    p.add_argument("--rt-priority", type=int, default=None, metavar="N",
                   help="run under SCHED_FIFO priority N (1-99; needs root or CAP_SYS_NICE), as a firmware would")
    with_examples(p, 'hfam-devices emulate --pty --mode on-device        # prints PORT /dev/pts/N')
    p.set_defaults(func=Body('devices.cli_hardware', 'run_emulate'))

    q = subparsers.add_parser(
        "latency", help="measure command->state round trip and achieved update rate of a device",
        description="Stream N zero-current commands (each answered by a state frame) as fast as the link allows "
                    "and report round-trip percentiles and the achieved rate; then N pings (no physics).")
    q.add_argument("--device", required=True, help="device string, e.g. serial:/dev/ttyACM0 or hid:16c0:0486")
    q.add_argument("--n", type=int, default=2000, help="number of round trips (default 2000)")
    q.add_argument("--warmup", type=int, default=100)
    q.add_argument("--rt-priority", type=int, default=None, metavar="N",
                   help="measure under SCHED_FIFO priority N (1-99; needs root or CAP_SYS_NICE)")
    with_examples(q, 'hfam-devices latency --device serial:/dev/pts/3 --n 2000')
    q.set_defaults(func=Body('devices.cli_hardware', 'run_latency'))

