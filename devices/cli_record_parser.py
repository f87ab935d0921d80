"""``python -m devices record``: tap a (simulated) real sample and save reference handle accelerations.

The parser (light: imported for ``--help``); the body is :mod:`devices.cli_record`.
"""

from __future__ import annotations

from plumbing.cliargs import add_renamed, with_examples
from plumbing.dispatch import Body


def register(subparsers) -> None:
    """Add the ``record`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m devices`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "record", help="tap a sample and record 100 ms of handle acceleration per tap (CSV)",
        description="Tap a sample once per velocity with the motor unpowered and save the handle acceleration "
                    "around each impact, at the servo rate, as a long-format CSV "
                    "(tap, incoming_velocity_m_s, t_s, accel_m_s2; t_s relative to impact). "
                    "With a simulated device the simulated hand taps the simulated sample; the impact is the "
                    "first servo tick in contact (true state) and the incoming velocity is measured from the "
                    "encoder over the 5 ms before impact.")
    p.add_argument("--device", default="sim", help="device string: sim, sim:lti, sim:<params file>, serial:<port>, "
                                                  "hid:<vid>:<pid> (default sim)")
    p.add_argument("--sample", default="wood_on_foam",
                   help="simulated sample under the stylus: wood, wood_on_foam, foam, placeholder (sim only)")
    add_renamed(p, "--velocities-m-s", "--velocities", dest="velocities", required=True, help="comma-separated tap speeds in m/s, e.g. 0.05,0.1,0.2")
    add_renamed(p, "--grip-N", "--grip", dest="grip", type=float, default=2.0, help="simulated grip force in N (default 2)")
    p.add_argument("--window-s", type=float, default=0.1, help="capture length per tap in s (default 0.1)")
    p.add_argument("--pre-s", type=float, default=0.005, help="capture before impact in s (default 0.005)")
    p.add_argument("--seed", type=int, default=0, help="sensor-noise seed of the simulated device")
    p.add_argument("--out", required=True, help="output CSV file")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    with_examples(p, 'hfam-devices record --device sim --sample wood_on_foam --velocities-m-s 0.05,0.1,0.2 --grip-N 2 --out taps.csv')
    p.set_defaults(func=Body('devices.cli_record', 'run'))

