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

#: the methods (kept here, not imported: the parser loads no numpy or scipy)
METHOD_NAMES = ("updown", "weighted", "quest+", "psi")
#: what the command writes (replaced with --force)
PRODUCTS = ("estimate.json", "trials.csv", "runs.csv", "precision.csv", "precision.png", "precision.svg",
            "precision.plot.csv", "staircase.png", "staircase.svg", "staircase.plot.csv")


def run(args: argparse.Namespace) -> int:
    """The ``simulate-observer`` command; returns the exit code."""
    from plumbing.fileio import check_output_dir, clear_products  # deferred: keeps `--help` light
    from study.simulate import SimulationSettings, simulate, write_results  # deferred: numpy/scipy/matplotlib

    settings = SimulationSettings(method=args.method, threshold=args.threshold, slope=args.slope,
                                  lapse=args.lapse, alternatives=args.alternatives, trials=args.trials,
                                  seed=args.seed, repeat=args.repeat, intensity_min=args.intensity_min,
                                  intensity_max=args.intensity_max)
    out = check_output_dir(args.out, args.force)
    if args.force and out.is_dir():  # an earlier run's precision files must not sit beside a new single run
        clear_products(out, PRODUCTS)
    result = simulate(settings)
    write_results(result, out)
    est = result["first"]["estimate"]
    print(f"{settings.method}: threshold estimate {est['threshold']:.4g} after {result['first']['method'].trials} "
          f"trials (true {result['reference']:.4g}); wrote {out}")
    if settings.repeat > 1:
        last = result["precision"][-1]
        print(f"{settings.repeat} runs: median |error| {last['median_abs_error_pct']:.1f} %, 90th percentile "
              f"{last['p90_abs_error_pct']:.1f} %, within 20 %: {100 * last['within_20pct']:.0f} % of runs")
    return 0


def register(subparsers) -> None:
    """Add the ``simulate-observer`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m study`` sub-command parsers.
    """
    p = subparsers.add_parser("simulate-observer", help="run an adaptive method against a simulated observer",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
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
    p.set_defaults(func=run)
