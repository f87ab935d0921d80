"""``python -m analysis psychometric DATA --out DIR``: psychometric fits of forced-choice data (issue 34).

The body; the parser is :mod:`analysis.cli_psychometric_parser`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from plumbing.fileio import atomic_write_text
from plumbing.outdir import output_folder
from plumbing.textsafe import csv_text

from analysis.psychometric_figures import fig_curves, fig_proportions, fig_tracks
from analysis.psychophysics import fit_groups, fits_table, load_trials, physical_summary, proportions_correct

#: what the command writes into --out (a folder of these alone, without the output marker, was written by an
#: older version and is replaced by --force)
PSYCHOMETRIC_FILES = ("fit.json", "fits.csv", "proportions.csv", "fig_*")
#: the most distinct intensities of one fit (each is a level of the likelihood; a CSV with 10^6 of them is not
#: a psychometric experiment but a typo or a continuous covariate, and its fit would not fit in memory)
MAX_FIT_LEVELS = 10_000


def _alternatives(args, experiment: dict) -> int:
    """``--alternatives``, else the sessions' ``experiment.alternatives``; a disagreement is said on stderr."""
    declared = experiment.get("alternatives")
    if declared is not None and experiment.get("guess_rate") == 0:
        declared = 1   # "which was harder?" in two intervals: a yes/no question about the comparison (gamma = 0)
    if args.alternatives is None:
        if declared is None:
            raise ValueError("--alternatives is required for a plain CSV (n of the n-AFC task; 1 for yes/no)")
        return int(declared)
    if declared is not None and int(declared) != args.alternatives:
        print(f"warning: --alternatives {args.alternatives} differs from the sessions' experiment.alternatives = "
              f"{declared}; fitting with {args.alternatives}", file=sys.stderr)
    return args.alternatives


def run(args: argparse.Namespace) -> int:
    """The ``psychometric`` command: fit, write ``fit.json``, ``fits.csv`` and the figures; returns the exit code."""


    if args.bootstrap < 0 or args.bootstrap > 100_000:
        raise ValueError(f"--bootstrap must be in 0..100000 resamples, got {args.bootstrap}")
    if not (0.5 <= args.ci < 1.0):
        raise ValueError(f"--ci must be in [0.5, 1), got {args.ci}")
    if args.reference is not None and not (math.isfinite(args.reference) and args.reference > 0):
        raise ValueError(f"--reference must be a finite number > 0, got {args.reference}")
    # written beside --out and swapped in whole, one writer at a time (plumbing.outdir): an interrupted or
    # failed fit leaves the earlier results as they were; an --out that is, holds or lies in DATA is refused
    folder = output_folder(args.out, args.force, inputs=[(args.data, "the data")], command="analysis psychometric",
                           own=PSYCHOMETRIC_FILES).open()
    with folder:
        said = _fit(args, folder.path, folder.out)
    print(said)
    return 0


