"""``python -m devices identify`` (record + fit a grip-dependent model set) and ``python -m devices fit``
(fit a model offline from recordings); formats in docs/models.md.

The parser (light: imported for ``--help``); the body is :mod:`devices.cli_identify`.
"""

from __future__ import annotations

import argparse

from plumbing.cliargs import add_renamed, auto_or, float_list, with_examples
from plumbing.dispatch import Body


def _fit_options_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--order", type=auto_or("--order", int, "an integer"), default="auto", help="number of poles, or 'auto' (default): "
                   "chosen from the error-versus-order table")
    p.add_argument("--max-order", type=int, default=14, help="largest order tried by --order auto (default 14)")
    add_renamed(p, "--delay-s", "--delay", dest="delay", type=auto_or("--delay-s", float, "a number of seconds"), default="auto", help="pure delay in s, or 'auto' (default)")
    p.add_argument("--max-rms-db", type=float, default=3.0,
                   help="requested RMS magnitude error; a worse fit writes nothing (default 3 dB)")
    p.add_argument("--max-rms-phase-deg", type=float, default=20.0,
                   help="requested RMS phase error; a worse fit writes nothing (default 20 deg)")
    p.add_argument("--no-coherence-weight", action="store_true", help="do not weight bins by coherence")
    p.add_argument("--min-phase", action="store_true",
                   help="mirror right-half-plane zeros into the left half plane and re-fit the delay (models "
                        "meant for inversion, section 4.2.2); the reported errors include the change")
    p.add_argument("--detrend", choices=("ramp", "periodic"), default="ramp",
                   help="ETFE detrending: 'ramp' (thesis eq. 3.13-3.14, default) or 'periodic' (remove only the "
                        "drift between the two sweep copies; exact in the lowest bins)")


