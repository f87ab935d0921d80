"""Benchmark: the mixed model's recovery of known rendering effects over 50 synthetic studies.

Each study is written by :func:`analysis.synthetic.write_synthetic_study` with its own seed; the
generator's true effect of each sample against the reference is the difference of its expected
ratings on the 1-7 scale it writes (:func:`analysis.synthetic.expected_ratings`: rounding and
clipping included). A rendering effect is recovered in a study when the truth lies inside the mixed
model's 95 % CI. Printed: the share of (study, effect) pairs covered (target: >= 90 %), the
worst effect's share, the studies whose every effect was covered, how often the random slope was
kept, and the median fit time.

``python benchmarks/bench_models.py [--studies 50] [--subjects 12]``
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

import numpy as np

from tests.support.models import TARGET_COVERAGE, coverage_study

def run(n_studies: int = 50, n_subjects: int = 12) -> dict:
    """Fit ``n_studies`` synthetic studies; returns the coverage figures (see the module docstring)."""
    per_sample, all_covered, slopes, times = {}, 0, 0, []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(n_studies):
            covered, info, took = coverage_study(Path(tmp), 1000 + seed, n_subjects)
            for s, c in covered.items():
                per_sample.setdefault(s, []).append(c)
            all_covered += all(covered.values())
            slopes += info.get("structure") == "random intercept + velocity slope"
            times.append(took)
    share = {s: float(np.mean(c)) for s, c in per_sample.items()}
    pooled = float(np.mean([c for v in per_sample.values() for c in v]))
    return {"studies": n_studies, "subjects": n_subjects, "coverage": pooled, "per_sample": share,
            "all_covered": all_covered, "slope_kept": slopes, "median_fit_s": statistics.median(times)}


def main(argv=None) -> None:
    """Print the coverage of 50 (``--studies``) synthetic studies against the >= 90 % target."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--studies", type=int, default=50)
    p.add_argument("--subjects", type=int, default=12)
    a = p.parse_args(argv if argv is not None else [])
    r = run(a.studies, a.subjects)
    worst = min(r["per_sample"], key=r["per_sample"].get)
    print(f"   mixed model, {r['studies']} studies x {r['subjects']} subjects: rendering effects inside their 95 % CI "
          f"{100 * r['coverage']:.1f} % of {sum(1 for _ in r['per_sample']) * r['studies']} (target >= "
          f"{100 * TARGET_COVERAGE:.0f} %: {'met' if r['coverage'] >= TARGET_COVERAGE else 'MISSED'}); worst effect "
          f"{worst} {100 * r['per_sample'][worst]:.0f} %; every effect covered in {r['all_covered']} studies; random "
          f"slope kept in {r['slope_kept']}; median fit {r['median_fit_s']:.2f} s", flush=True)


if __name__ == "__main__":
    import sys
    main(sys.argv[1:])
