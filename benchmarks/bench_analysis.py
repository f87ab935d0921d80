"""Benchmark: the full study report (load, validate, every table, four figures, report.md/.html) as a
whole process at 40 / 100 / 1,000 / 10,000 synthetic subjects, against the targets (10,000
subjects: under 5 s and under 1 GB peak memory; 40 subjects, the mixed and ordinal models
included: under 10 s; the models are skipped above 400 subjects), plus the paired t-test matrix alone
(linear in subjects).

Each run writes a new report folder (the report refuses to overwrite an earlier one) and a run that
fails stops the benchmark. Python compiles every imported module when it finds no cached bytecode
(``.pyc``), as in an environment with ``PYTHONDONTWRITEBYTECODE`` set and a venv installed without
byte-compiling: seconds of start-up that an installed program does not pay. ``--warm-bytecode``
(``python -m benchmarks analysis --warm-bytecode 10000``) gives the child processes a private
bytecode cache (``PYTHONPYCACHEPREFIX`` in the temporary folder) filled by one untimed run first;
without it the children inherit the environment as it is.

The command is run as ``python -m analysis report`` runs it (``analysis.__main__.run``, exit included).
The report draws two of its figures (and reads the session files) in a second process it forks at its start
(``analysis.cli_report.figure_process``): that process's CPU time and peak memory are printed beside the
main one's, and the memory target is checked against the sum of the two peaks.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from analysis.models import MODELS_MAX_SUBJECTS
from analysis.stats import RatingMatrix, pairwise_ttests
from analysis.synthetic import write_synthetic_study

SIZES = (40, 100, 1000, 10000)
TARGET_S = 5.0            # full report of 10,000 subjects, whole process (models skipped above 400 subjects)
TARGET_MODELS_S = 10.0    # the whole report including the mixed and ordinal models, 40 subjects
TARGET_MB = 1024.0        # peak resident memory of that process (and of the one drawing figures)
ROOT = Path(__file__).resolve().parents[1]

# the child runs the command as ``python -m analysis report`` does (``analysis.__main__.run``, which ends by
# exiting) and reports its own wall time, CPU time and peak RSS, and those of the process it started to draw
# figures (RUSAGE_CHILDREN: waited-for children; ru_maxrss is in KiB on Linux)
CHILD = """
import json, resource, sys, time, warnings
t0 = time.perf_counter()
warnings.simplefilter("ignore")
from analysis.__main__ import run
sys.argv = ["python -m analysis", "report", sys.argv[1], "--out", sys.argv[2]]
try:
    run()
except SystemExit as exc:
    rc = exc.code
ru, ch = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"rc": rc, "in_process_s": time.perf_counter() - t0, "cpu_s": ru.ru_utime + ru.ru_stime,
                  "peak_mb": ru.ru_maxrss / 1024, "children_cpu_s": ch.ru_utime + ch.ru_stime,
                  "children_peak_mb": ch.ru_maxrss / 1024}))
