"""``python -m devices validate MODEL``: check an identified model against the device (thesis sec. 3.4.5):
ETFE agreement at several current magnitudes and the held-handle response to contact-like transients.

The parser (light: imported for ``--help``); the body is :mod:`devices.cli_validate`.
"""

from __future__ import annotations


from plumbing.cliargs import add_renamed, float_list, with_examples
from plumbing.dispatch import Body


def register(subparsers) -> None:
    """Add the ``validate`` command to ``python -m devices``."""
    p = subparsers.add_parser(
        "validate", help="validate an identified model against the device (ETFEs, held transients)",
        description="MODEL is a nonlinear model file from 'identify --method successive' (model.json, a sim "
                    "parameter file), a zpk model JSON from comprehensive evaluation, or a folder holding either "
                    "(model.json or the accel model nearest --grip-N of model_set.json). Plays contact-like "
                    "transients while the (simulated) user holds at --grip-N and reports the normalized RMS error "
                    "of the model's predicted handle acceleration per transient; for a nonlinear model also "
                    "compares the ETFEs of device and model at each --amplitudes-A (20-500 Hz).")
    p.add_argument("model", help="model.json (nonlinear), a zpk JSON, or a model folder")
    p.add_argument("--device", default="sim", help="device string of the device to validate against")
    add_renamed(p, "--grip-N", "--grip", dest="grip", type=float, default=2.0,
                help="grip of the holding user in N (default 2)")
    add_renamed(p, "--amplitude-A", "--amplitude", dest="amplitude", type=float, default=1.0,
                help="transient amplitude in A (default 1)")
    add_renamed(p, "--amplitudes-A", "--amplitudes", dest="amplitudes", type=float_list, default=(0.2, 0.75, 1.25),
                   help="sweep amplitudes for the ETFE comparison (nonlinear models; default 0.2,0.75,1.25)")
    p.add_argument("--seed", type=int, default=0, help="sim noise seed")
    p.add_argument("--plot", default=None, help="write the time-domain figure (Figure 3.10 style) here")
    p.add_argument("--force", action="store_true", help="overwrite --plot if it exists")
    with_examples(p, "hfam-devices validate ident/ --device sim --grip-N 2 --plot td.png",
                  "hfam-devices validate model.json --amplitudes-A 0.2,0.75 --grip-N 3")
    p.set_defaults(func=Body('devices.cli_validate', 'run_validate'))