def _fit(args: argparse.Namespace, out: Path, final: Path) -> str:
    """Fit DATA and write the results into ``out`` (swapped in later as ``final``); returns the line to print."""
    trials = load_trials(args.data)
    levels = len(set(trials.intensity.tolist()))
    if levels > MAX_FIT_LEVELS:
        raise ValueError(f"{args.data}: {levels} distinct intensities; a fit takes at most {MAX_FIT_LEVELS} "
                         "(group the intensities into levels first)")
    if trials.experiment.get("kind") == "real-virtual-2afc":
        return _real_virtual(args, trials, out, final)
    alternatives = _alternatives(args, trials.experiment)
    reference = args.reference if args.reference is not None else trials.experiment.get("reference")
    scale = trials.experiment.get("intensity_scale", "linear")
    # on a log10 intensity axis the reference is compared in physical units (physical_summary), not in the fit
    equal = alternatives == 1 and args.lower_asymptote == "lapse"
    fits = fit_groups(trials, alternatives, args.function, args.lapse, args.bootstrap, args.ci,
                      None if scale == "log10" else reference, args.seed, equal)
    out.mkdir(parents=True, exist_ok=True)
    def entry(f):
        d = f.as_dict()
        if scale == "log10":
            d.update(physical_summary(f, reference))
        return d

    doc = {"source": [str(s) for s in trials.sources], "experiment": trials.experiment, "threshold_convention":
           "the stimulus where the sigmoid F (before guess and lapse scaling) is 0.5", "intensity_scale": scale,
           **entry(fits[0].fit),
           "groups": [{"subject": g.subject, "condition": g.condition, **entry(g.fit)} for g in fits]}
    header, rows = fits_table(fits, reference if scale == "log10" else None)
    lines = [",".join(header)] + [",".join(_cell(v) for v in row) for row in rows]
    atomic_write_text(out / "fits.csv", "\n".join(lines) + "\n")
    atomic_write_text(out / "fit.json", json.dumps(doc, indent=2, allow_nan=False) + "\n")
    if not args.no_figures:

        label = args.intensity_label or _default_label(trials.experiment)
        fig_curves(trials, fits, out / "fig_psychometric", label)
        if any(trials.staircase) or trials.experiment.get("method", "constant") != "constant":
            fig_tracks(trials, out / "fig_staircases", label)
    f = fits[0].fit
    lo, hi = f.threshold_ci
    ci = f"[{lo:.4g}, {hi:.4g}]" if math.isfinite(lo) else "(no bootstrap)"
    task = "yes/no" if alternatives == 1 else f"{alternatives}-AFC"
    return (f"{f.n_trials} trials at {f.n_levels} intensities, {f.function}, {task}: threshold {f.threshold:.4g} {ci} "
            f"({f.ci_level:.0%} CI), slope {f.slope:.4g}, lapse {f.lapse:.3g}, deviance {f.deviance:.3g} (bootstrap p "
            f"= {f.deviance_p_bootstrap:.3g}); {len(fits)} fit(s) in {final / 'fits.csv'}")


def _real_virtual(args, trials, out: Path, final: Path) -> str:
    """Real-vs-virtual 2AFC: proportion correct per rendering with its exact interval and a test against 0.5."""


    props = proportions_correct(trials, 0.5, args.ci)
    out.mkdir(parents=True, exist_ok=True)
    header = ["subject", "condition", "n_trials", "n_correct", "proportion_correct", "ci_low", "ci_high",
              "p_vs_chance"]
    lines = [",".join(header)] + [",".join(_cell(v) for v in (p.subject, p.condition, p.n_trials, p.n_correct,
                                                                p.proportion, p.ci_low, p.ci_high, p.p_vs_chance))
                                  for p in props]
    atomic_write_text(out / "proportions.csv", "\n".join(lines) + "\n")
    doc = {"source": [str(s) for s in trials.sources], "experiment": trials.experiment, "chance": 0.5,
           "ci_level": args.ci, "ci_method": "Clopper-Pearson", "test": "exact two-sided binomial test against 0.5",
           "proportions": [p.__dict__ for p in props]}
    atomic_write_text(out / "fit.json", json.dumps(doc, indent=2, allow_nan=False) + "\n")
    if not args.no_figures:

        fig_proportions(props, out / "fig_real_virtual")
    lines = [f"{p.condition}: {p.n_correct}/{p.n_trials} correct = {p.proportion:.2f} [{p.ci_low:.2f}, "
             f"{p.ci_high:.2f}], p = {p.p_vs_chance:.3g} against chance" for p in props if p.subject == "(pooled)"]
    return "\n".join(lines + [f"{len(props)} proportion(s) in {final / 'proportions.csv'}"])


def _cell(v) -> str:
    if isinstance(v, float):
        return "" if not math.isfinite(v) else repr(v)
    text = csv_text(str(v))   # a name from the data is never a spreadsheet formula (plumbing.textsafe)
    return '"' + text.replace('"', '""') + '"' if any(c in text for c in ',"\n') else text


def _default_label(experiment: dict) -> str:
    kind = experiment.get("kind")
    scale = experiment.get("intensity_scale", "linear")
    base = {"discrimination": "comparison stiffness (N/m)", "detection": "transient amplitude (A)"}.get(
        kind, "intensity (stimulus units)")
    return f"log10 {base}" if scale == "log10" else base
