"""``python -m analysis psychometric DATA --out DIR``: psychometric fits of forced-choice data.

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

from analysis.psychometric_figures import axis_words, fig_curves, fig_proportions, fig_tracks
from analysis.psychophysics import (ALL, POOLED, FitOptions, check_poolable, compare_conditions, dprime_table,
                                    fit_groups, fits_table, load_trials, measurements, physical_summary,
                                    proportions_correct)

#: the lower-asymptote flag's words -> the model (psychophysics.fitting.LOWER_ASYMPTOTES)
LOWER = {"free": "free", "lapse": "equal", "zero": "fixed"}



#: what the command writes into --out (a folder of these alone, without the output marker, was written by an
#: older version and is replaced by --force)
PSYCHOMETRIC_FILES = ("fit.json", "fits.csv", "proportions.csv", "dprime.csv", "fig_*")
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


def _lower_asymptote(args, alternatives: int, experiment: dict) -> str:
    """The lower-asymptote model: n-AFC ``fixed``; yes/no from ``--lower-asymptote`` (``auto``: equal asymptotes
    for "which was harder?", a free false-alarm rate otherwise)."""
    if alternatives != 1:
        return "fixed"
    if args.lower_asymptote == "auto":
        return "equal" if experiment.get("kind") == "discrimination" else "free"
    return LOWER[args.lower_asymptote]


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
    """Fit DATA and write the results into ``out`` (swapped in later as ``final``); returns the last line to
    print (the console lines of each fit are printed as they are made)."""
    trials = load_trials(args.data)
    levels = len(set(trials.intensity.tolist()))
    if levels > MAX_FIT_LEVELS:
        raise ValueError(f"{args.data}: {levels} distinct intensities; a fit takes at most {MAX_FIT_LEVELS} "
                         "(group the intensities into levels first)")
    if trials.experiment.get("kind") == "real-virtual-2afc":
        return _real_virtual(args, trials, out, final)
    groups = measurements(trials)
    if not args.separately:
        check_poolable(trials)
        groups = groups[:1]
    results = [_fit_measurement(args, trials.subset(g.mask) if args.separately else trials, g)
               for g in groups]
    out.mkdir(parents=True, exist_ok=True)
    tag = (lambda r: r["measurement"]) if args.separately else (lambda r: None)
    header, rows = None, []
    for r in results:
        h, rs = fits_table(r["fits"], r["reference"], r["scale"] == "log10", args.threshold_at, tag(r))
        if header is not None and h != header:        # measurements of both scales: physical columns for all
            h, rs = fits_table(r["fits"], r["reference"], True, args.threshold_at, tag(r))
        header = h if header is None or len(h) > len(header) else header
        rows += [row + [math.nan] * (len(header) - len(row)) for row in rs]
    lines = [",".join(header)] + [",".join(_cell(v) for v in row) for row in rows]
    atomic_write_text(out / "fits.csv", "\n".join(lines) + "\n")
    docs = [_document(args, r) for r in results]
    doc = {"source": [str(s) for s in trials.sources], "threshold_convention":
           "the stimulus where the sigmoid F (before guess and lapse scaling) is 0.5"}
    if args.separately:
        doc["measurements"] = docs
    else:
        doc.update(docs[0])
    atomic_write_text(out / "fit.json", json.dumps(doc, indent=2, allow_nan=False) + "\n")
    dprimes = [dict(row, measurement=r["measurement"]) for r in results for row in r["dprime"]]
    if dprimes:
        keys = (["measurement"] if args.separately else []) + [k for k in dprimes[0] if k != "measurement"]
        text = [",".join(keys)] + [",".join(_cell(d[k]) for k in keys) for d in dprimes]
        atomic_write_text(out / "dprime.csv", "\n".join(text) + "\n")
    for r in results:
        suffix = f"_m{r['measurement']}" if args.separately else ""
        if not args.no_figures:
            words = axis_words(r["experiment"], r["alternatives"], args.intensity_label)
            fig_curves(r["trials"], r["fits"], out / f"fig_psychometric{suffix}", words)
            if any(r["trials"].staircase) or r["experiment"].get("method", "constant") != "constant":
                fig_tracks(r["trials"], out / f"fig_staircases{suffix}", words)
        _say(args, r, out)
    return f"{sum(len(r['fits']) for r in results)} fit(s) in {final / 'fits.csv'}"


def _fit_measurement(args, trials, group) -> dict:
    """Every fit of one measurement (one set of sessions that are the same measurement)."""
    experiment = trials.experiment
    alternatives = _alternatives(args, experiment)
    reference = args.reference if args.reference is not None else experiment.get("reference")
    scale = experiment.get("intensity_scale", "linear")
    lower = _lower_asymptote(args, alternatives, experiment)
    # on a log10 intensity axis the reference is compared in physical units (physical_summary), not in the fit
    o = FitOptions(alternatives=alternatives, function=args.function, lapse=args.lapse, bootstrap=args.bootstrap,
                   ci_level=args.ci, reference=None if scale == "log10" else reference, seed=args.seed,
                   lower_asymptote=lower, bayesian=args.bayesian)
    fits = fit_groups(trials, alternatives, options=o)
    comparisons = []
    if args.compare:
        subjects = sorted(set(trials.subject[~trials.is_catch]))
        for subject in [POOLED] + (subjects if len(subjects) > 1 else []):
            c = compare_conditions(trials, o, subject)
            if c is not None:
                comparisons.append(c)
        if not comparisons:
            print("warning: --compare needs two or more conditions; the data have one", file=sys.stderr)
    return {"measurement": group.index, "sessions": group.sessions, "experiment": experiment, "trials": trials,
            "alternatives": alternatives, "reference": reference, "scale": scale, "lower": lower, "options": o,
            "fits": fits, "comparisons": comparisons,
            "dprime": dprime_table(trials) if alternatives == 1 else []}


def _document(args, r) -> dict:
    """fit.json's part for one measurement."""
    def entry(f):
        d = f.as_dict()
        if r["scale"] == "log10":
            d.update(physical_summary(f, r["reference"]))
        for pc in args.threshold_at:
            try:
                d.setdefault("thresholds_at", []).append(f.threshold_at(pc))
            except ValueError as exc:
                d.setdefault("thresholds_at", []).append({"pc": pc, "error": str(exc)})
        return d

    doc = {"measurement": r["measurement"], "sessions": list(r["sessions"]), "experiment": r["experiment"],
           "intensity_scale": r["scale"],
           "fit_method": "Bayesian (maximum a posteriori)" if args.bayesian else "maximum likelihood",
           **entry(r["fits"][0].fit),
           "groups": [{"subject": g.subject, "condition": g.condition, **entry(g.fit)} for g in r["fits"]]}
    if not args.separately:
        doc.pop("measurement")
    if r["comparisons"]:
        doc["comparisons"] = [{"subject": c["subject"], "shared_slope_and_lapse": c["shared"].as_dict(),
                               "thresholds_differ": _lr(c["thresholds_differ"]),
                               "slopes_differ": _lr(c["slopes_differ"])} for c in r["comparisons"]]
    return doc


