"""``python -m analysis adjustment`` and ``python -m analysis magnitude``: the bodies (parsers:
:mod:`analysis.cli_scaling_parser`). Each writes its output folder staged (whole or not at all,
:mod:`plumbing.outdir`)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from plumbing.fileio import atomic_write_text
from plumbing.outdir import output_folder

from analysis import adjustment, magnitude
from analysis.scaling_figures import (build_adjustment_pooled, build_adjustment_subjects, build_magnitude_exponents,
                                      build_magnitude_loglog, save)


def _check(args) -> None:
    if not (0.5 <= args.ci < 1.0):
        raise ValueError(f"--ci must be in [0.5, 1), got {args.ci}")
    if Path(args.out).resolve() == Path(args.data).resolve():
        raise ValueError(f"--out {args.out} must not be the data folder {args.data}")


def _csv(df) -> str:
    return df.to_csv(index=False, float_format="%.10g", lineterminator="\n")


def _unit(result: dict) -> tuple[str, str]:
    """The varied parameter in words (its unit suffix dropped: ``stiffness_N_m`` -> ``stiffness``) and its unit."""
    exp = next(iter(result["experiments"].values()))
    vary, unit = exp.get("vary", "value"), exp.get("unit", "1")
    for suffix in ("_N_m", "_Ns_m", "_hz", "_s"):
        if vary.endswith(suffix):
            return vary[:-len(suffix)].replace("_", " "), unit
    return vary.replace("_", " "), unit


def _vary(result: dict) -> str:
    return next(iter(result["experiments"].values())).get("vary", "")


def _write(folder, result: dict, summary: dict) -> None:
    for name in ("subjects", "pooled", "trials"):
        atomic_write_text(folder / f"{name}.csv", _csv(result[name]))
    if result["order"] is not None:
        atomic_write_text(folder / "order_effects.csv", _csv(result["order"]))
    atomic_write_text(folder / "summary.json", json.dumps(summary, indent=2, allow_nan=False, default=_plain) + "\n")


def _plain(v):
    return None if isinstance(v, float) and not math.isfinite(v) else float(v)


def _interval(low, high, fmt: str) -> str:
    """``[low, high]``, or why there is none (one subject: a pooled interval needs two)."""
    if not (math.isfinite(low) and math.isfinite(high)):
        return "(no interval: one subject)"
    return f"[{low:{fmt}}, {high:{fmt}}]"


def _records(df) -> list:
    return [{k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in r.items()}
            for r in json.loads(df.to_json(orient="records"))]


def run_adjustment(args: argparse.Namespace) -> int:
    """The ``adjustment`` command; returns the exit code."""
    _check(args)
    folder = output_folder(args.out, args.force).open()
    with folder:
        result = adjustment.analyse(args.data, args.ci)
        vary, unit = _unit(result)
        summary = {"data": str(args.data), "ci_level": args.ci, "vary": _vary(result), "unit": unit,
                   "pse": "geometric mean of the matched settings (t interval on their logarithms)",
                   "jnd": "0.6745 SD of the log settings (75 % point): weber = exp(0.6745 sd_log) - 1",
                   "pooled": _records(result["pooled"]), "skipped_folders": result["skipped"]}
        _write(folder.path, result, summary)
        if not args.no_figures:
            save(build_adjustment_subjects, folder.path / "fig_adjustment_subjects", result["trials"],
                 result["subjects"], f"comparison {vary} ({unit})")
            save(build_adjustment_pooled, folder.path / "fig_adjustment_pooled", result["subjects"], result["pooled"])
    for note in result["skipped"]:
        print(f"note: {note} is not a method-of-adjustment session; left out", file=sys.stderr)
    for _, p in result["pooled"].iterrows():
        print(f"{p['condition']}: PSE {p['pse']:.4g} {unit} {_interval(p['pse_low'], p['pse_high'], '.4g')} over "
              f"{p['subjects']} subject(s), constant error {100 * p['ce_rel']:+.1f} %, Weber fraction "
              f"{p['weber']:.3f}")
    print(f"wrote {args.out}")
    return 0


def run_magnitude(args: argparse.Namespace) -> int:
    """The ``magnitude`` command; returns the exit code."""
    _check(args)
    folder = output_folder(args.out, args.force).open()
    with folder:
        result = magnitude.analyse(args.data, args.ci)
        vary, unit = _unit(result)
        summary = {"data": str(args.data), "ci_level": args.ci, "vary": _vary(result), "unit": unit,
                   "model": "ln number = ln k + exponent ln stimulus (OLS per subject and condition)",
                   "normalisation": "each subject's numbers over their geometric mean, times the grand geometric mean",
                   "pooled": _records(result["pooled"]), "skipped_folders": result["skipped"]}
        _write(folder.path, result, summary)
        if not args.no_figures:
            save(build_magnitude_loglog, folder.path / "fig_magnitude_loglog", result["trials"], result["pooled"],
                 f"stimulus {vary} ({unit})")
            save(build_magnitude_exponents, folder.path / "fig_magnitude_exponents", result["subjects"],
                 result["pooled"])
    for note in result["skipped"]:
        print(f"note: {note} is not a magnitude-estimation session; left out", file=sys.stderr)
    for _, p in result["pooled"].iterrows():
        print(f"{p['condition']}: exponent {p['exponent']:.3f} {_interval(p['exponent_low'], p['exponent_high'], '.3f')} "
              f"over {p['subjects']} subject(s); group curve {p['curve_exponent']:.3f}")
    print(f"wrote {args.out}")
    return 0