def register(subparsers) -> None:
    """Add the ``identify``, ``fit`` and ``validate``-family commands.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m devices`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "identify", help="identify a device: comprehensive evaluation (LTI model set) or successive isolation "
                         "(nonlinear physical model)",
        description="--method comprehensive (default, thesis sec. 3.4): play swept-sine current commands (eq. "
                    "3.11-3.12, twice back to back) while the user holds the handle at each grip level, estimate "
                    "ETFEs, fit stable zpk models with delay for handle acceleration and position, validate on "
                    "transients, and write recordings, one model JSON per grip and output, model_set.json, Bode "
                    "PNGs and a fit report into --out. --method successive (sec. 3.5): identify the nonlinear "
                    "model of eq. 3.32-3.35 stage by stage (amplifier, timing, motor, cables, drum, linkage "
                    "hysteresis, handle, user) in the mechanical configuration each stage needs (set directly on "
                    "the sim; the operator is prompted on hardware) and write model.json (a sim parameter file: "
                    "--device sim:DIR/model.json), report.txt/json and one figure per stage into --out.")
    p.add_argument("--method", choices=("comprehensive", "successive"), default="comprehensive",
                   help="comprehensive evaluation (LTI, default) or successive isolation (nonlinear)")
    p.add_argument("--device", default="sim", help="device string (sim, sim:lti, serial:PORT, hid:VID:PID)")
    add_renamed(p, "--grips-N", "--grip", dest="grip", type=float_list, default=None,
                   help="comma-separated grip levels in N (default: spans the device's grip range, "
                        "0,1,2,3,5,10 on the sim, so an HFAM library built from the set covers every grip)")
    p.add_argument("--trials", type=int, default=4, help="good trials per grip, half reversed (default 4)")
    add_renamed(p, "--amplitudes-A", "--amplitude", dest="amplitude", type=float_list, default=(0.75,),
                help="sweep amplitude(s) in A, comma-separated (default 0.75); several give one ETFE curve each, "
                     "combined by --purpose")
    p.add_argument("--purpose", choices=("hfam", "cimm", "general"), default="general",
                   help="fit rule (sec. 3.4.4): hfam fits the highest-magnitude curves (inverted model never "
                        "over-stimulates a resonance), cimm the lowest (never over-cancels), general the average; "
                        "stored in every model's fit.purpose")
    p.add_argument("--workers", type=int, default=None,
                   help="simulated devices: grips fitted in this many processes at once, beside one recording process "
                        "(default: the number of cores)")
    p.add_argument("--stages", default=None,
                   help="successive: comma-separated stages to run (default all: timing,amplifier,motor,cables,"
                        "drum,linkage,handle,user)")
    p.add_argument("--resume", action="store_true",
                   help="successive: skip the stages already done in --out (after an interruption)")
    p.add_argument("--no-figures", action="store_true", help="successive: do not draw the per-stage figures")
    add_renamed(p, "--f-start-hz", "--f-start", dest="f_start", type=float, default=5.0, help="sweep start frequency f_i in Hz (default 5)")
    add_renamed(p, "--f-end-hz", "--f-end", dest="f_end", type=float, default=1000.0, help="sweep end frequency f_f in Hz (default 1000)")
    add_renamed(p, "--duration-s", "--duration", dest="duration", type=float, default=2.0, help="one sweep's duration in s (default 2)")
    p.add_argument("--repetitions", type=int, default=2, help="sweep copies back to back (default 2)")
    add_renamed(p, "--band-hz", "--band", dest="band", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="fit band in Hz (default: 10 Hz to f_end, position limited by encoder resolution)")
    p.add_argument("--no-reverse", action="store_true",
                   help="do not reverse the sweep polarity for the second half of the trials")
    p.add_argument("--no-validate", action="store_true", help="skip the time-domain validation on transients")
    p.add_argument("--seed", type=int, default=0, help="sim noise seed")
    _fit_options_args(p)
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--force", action="store_true",
                   help="replace an earlier identification in --out (its models, recordings, plots and report are "
                        "replaced once the new run has succeeded, so old and new models never mix; a failed or "
                        "interrupted run leaves them as they were)")
    with_examples(p, 'hfam-devices identify --device sim --out ident/                  # grips 0,1,2,3,5,10 N', 'hfam-devices identify --device serial:/dev/ttyACM0 --grips-N 1,2,4 --trials 4 --out ident_hw/')
    p.set_defaults(func=Body('devices.cli_identify', 'run_identify'))

    q = subparsers.add_parser(
        "fit", help="fit a model to swept-sine recordings made anywhere",
        description="Fit a stable zpk model with pure delay to the ETFE of one or more recordings (CSV "
                    "t_s,current_A,accel_m_s2,position_m,grip_N plus a JSON sidecar of the same name). "
                    "Recordings with the same sidecar 'condition' (else the same grip to 0.5 N and amplitude) "
                    "are complex-averaged into one curve; several curves are combined by --weight.")
    q.add_argument("recordings", nargs="+", help="recording CSV files")
    q.add_argument("--output", choices=("accel_m_s2", "position_m"), default="accel_m_s2",
                   help="which output to model (default accel_m_s2, H_ha)")
    add_renamed(q, "--band-hz", "--band", dest="band", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="fit band in Hz (default: 10 Hz to the sweep's end, limited by quantization)")
    q.add_argument("--weight", choices=("high", "low", "mean"), default="mean",
                   help="combine several curves by their upper envelope (HFAM), lower envelope "
                        "(cancellation) or mean (default)")
    q.add_argument("--plot", default=None, help="also write a Bode PNG here")
    q.add_argument("--validate", nargs="+", default=(), metavar="TRANSIENTS.csv",
                   help="time-domain validation (section 3.4.5): simulate the model on the commanded current of "
                        "these recordings (columns t_s,current_A,<output>) and print the NRMSE against the measured "
                        "output (e.g. recordings/transients_g2N.csv written by identify)")
    _fit_options_args(q)
    q.add_argument("--out", required=True, help="model JSON to write")
    q.add_argument("--force", action="store_true", help="overwrite --out (and --plot) if they exist")
    with_examples(q, 'hfam-devices fit ident/recordings/g1N_t*.csv ident/recordings/g3N_t*.csv --weight high --out hfam_model.json')
    q.set_defaults(func=Body('devices.cli_identify', 'run_fit'))