def _lr(cmp) -> dict:
    d = cmp.as_dict()
    return {k: d[k] for k in ("lr", "df", "p_bootstrap", "p_chi2", "bootstrap")}


def _number(v: float, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "n/a"
    if math.isinf(v):
        return "-inf" if v < 0 else "inf"
    return f"{v:.{digits}g}"


def _interval(ci) -> str:
    lo, hi = ci
    return f"[{_number(lo)}, {_number(hi)}]"


def _say(args, r, out: Path) -> None:
    """The console lines of one measurement: its pooled fit in the task's words and units, then every flag."""
    f = r["fits"][0].fit
    words = axis_words(r["experiment"], r["alternatives"], args.intensity_label)
    unit = f" {words.unit}" if words.unit and words.unit != "1" else ""
    ci_name = "credible interval" if args.bayesian else "CI"
    task = "yes/no" if r["alternatives"] == 1 else f"{r['alternatives']}-AFC"
    if r["alternatives"] == 1:
        task += {"equal": ", lower asymptote = lapse rate", "free": f", false alarms {f.guess:.3g}",
                 "fixed": ""}[r["lower"]]
    head = f"measurement {r['measurement']} ({len(r['sessions'])} session(s)): " if args.separately else ""
    name = "PSE" if r["alternatives"] == 1 else "threshold"
    if r["scale"] == "log10":
        ph = physical_summary(f, r["reference"])
        parts = [f"{name} {_number(ph['threshold_physical'])}{unit} {_interval(ph['threshold_ci_physical'])}"]
        if ph["jnd_physical"] is not None:
            parts.append(f"JND {_number(ph['jnd_physical'])}{unit} {_interval(ph['jnd_ci_physical'])}")
        if ph["weber_physical"] is not None:
            parts.append(f"Weber fraction {_number(ph['weber_physical'])} {_interval(ph['weber_ci_physical'])}")
        parts.append(f"(log10 axis: {_number(f.threshold)} {_interval(f.threshold_ci)})")
    else:
        parts = [f"{name} {_number(f.threshold)}{unit} {_interval(f.threshold_ci)}"]
        if not math.isnan(f.jnd):
            parts.append(f"JND {_number(f.jnd)}{unit} {_interval(f.jnd_ci)}")
        if not math.isnan(f.weber):
            parts.append(f"Weber fraction {_number(f.weber)} {_interval(f.weber_ci)}")
    gof = (f"eta {f.eta:.3g}" if args.bayesian else
           f"deviance {f.deviance:.3g} (bootstrap p = {_number(f.deviance_p_bootstrap, 3)})")
    print(f"{head}{f.n_trials} trials at {f.n_levels} intensities, {f.function}, {task}: " + ", ".join(parts)
          + f" ({f.ci_level:.0%} {ci_name}), slope {f.slope:.4g}, lapse {f.lapse:.3g}, {gof}")
    for pc in args.threshold_at:
        try:
            t = f.threshold_at(pc)
        except ValueError as exc:
            print(f"  threshold at {pc:g}: {exc}")
            continue
        x, ci = t["threshold"], t["ci"]
        if r["scale"] == "log10":
            x, ci = 10.0 ** x, [10.0 ** v if not math.isnan(v) else math.nan for v in ci]
        print(f"  threshold at {pc:g}: {_number(x)}{unit} {_interval(ci)}")
    for c in r["comparisons"]:
        who = "all subjects" if c["subject"] == POOLED else f"subject {c['subject']}"
        t, s = c["thresholds_differ"], c["slopes_differ"]
        print(f"  conditions ({who}, slope and lapse shared): thresholds differ? LR {t.lr:.3g}, df {t.df}, p = "
              f"{_number(t.p_bootstrap, 3)} (bootstrap), {_number(t.p_chi2, 3)} (chi-square); slopes differ? LR "
              f"{s.lr:.3g}, df {s.df}, p = {_number(s.p_bootstrap, 3)} (bootstrap)")
    for g in r["fits"]:
        for flag in g.fit.flags:
            who = "all trials" if g.subject == POOLED and g.condition == ALL else (
                f"condition {g.condition}" if g.subject == POOLED else f"subject {g.subject}, condition {g.condition}")
            print(f"warning: {head}{who}: {flag.name}: {flag.message}", file=sys.stderr)


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
    for p in props:
        if p.subject == "(pooled)":
            print(f"{p.condition}: {p.n_correct}/{p.n_trials} correct = {p.proportion:.2f} "
                  f"[{p.ci_low:.2f}, {p.ci_high:.2f}], p = {p.p_vs_chance:.3g} against chance")
    return f"{len(props)} proportion(s) in {final / 'proportions.csv'}"


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if not math.isfinite(v) else repr(v)
    text = csv_text(str(v))   # a name from the data is never a spreadsheet formula (plumbing.textsafe)
    return '"' + text.replace('"', '""') + '"' if any(c in text for c in ',"\n') else text
