"""The mixed model's coverage of a generated study's true effects (shared by tests/analysis/test_analysis_models.py
and the benchmark ``models``)."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

from analysis.load import load_study
from analysis.models import fit_models
from analysis.synthetic import expected_ratings, write_synthetic_study

REFERENCE = "wood_on_foam"
TARGET_COVERAGE = 0.90


def coverage_study(root: Path, seed: int, n_subjects: int) -> tuple[dict, dict, float]:
    """One synthetic study's mixed-model fit: ``({sample: covered}, mixed info, fit seconds)``."""
    folder = root / f"study_{seed}"
    write_synthetic_study(folder, n_subjects, seed=seed)
    truth = expected_ratings(n_subjects)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        study = load_study(folder)
        t0 = time.perf_counter()
        res = fit_models(study, REFERENCE)
        took = time.perf_counter() - t0
    fixed = res.fixed[res.fixed["model"] == "mixed"].set_index("term")
    if not res.mixed.get("fitted"):
        # a study the model could not fit counts as every effect missed (its reason is printed)
        print(f"   seed {seed}: mixed model not fitted: {'; '.join(res.notes)}", flush=True)
        return {s: False for s in truth if s != REFERENCE}, res.mixed, took
    covered = {}
    for sample, value in truth.items():
        if sample == REFERENCE:
            continue
        row = fixed.loc[f"sample[{sample}]"]
        effect = value - truth[REFERENCE]
        covered[sample] = bool(row["ci_low"] <= effect <= row["ci_high"])
    return covered, res.mixed, took
