"""``python -m study simulate-observer``: an adaptive method against a simulated observer (planning).

Runs ``--method`` against an observer with the given threshold (and slope, lapse, alternatives) and writes
into ``--out``: ``estimate.json`` (threshold and the rest of the method's estimate, the truth it is compared
with, the settings), ``trials.csv`` (the track: trial, intensity, correct, reversal) and ``staircase.png``
(the track with its reversals). With ``--repeat R``, R runs (seeds SEED .. SEED+R-1) answer how many trials
the method needs for a precision: ``precision.csv``/``precision.png`` (error after every 10 trials) and
``runs.csv``. Only the threshold is required; docs/psychophysics.md lists the defaults.

The body; the parser is :mod:`study.cli_simulate_observer_parser`.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
from pathlib import Path

from plumbing.fileio import atomic_write_text
from plumbing.outdir import output_folder
from plumbing.textsafe import csv_dict, csv_header
from psychophysics.simulate import SimulationSettings, estimate_record, simulate

from .observer_figures import plot_precision, plot_track

#: what the command writes (a folder of these alone, without the output marker, was written by an older version
#: and is replaced by --force)
PRODUCTS = ("estimate.json", "trials.csv", "runs.csv", "precision.csv", "precision.png", "precision.svg",
            "precision.plot.csv", "staircase.png", "staircase.svg", "staircase.plot.csv")


def run(args: argparse.Namespace) -> int:
    """The ``simulate-observer`` command; returns the exit code."""

    settings = SimulationSettings(method=args.method, threshold=args.threshold, slope=args.slope,
                                  lapse=args.lapse, alternatives=args.alternatives, trials=args.trials,
                                  seed=args.seed, repeat=args.repeat, intensity_min=args.intensity_min,
                                  intensity_max=args.intensity_max)
    # written beside --out and swapped in whole, one writer at a time (plumbing.outdir): an interrupted run
    # leaves the earlier results as they were, and an earlier run's precision files never sit beside a new
    # single run's; a study's data is refused as --out whatever --force
    folder = output_folder(args.out, args.force, command="study simulate-observer", own=PRODUCTS).open()
    with folder:
        result = simulate(settings)
        write_results(result, folder.path)
    out = folder.out
    est = result["first"]["estimate"]
    method = result["first"]["method"]
    # an up-down staircase converges on the intensity of its target probability (70.7 % for 2-down 1-up),
    # not on the psychometric threshold: say which point the truth is
    target = getattr(method, "target_probability", None)
    truth = (f"true {100 * target():.1f} % correct point {result['reference']:.4g}" if callable(target)
             else f"true threshold {result['reference']:.4g}")
    print(f"{settings.method}: threshold estimate {est['threshold']:.4g} after {method.trials} "
          f"trials ({truth}); wrote {out}")
    if settings.repeat > 1:
        last = result["precision"][-1]
        print(f"{settings.repeat} runs: median |error| {last['median_abs_error_pct']:.1f} %, 90th percentile "
              f"{last['p90_abs_error_pct']:.1f} %, within 20 %: {100 * last['within_20pct']:.0f} % of runs")
    return 0


def _csv(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(csv_header(rows[0]))
    for row in rows:   # text never a spreadsheet formula (plumbing.textsafe)
        w.writerow(csv_dict({k: repr(v) if isinstance(v, float) else v for k, v in row.items()}).values())
    return buf.getvalue()


def write_results(result: dict, out, figures: bool = True) -> list:
    """Write estimate.json, trials.csv, runs.csv and precision.csv (several runs) and the figures into ``out``.

    Every file is written atomically (a kill leaves the old file or the new one, never half of one).

    Returns
    -------
    list of pathlib.Path
        The files written.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    s: SimulationSettings = result["settings"]
    written = [atomic_write_text(out / "estimate.json", json.dumps(estimate_record(result), indent=2) + "\n"),
               atomic_write_text(out / "trials.csv", _csv(result["tracks"]))]
    if s.repeat > 1:
        written += [atomic_write_text(out / "runs.csv", _csv(result["runs"])),
                    atomic_write_text(out / "precision.csv", _csv(result["precision"]))]
    if figures:
        first = result["first"]
        written += list(plot_track(first["track"], out / "staircase.png", reference=result["reference"],
                                   estimate=first["estimate"]["threshold"], title=s.method).values())
        if s.repeat > 1:
            written += list(plot_precision(result["precision"], out / "precision.png", title=s.method).values())
    return written
