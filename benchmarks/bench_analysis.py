"""Benchmark: analysis of 1,000 subjects x 12 samples x 3 repetitions (tables only) must take < 3 s."""

from __future__ import annotations

import statistics
import tempfile
import time
import warnings
from pathlib import Path

N_SUBJECTS = 1000
BUDGET_S = 3.0


def main(repeats: int = 5) -> dict:
    from analysis.load import load_study
    from analysis.pipeline import AnalysisConfig, analyse, write_tables
    from analysis.synthetic import write_synthetic_study

    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data"
        t0 = time.perf_counter()
        write_synthetic_study(data, N_SUBJECTS, seed=1, missing={"S010": ["foam"]})
        gen_s = time.perf_counter() - t0
        total, load, cpu = [], [], []
        for _ in range(repeats):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                t0 = time.perf_counter()
                load_study(data)
                t1, c1 = time.perf_counter(), time.process_time()
                res = analyse(data, AnalysisConfig())
                write_tables(res, Path(tmp) / "report")
                t2, c2 = time.perf_counter(), time.process_time()
            cpu.append(c2 - c1)
            load.append(t1 - t0)
            total.append(t2 - t1)
        n_rows = len(res.study.trials)
    med, med_load, med_cpu = statistics.median(total), statistics.median(load), statistics.median(cpu)
    print(f"   data: {N_SUBJECTS} subjects x 12 samples x 3 repetitions, {n_rows} attempt rows "
          f"(generated in {gen_s:.2f} s)")
    print(f"   load+validate only: median {med_load:.3f} s")
    print(f"   full analysis (load, validate, tables, CSV): median {med:.3f} s of {repeats} "
          f"(min {min(total):.3f} s); budget {BUDGET_S:.1f} s -> {med / BUDGET_S:.0%} of budget")
    print(f"   CPU time of the full analysis: median {med_cpu:.3f} s (less sensitive to other load on the machine)")
    return {"median_s": med, "load_s": med_load, "cpu_s": med_cpu}


if __name__ == "__main__":
    main()
