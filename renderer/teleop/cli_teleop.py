"""``python -m renderer teleop`` / ``teleop-sweep`` / ``teleop-servo-study``: the argument parsers, light enough for a fast ``--help``.

The commands themselves are in :mod:`renderer.teleop.commands` (named as a ``plumbing.dispatch.Body``,
imported when one runs): it needs the numba-compiled testbed (``devices.sim``), ~0.3 s to import. The choice lists below are
the testbed's and the controllers' names, kept here as plain tuples (a test checks they match).
"""

from __future__ import annotations

from plumbing.cliargs import add_renamed, with_examples
from plumbing.dispatch import Body

from .options import (CONTROLLER_NAMES, ENVIRONMENT_NAMES, SERVO_BANDWIDTH_HZ,  # noqa: F401
                      SLAVE_HANDLE_DAMPING_N_S_M, SWEEP_CONDITIONS, parse_lambdas)


def _add_common(p) -> None:
    p.add_argument("--mu", type=float, default=1.0, help="position scale mu (default 1)")
    p.add_argument("--environment", default="hard", choices=ENVIRONMENT_NAMES,
                   help="the slave's environment (default hard)")
    p.add_argument("--rate-hz", type=float, default=5000.0, help="servo rate (default 5000, as the thesis)")
    p.add_argument("--cimm-model", default=None, help="parameter file of the identified master (default: the simulated "
                   "master identified by successive isolation, section 3.5, cached; 'linear-linkage': that model "
                   "with its linkage made linear, Figure 5.11's simpler model; 'stand-in': marked Table 3.1 "
                   "parameters with 5-20 %% errors)")
    p.add_argument("--washout-hz", type=float, default=0.0, help="high-pass on the CIMM model output (0: off)")
    p.add_argument("--backlash-mm", type=float, default=0.0,
                   help="free play in both transmissions, motor to drum, mm at the handle (Figure 5.11's "
                        "uncorrected backlash: 0.1; default 0, Figure 5.10's corrected testbed)")
    p.add_argument("--servo-bandwidth-hz", type=float, default=SERVO_BANDWIDTH_HZ,
                   help=f"natural frequency of the servo-gain rule (damping ratio 0.7 on the joystick's moving "
                        f"mass; default {SERVO_BANDWIDTH_HZ:g}: the user's motion-control bandwidth, 81.5 N/m and "
                        f"2.27 N s/m)")
    p.add_argument("--slave-handle-damping-N-s-m", dest="slave_handle_damping", type=float,
                   default=SLAVE_HANDLE_DAMPING_N_S_M,
                   help=f"viscous damping between the slave's unheld handle and its linkage, N s/m (default "
                        f"{SLAVE_HANDLE_DAMPING_N_S_M:g}: calibrated so that the slave's natural impact settles "
                        f"in 40 ms, below Figure 5.10's lambda = 1 value; 0: Table 3.1 as identified, with the "
                        f"handle held)")
    p.add_argument("--out", required=True, help="output folder (must not exist or be empty)")


