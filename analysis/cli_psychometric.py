"""``python -m analysis psychometric DATA --out DIR``: psychometric fits of forced-choice data (issue 34)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from plumbing.cliargs import with_examples

FUNCTION_CHOICES = ("logistic", "normal", "weibull")


def _lapse(text: str):
    """``--lapse``: ``free`` (fitted) or a fixed rate."""
    if text == "free":
        return None
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be 'free' or a number in [0, 0.5), got {text!r}") from None
    if not (0.0 <= value < 0.5):
        raise argparse.ArgumentTypeError(f"must be 'free' or a number in [0, 0.5), got {text!r}")
    return value


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
    from plumbing.fileio import atomic_write_text, check_output_dir  # deferred: keeps `--help` fast (a command loads only what it runs)

    from analysis.psychophysics import fit_groups, fits_table, load_trials, physical_summary  # deferred: keeps `--help` fast (a command loads only what it runs)

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
    fits = fit_groups(trials, alternatives, args.function, args.lapse, args.bootstrap, args.ci,
                      None if scale == "log10" else reference, args.seed)
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
        from analysis.psychometric_figures import fig_curves, fig_tracks  # deferred: matplotlib only when drawing

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
    from plumbing.fileio import atomic_write_text  # deferred: keeps `--help` fast (a command loads only what it runs)

    from analysis.psychophysics import proportions_correct  # deferred: keeps `--help` fast (a command loads only what it runs)

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
        from analysis.psychometric_figures import fig_proportions  # deferred: matplotlib only when drawing

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


def register(subparsers) -> None:
    """Add the ``psychometric`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m analysis`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "psychometric", help="psychometric fits (threshold, slope, lapse, PSE, JND) of forced-choice data",
        description="Fit psi(x) = gamma + (1 - gamma - lambda) F(x) by maximum likelihood to DATA: a study folder "
                    "of psychophysics sessions or a CSV with columns intensity and correct (0/1), optional subject "
                    "and condition. The threshold is the stimulus where F = 0.5. Writes fit.json (the fit of all "
                    "trials pooled, and every group), fits.csv (per subject and condition, and pooled) and the "
                    "figures into --out.")
    p.add_argument("data", metavar="DATA", help="study data folder, one subject's folder, or a CSV file")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created; new or empty)")
    p.add_argument("--force", action="store_true", help="write into --out even if it holds earlier results")
    p.add_argument("--alternatives", type=int, default=None, metavar="N",
                   help="n of the n-AFC task: guess rate 1/N; 1 for yes/no or 'which was harder?' (guess rate 0). "
                        "Default: the sessions' experiment.alternatives (required for a CSV)")
    p.add_argument("--function", choices=FUNCTION_CHOICES, default="logistic",
                   help="F: logistic, cumulative normal or Weibull (intensities > 0) (default logistic)")
    p.add_argument("--lapse", type=_lapse, default=None, metavar="free|RATE",
                   help="lapse rate: 'free' (fitted in [0, 0.1], the default) or a fixed rate such as 0")
    p.add_argument("--bootstrap", type=int, default=1000, metavar="R",
                   help="parametric bootstrap resamples for the intervals and the deviance test (default 1000; 0: none)")
    p.add_argument("--ci", type=float, default=0.95, help="confidence level of the intervals (default 0.95)")
    p.add_argument("--reference", type=float, default=None, metavar="X",
                   help="reference stimulus of a discrimination task, for the Weber fraction (default: the "
                        "sessions' experiment.reference)")
    p.add_argument("--intensity-label", default=None, metavar="TEXT",
                   help="x axis label with its unit, e.g. 'comparison stiffness (N/m)'")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap (default 0)")
    p.add_argument("--no-figures", action="store_true", help="tables without figures")
    with_examples(p, "hfam-analysis psychometric DATA --out FITS",
                  "hfam-analysis psychometric trials.csv --alternatives 2 --function weibull --out FITS",
                  "hfam-analysis psychometric jnd.csv --alternatives 1 --reference 500 --lapse 0 --out FITS")
    p.set_defaults(func=run)
