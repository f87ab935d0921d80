"""The trials reader's error path does not copy the file many times over (issue 38, item 4: a 367 MB
trials.csv with one bad cell peaked at 9.3 GB before its error)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from analysis.synthetic import write_synthetic_study

ROOT = Path(__file__).resolve().parents[2]

#: load the study in a fresh process; print the error and the process's peak RSS (kB)
LOAD = """
import resource, sys
from analysis.load import load_study
try:
    load_study(sys.argv[1])
    print("loaded")
except ValueError as exc:
    print(exc)
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def _grow(trials: Path, target_bytes: int, bad_column: str | None) -> int:
    """Repeat the rows of ``trials`` up to ``target_bytes``; put ``abc`` in ``bad_column`` of the middle row."""
    head, *body = trials.read_text().splitlines()
    rows = []
    size, block = 0, sum(len(r) + 1 for r in body)      # a running total: summing all rows each time was O(n^2)
    while size < target_bytes:
        rows.extend(body)
        size += block
    middle = len(rows) // 2
    if bad_column:
        cells = rows[middle].split(",")
        cells[head.split(",").index(bad_column)] = "abc"
        rows[middle] = ",".join(cells)
    trials.write_text("\n".join([head, *rows]) + "\n")
    return middle + 2        # its line number


def _load(data: Path) -> tuple[str, int]:
    out = subprocess.run([sys.executable, "-c", LOAD, str(data)], capture_output=True, text=True, cwd=ROOT,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    message, peak_kb = out.stdout.strip().splitlines()
    return message, int(peak_kb) * 1024


def test_a_bad_cell_in_a_large_trials_file_costs_a_few_times_its_size(tmp_path):
    small, big = tmp_path / "small", tmp_path / "big"
    for root in (small, big):
        write_synthetic_study(root, 1, seed=5)
    (trials,) = big.glob("*/trials.csv")
    (small_trials,) = small.glob("*/trials.csv")
    line = _grow(trials, 40 << 20, "n_taps")
    _grow(small_trials, 1 << 20, "n_taps")
    message, peak_big = _load(big)
    assert message == f"{trials}:{line}: column 'n_taps': value 'abc' is not an integer"
    _, peak_small = _load(small)
    size = trials.stat().st_size
    # the reader's own memory beyond the interpreter and libraries: was ~25x the file (Python strings per cell)
    assert peak_big - peak_small < 6 * size, (peak_big - peak_small) / size
