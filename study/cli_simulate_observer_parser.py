"""``python -m study simulate-observer``: an adaptive method against a simulated observer (planning).

Runs ``--method`` against an observer with the given threshold (and slope, lapse, alternatives) and writes
into ``--out``: ``estimate.json`` (threshold and the rest of the method's estimate, the truth it is compared
with, the settings), ``trials.csv`` (the track: trial, intensity, correct, reversal) and ``staircase.png``
(the track with its reversals). With ``--repeat R``, R runs (seeds SEED .. SEED+R-1) answer how many trials
the method needs for a precision: ``precision.csv``/``precision.png`` (error after every 10 trials) and
``runs.csv``. Only the threshold is required; docs/psychophysics.md lists the defaults.
"""

from __future__ import annotations

import argparse

from plumbing.cliargs import with_examples
from plumbing.dispatch import Body
from psychophysics.names import METHOD_NAMES


def register(subparsers) -> None:
    """Add the ``simulate-observer`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m study`` sub-command parsers.
    """
    p = subparsers.add_parser("simulate-observer", help="run an adaptive method against a simulated observer",
                              description=__doc__.replace("``", ""), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--method", required=True, choices=METHOD_NAMES,
                   help="updown (1-up-2-down), weighted (Kaernbach), quest+ (Watson) or psi (Kontsevich & Tyler)")
    p.add_argument("--threshold", type=float, required=True,
                   help="the observer's threshold (Weibull F = 0.5), in stimulus units (> 0)")
    p.add_argument("--slope", type=float, default=3.5, help="the observer's Weibull slope (default 3.5)")
    p.add_argument("--lapse", type=float, default=0.02, help="lapse rate in [0, 0.5) (default 0.02)")
    p.add_argument("--alternatives", type=int, default=2, help="n of the n-AFC task, guess rate 1/n (default 2)")
    p.add_argument("--trials", type=int, default=80, help="trials per run (default 80)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first run (default 0)")
    p.add_argument("--repeat", type=int, default=1,
                   help="runs (seeds SEED..SEED+R-1); > 1 writes precision vs trials (default 1)")
    p.add_argument("--intensity-min", type=float, default=None,
                   help="lowest stimulus intensity (default threshold / 10)")
    p.add_argument("--intensity-max", type=float, default=None,
                   help="highest stimulus intensity (default 10 x threshold)")
    p.add_argument("--out", required=True, help="output folder (new or empty, or use --force)")
    p.add_argument("--force", action="store_true", help="write into a non-empty --out, replacing its files")
    with_examples(p, "python -m study simulate-observer --method quest+ --threshold 0.5 --out SIM",
                  "python -m study simulate-observer --method updown --threshold 120 --slope 2.5 --trials 60 "
                  "--repeat 200 --out PLAN")
    p.set_defaults(func=Body("study.cli_simulate_observer", "run"))
