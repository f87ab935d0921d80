"""What ``python -m analysis plan`` writes: ``plan.csv`` and the power-curve figure."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from analysis import figures
from analysis.failures import attempt
from analysis.power import power_curves
from plumbing.fileio import atomic_write_text
from plumbing.textsafe import safe_frame


def write_plan(plan: pd.DataFrame, out_dir, notes: list | None = None) -> list[Path]:
    """Write ``plan.csv`` and ``fig_power_curves.png/.svg/.plot.csv`` into ``out_dir`` (created); returns the paths.

    ``out_dir`` is the staging folder of the caller's :func:`plumbing.outdir.output_folder` (an earlier plan is
    replaced only with ``--force``, once the new one is whole). Sample names are written as text a
    spreadsheet never runs (:func:`plumbing.textsafe.safe_frame`). The figure fails alone: ``plan.csv`` is
    written first, and a figure that cannot be drawn is a line in ``notes`` saying why (:mod:`analysis.failures`).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = atomic_write_text(out / "plan.csv", safe_frame(plan).to_csv(index=False, float_format="%.6g"))
    notes = [] if notes is None else notes
    fig = attempt("the power-curve figure", notes, lambda: figures.fig_power_curves(power_curves(plan), plan,
                                                                                   out / "fig_power_curves.png"),
                  default={}, failed="not drawn")
    return [csv_path] + [Path(p) for p in fig.values()]
