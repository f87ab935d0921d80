"""Start-up of every command: ``python -m <package> --help`` and a 2 s simulated run.

``python -m benchmarks startup`` (or ``.venv/bin/python benchmarks/bench_startup.py [--quick]``).
Whole-process wall time, median of 5 runs each (after one warm-up run, so the
numba cache and the OS file cache are warm):

* ``python -m <package> --help`` for devices, renderer, stimuli, study and
  analysis, and ``python -m <package> <command> --help`` for every command:
  target 0.3 s each;
* ``python -m renderer run --device sim --duration 2``: target 0.6 s (with the simulated loop compiled
  ahead of time, ``renderer.sim_aot``; the JIT path with a warm numba cache is printed beside it).

For each figure the ratio to its target is printed, and for the slowest
``--help`` and the run the top entries of ``python -X importtime`` (cumulative
microseconds per imported module) so a regression shows where it comes from.
The machine is shared: the medians move with other load; the importtime
breakdown does not depend on it as much.
"""

from __future__ import annotations

import importlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
HELP_TARGET_S = 0.3
RUN_TARGET_S = 0.6
PACKAGES = ("devices", "renderer", "stimuli", "study", "analysis")


def _commands(package: str) -> list[str]:
    """The subcommands a package's ``__main__`` lists (from its table, without importing them)."""

    main = importlib.import_module(f"{package}.__main__")
    return [c.name for c in main.COMMANDS]


def wall_times(argv: list[str], repeats: int, cwd: Path, **env_extra: str) -> list[float]:
    """Whole-process wall time (s) of ``python argv`` run ``repeats`` times after one warm-up run."""
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="", **env_extra)
    out = []
    for k in range(repeats + 1):
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, *argv], cwd=cwd, env=env, capture_output=True, text=True)
        dt = time.perf_counter() - t0
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(argv)} failed ({proc.returncode}): {proc.stderr.strip()[-400:]}")
        if k:
            out.append(dt)
    return out


def importtime_top(argv: list[str], cwd: Path, n: int = 8) -> list[tuple[int, int, str]]:
    """The ``n`` imports with the largest cumulative time under ``python -X importtime argv``.

    Returns
    -------
    list of (cumulative_us, self_us, module)
    """
    proc = subprocess.run([sys.executable, "-X", "importtime", *argv], cwd=cwd, capture_output=True, text=True)
    rows = []
    for line in proc.stderr.splitlines():
        if not line.startswith("import time:") or "cumulative" in line:
            continue
        self_us, cum_us, name = (x.strip() for x in line.removeprefix("import time:").split("|"))
        rows.append((int(cum_us), int(self_us), name.strip()))
    rows.sort(reverse=True)
    return rows[:n]


def _show_top(argv: list[str], cwd: Path, n: int = 8) -> None:
    print(f"     -X importtime, top {n} cumulative: " + "; ".join(
        f"{name} {cum / 1e3:.0f} ms" for cum, _, name in importtime_top(argv, cwd, n)))


def main(argv=None) -> dict:
    argv = sys.argv[1:] if argv is None else argv
    repeats = 3 if "--quick" in argv else 5
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        cwd = Path(tmp)  # not the repository: what an installed package costs, not the source tree
        env_path = os.environ.get("PYTHONPATH", "")
        os.environ["PYTHONPATH"] = str(ROOT) + (os.pathsep + env_path if env_path else "")
        try:
            worst = (0.0, None)
            for package in PACKAGES:
                for cmd in [None, *_commands(package)]:
                    args = ["-m", package] + ([cmd] if cmd else []) + ["--help"]
                    med = statistics.median(wall_times(args, repeats, cwd))
                    results[" ".join(args[1:])] = med
                    print(f"   python -m {' '.join(args[1:]):28s} median {med:.3f} s of {repeats}; target "
                          f"{HELP_TARGET_S:.1f} s -> {med / HELP_TARGET_S:.2f}x", flush=True)
                    worst = max(worst, (med, args))
            print(f"   slowest --help: python {' '.join(worst[1])} ({worst[0]:.3f} s)")
            _show_top(worst[1], cwd)
            run = ["-m", "renderer", "run", "--device", "sim", "--duration-s", "2", "--no-figure", "--force", "--out",
                   str(cwd / "run")]  # the run figure (matplotlib) is measured apart: bench_renderer
            # the simulated loop compiled ahead of time (renderer.sim_aot; built once, as a user's first
            # simulated run does in the background), then the JIT path with a warm numba cache for comparison
            subprocess.run([sys.executable, "-m", "renderer", "compile-sim"], cwd=cwd, check=True, capture_output=True)
            for label, mode in (("ahead-of-time compiled loop", "nobuild"), ("JIT, warm numba cache", "off")):
                times = wall_times(run, repeats, cwd, HFAM_SIM_AOT=mode)
                med = statistics.median(times)
                results[f"renderer run --device sim --duration 2 ({mode})"] = med
                print(f"   python -m renderer run --device sim --duration 2 (whole process, {label}): median "
                      f"{med:.3f} s of {repeats} (min {min(times):.3f} s); target {RUN_TARGET_S:.1f} s -> "
                      f"{med / RUN_TARGET_S:.2f}x")
            results["renderer run --device sim --duration 2"] = results["renderer run --device sim --duration 2 (nobuild)"]
            _show_top(run, cwd)
        finally:
            os.environ["PYTHONPATH"] = env_path
            if not env_path:
                del os.environ["PYTHONPATH"]
    return results


if __name__ == "__main__":
    main()
