"""``python -m analysis psychometric DATA --out DIR``: psychometric fits of forced-choice data.

The body; the parser is :mod:`analysis.cli_psychometric_parser`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from plumbing.fileio import atomic_write_text, check_output_dir

from analysis.psychometric_figures import fig_curves, fig_proportions, fig_tracks
from analysis.psychophysics import fit_groups, fits_table, load_trials, physical_summary, proportions_correct


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
    out = check_output_dir(args.out, force=args.force)
    trials = load_trials(args.data)
    if trials.experiment.get("kind") == "real-virtual-2afc":
        return _real_virtual(args, trials, out)
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
    print(f"{f.n_trials} trials at {f.n_levels} intensities, {f.function}, {task}: threshold {f.threshold:.4g} {ci} ({f.ci_level:.0%} CI), "
          f"slope {f.slope:.4g}, lapse {f.lapse:.3g}, deviance {f.deviance:.3g} (bootstrap p = "
          f"{f.deviance_p_bootstrap:.3g}); {len(fits)} fit(s) in {out / 'fits.csv'}")
    return 0


def _real_virtual(args, trials, out: Path) -> int:
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
    for p in props:
        if p.subject == "(pooled)":
            print(f"{p.condition}: {p.n_correct}/{p.n_trials} correct = {p.proportion:.2f} "
                  f"[{p.ci_low:.2f}, {p.ci_high:.2f}], p = {p.p_vs_chance:.3g} against chance")
    print(f"{len(props)} proportion(s) in {out / 'proportions.csv'}")
    return 0


def _cell(v) -> str:
    if isinstance(v, float):
        return "" if not math.isfinite(v) else repr(v)
    text = str(v)
    return '"' + text.replace('"', '""') + '"' if any(c in text for c in ',"\n') else text


def _default_label(experiment: dict) -> str:
    kind = experiment.get("kind")
    scale = experiment.get("intensity_scale", "linear")
    base = {"discrimination": "comparison stiffness (N/m)", "detection": "transient amplitude (A)"}.get(
        kind, "intensity (stimulus units)")
    return f"log10 {base}" if scale == "log10" else base