def register(sub) -> None:
    """Add the ``teleop``, ``teleop-sweep`` and ``teleop-servo-study`` commands.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The ``python -m renderer`` sub-command parsers.
    """
    p = sub.add_parser("teleop", help="run a simulated teleoperation session (thesis ch. 5)")
    p.add_argument("--controller", default="pf", choices=CONTROLLER_NAMES,
                   help="the teleoperation controller (thesis ch. 5; default pf: position-force)")
    p.add_argument("--lambda", dest="lam", type=float, default=1.0, help="force-feedback gain lambda")
    p.add_argument("--taps", type=int, default=10, help="taps of the simulated operator (default 10)")
    add_renamed(p, "--b-N-s-m", "--b", dest="b", type=float, default=0.0, help="master damping b, N s/m (eq. 5.9)")
    add_renamed(p, "--speed-m-s", "--speed", dest="speed", type=float, default=0.1,
                help="incoming tap speed of the slave, m/s (default 0.1)")
    p.add_argument("--k-mu-hz", type=float, default=None,
                   help="position-command low-pass K_mu (eq. 5.10), Hz; default 0 (off; section 4.3.1's pd+hfam has "
                        "none)")
    p.add_argument("--master-pd-lowpass-hz", type=float, default=None,
                   help="pd, pd+hfam: low-pass on the master's PD force, Hz; default 0 (off; section 4.3.1's pd+hfam "
                        "has none)")
    p.add_argument("--k-lambda-hz", type=float, default=0.0, help="force-feedback low-pass K_lambda (eq. 5.11)")
    p.add_argument("--no-figures", action="store_true", help="write the data only, no figures")
    p.add_argument("--hha-model", default=None, help="H_ha model file for pd+hfam (default: identify the master)")
    add_renamed(p, "--hfam-max-current-A", "--hfam-max-current", dest="hfam_max_current", type=float, default=4.0,
                help="saturation of the HFAM channel, A (default 4)")
    p.add_argument("--master", default="sim",
                   help="the master: sim (simulated master and operator, default) or a device string such as "
                        "serial:/dev/ttyACM0 (a real master streaming over the serial link; the slave and the "
                        "environment stay simulated, the servo rate is the master's; pf and pf+cimm only)")
    p.add_argument("--duration-s", type=float, default=10.0,
                   help="with --master DEVICE: session length in s (default 10); the simulated operator's "
                        "session lasts as long as its --taps")
    _add_common(p)
    with_examples(p, "hfam-renderer teleop --controller pf+cimm --lambda 4 --taps 5 --speed-m-s 0.12 --out teleop/",
                  "hfam-renderer teleop --controller pf --lambda 3 --slave-handle-damping-N-s-m 0 --out teleop_table31/",
                  "hfam-renderer teleop --controller pd+hfam --environment wood --taps 3 --out teleop_hfam/",
                  "hfam-renderer teleop --controller pf --master serial:/dev/ttyACM0 --duration-s 10 --out teleop_hw/")
    p.set_defaults(func=Body("renderer.teleop.commands", "run_teleop"))
    q = sub.add_parser("teleop-sweep", help="lambda sweep with/without cancellation and stabilisers (Fig. 5.11)")
    q.add_argument("--lambda", dest="lam", default="1:15", help="lambda values: a:b, a:b:step or a,b,c")
    q.add_argument("--taps", type=int, default=2, help="taps per condition and lambda (speeds 0.08-0.12 m/s)")
    q.add_argument("--conditions", default=",".join(SWEEP_CONDITIONS),
                   help=f"comma list of {', '.join(SWEEP_CONDITIONS)}")
    q.add_argument("--seed", type=int, default=1, help="seed of the blind randomisation")
    q.add_argument("--robustness", action="store_true",
                   help="also the CIMM table with +/-30 %% error in user stiffness and hand mass")
    q.add_argument("--press-depth-mm", default=None, metavar="LIST",
                   help="comma list of how far below the surface the operator presses, mm (default 2; the thesis "
                        "gives none: e.g. 2,3,4)")
    q.add_argument("--lambda-by-speed", action="store_true",
                   help="Figure 5.11's protocol: each lambda's taps come in at a speed inversely proportional to "
                        "lambda, the feedback's peak held at the device's limit (default: 0.08-0.12 m/s at every "
                        "lambda)")
    _add_common(q)
    with_examples(q, "hfam-renderer teleop-sweep --lambda 0.25,0.5,1,1.5,2,3,4,6,8,10,15 --taps 2 --out sweep/",
                  "hfam-renderer teleop-sweep --lambda 1,3,6,10 --conditions pf,pf+cimm --servo-bandwidth-hz 12 "
                  "--out sweep_12hz/",
                  "hfam-renderer teleop-sweep --lambda 1,4,8 --conditions pf,pf+cimm --robustness --out sweep/",
                  "hfam-renderer teleop-sweep --lambda 1:6 --conditions pf,pf+cimm --backlash-mm 0.1 --lambda-by-speed "
                  "--cimm-model linear-linkage --out sweep_fig511/",
                  "hfam-renderer teleop-sweep --lambda 0,1,3,6,10,15 --conditions pf,pf+cimm --press-depth-mm 2,3,4 "
                  "--out sweep_press/")
    q.set_defaults(func=Body("renderer.teleop.commands", "run_sweep"))
    r = sub.add_parser("teleop-servo-study",
                       help="section 5.7's targets at each servo bandwidth, slave handle re-identified at each")
    r.add_argument("--servo-bandwidth-hz", default="6,8,10,12.6,16,20,22",
                   help="comma list of natural frequencies of the servo-gain rule, Hz (default 6,8,10,12.6,16,20,22: "
                        "the rule's 8, the 8-10 Hz of human motion, up to section 4.3.1's 22 Hz slave PD)")
    r.add_argument("--taps", type=int, default=2, help="taps per condition and lambda (speeds 0.08-0.12 m/s)")
    r.add_argument("--seed", type=int, default=1, help="seed of the sweeps' blind randomisation")
    r.add_argument("--fixed-slave-handle-damping-N-s-m", dest="fixed_slave_handle_damping", type=float, default=None,
                   help="hold the slave handle's damping at this value, N s/m (default: re-identify it on the "
                        "natural impact at every bandwidth)")
    r.add_argument("--count-from-impact", action="store_true",
                   help="classify counting every contact loss from the impact on, the slave's own bounce included "
                        "(default: only the losses later than 30 ms after the impact)")
    r.add_argument("--cimm-model", default=None, help="parameter file of the identified master (default: the "
                   "simulated master identified by successive isolation, cached; 'stand-in': marked Table 3.1)")
    r.add_argument("--washout-hz", type=float, default=0.0, help="high-pass on the CIMM model output (0: off)")
    r.add_argument("--out", required=True, help="output folder (must not exist or be empty)")
    with_examples(r, "hfam-renderer teleop-servo-study --out servo_study/",
                  "hfam-renderer teleop-servo-study --servo-bandwidth-hz 8,16 --fixed-slave-handle-damping-N-s-m 1.8 "
                  "--out servo_study_fixed/")
    r.set_defaults(func=Body("renderer.teleop.servo_study", "run_servo_study"))

