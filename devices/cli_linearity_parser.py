"""``python -m devices linearity``: is the device linear and time-invariant? (thesis sec. 3.4.3)

The parser (light: imported for ``--help``); the body is :mod:`devices.cli_linearity`.
"""

from __future__ import annotations


from plumbing.cliargs import add_renamed, float_list, with_examples
from plumbing.dispatch import Body


def register(subparsers) -> None:
    """Add the ``linearity`` command to ``python -m devices``."""
    p = subparsers.add_parser(
        "linearity", help="linearity and time-invariance report: ETFEs at several amplitudes, grips, positions",
        description="Measure handle-acceleration ETFEs (with coherence) at several current magnitudes, grips and "
                    "workspace positions, and the first condition again at the end; judge every pair of "
                    "conditions that differ in one factor (dB and degree distance, and over which band) and "
                    "conclude in plain language whether an LTI model suffices (sec. 3.4.3).")
    p.add_argument("--device", default="sim", help="device string (sim, sim:lti, serial:PORT, ...)")
    add_renamed(p, "--amplitudes-A", "--amplitudes", dest="amplitudes", type=float_list, default=None,
                   help="sweep amplitudes in A (default: 8, 40 and 95 %% of the continuous current)")
    add_renamed(p, "--grips-N", "--grips", dest="grips", type=float_list, default=(1.0, 2.0, 3.0),
                help="grips in N (default 1,2,3)")
    p.add_argument("--positions", type=float_list, default=(0.0, 0.02),
                   help="workspace positions in m, handle space (default 0,0.02)")
    add_renamed(p, "--band-hz", "--band", dest="band", type=float, nargs=2, default=(20.0, 500.0), metavar=("LO", "HI"),
                   help="judged band in Hz (default 20 500)")
    p.add_argument("--trials", type=int, default=2, help="trials per condition (coherence needs >= 2)")
    p.add_argument("--seed", type=int, default=0, help="sim noise seed")
    p.add_argument("--out", default=None, help="folder for linearity.txt, linearity.json and linearity.png")
    p.add_argument("--force", action="store_true", help="replace an existing report in --out")
    with_examples(p, "hfam-devices linearity --device sim --amplitudes-A 0.2,1 --grips-N 1,3 --band-hz 20 500 "
                     "--out lin/")
    p.set_defaults(func=Body('devices.cli_linearity', 'run_linearity'))