"""


def _report(data: Path, out: Path, pycache: Path | None = None) -> dict:
    env = {**os.environ, "MPLBACKEND": "Agg"}
    if pycache is not None:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env["PYTHONPYCACHEPREFIX"] = str(pycache)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", CHILD, str(data), str(out)], cwd=ROOT, capture_output=True,
                          text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-2000:])
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    if res["rc"] != 0:      # main() reports bad input by its return code, not by an exception
        raise RuntimeError(f"report exited with {res['rc']}: {proc.stderr[-2000:]}")
    res["wall_s"] = wall
    return res


def _ttest_ms(n: int, repeats: int = 5) -> float:
    rng = np.random.default_rng(0)
    m = rng.integers(1, 8, (n, 12)).astype(float)
    m[3, 2] = np.nan                       # one subject missing one sample: two subject sets
    mat = RatingMatrix(np.array([f"S{i}" for i in range(n)], dtype=object), tuple("abcdefghijkl"), m,
                       np.ones((n, 12), int), np.array(["few"] * n, dtype=object))
    pairwise_ttests(mat, "all")
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        pairwise_ttests(mat, "all")
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def run(repeats: int = 3, sizes=SIZES, warm_bytecode: bool = False) -> dict:
    """Time ``repeats`` whole report processes at each number of subjects in ``sizes`` and print each size's
    figures against the targets; returns ``{n: {"wall_s", "cpu_s", "peak_mb", ...}}``."""
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        pycache = Path(tmp) / "pycache" if warm_bytecode else None
        print(f"   bytecode: {'private cache, warmed by one untimed run' if warm_bytecode else 'as the environment says'}"
              f" (PYTHONDONTWRITEBYTECODE={os.environ.get('PYTHONDONTWRITEBYTECODE', '')!r})", flush=True)
        for n in sizes:
            data = Path(tmp) / f"data{n}"
            t0 = time.perf_counter()
            write_synthetic_study(data, n, seed=1, missing={"S010": ["foam"]}, traces=3)
            gen_s = time.perf_counter() - t0
            if warm_bytecode:
                _report(data, Path(tmp) / f"report{n}_warmup", pycache)
            runs = [_report(data, Path(tmp) / f"report{n}_{i}", pycache) for i in range(repeats)]
            wall = statistics.median(r["wall_s"] for r in runs)
            cpu = statistics.median(r["cpu_s"] for r in runs)
            peak = max(r["peak_mb"] for r in runs)
            child_cpu = statistics.median(r["children_cpu_s"] for r in runs)
            child_peak = max(r["children_peak_mb"] for r in runs)
            ttest = _ttest_ms(n)
            results[n] = {"wall_s": wall, "cpu_s": cpu, "peak_mb": peak, "children_cpu_s": child_cpu,
                          "children_peak_mb": child_peak, "ttest_ms": ttest}
            target = TARGET_MODELS_S if n <= MODELS_MAX_SUBJECTS else TARGET_S
            models = "with the models" if n <= MODELS_MAX_SUBJECTS else "models skipped (above their size limit)"
            print(f"   {n:6d} subjects (data generated in {gen_s:.1f} s): full report {models}, whole-process median "
                  f"{wall:.2f} s of {repeats} (CPU {cpu:.2f} s + drawing process {child_cpu:.2f} s), target "
                  f"{target:.0f} s -> ratio {wall / target:.2f}; peak memory {peak:.0f} MB + drawing process "
                  f"{child_peak:.0f} MB, target {TARGET_MB:.0f} MB -> ratio of the sum "
                  f"{(peak + child_peak) / TARGET_MB:.2f}; t-test matrix {ttest:.1f} ms", flush=True)
            shutil.rmtree(data, ignore_errors=True)
            for old in Path(tmp).glob(f"report{n}_*"):
                shutil.rmtree(old, ignore_errors=True)
    if len(results) > 1:
        ns = sorted(results)
        for a, b in zip(ns, ns[1:]):
            print(f"   t-test matrix growth {a} -> {b} subjects ({b // a}x): "
                  f"{results[b]['ttest_ms'] / results[a]['ttest_ms']:.1f}x (linear: <= {b // a}x)")
    return results


def main(argv=None) -> dict:
    """``python -m benchmarks analysis [SIZES ...] [--warm-bytecode] [--repeats N]`` (no options: every size)."""
    cli = argparse.ArgumentParser(prog="python -m benchmarks analysis", description=__doc__.splitlines()[0])
    cli.add_argument("sizes", nargs="*", type=int, help=f"numbers of subjects (default: {' '.join(map(str, SIZES))})")
    cli.add_argument("--warm-bytecode", action="store_true",
                     help="compile the libraries' bytecode once first, as a normal install has it")
    cli.add_argument("--repeats", type=int, default=3, help="whole report processes per size (default 3)")
    a = cli.parse_args(argv if argv is not None else [])
    if a.repeats < 1 or any(n < 1 for n in a.sizes):
        cli.error("--repeats and every size must be >= 1")
    return run(a.repeats, tuple(a.sizes) or SIZES, a.warm_bytecode)


if __name__ == "__main__":
    main(sys.argv[1:])
