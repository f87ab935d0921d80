"""Peak memory of ``renderer run --device sim`` against the number of taps and the run's length.

Each run is a fresh ``python -m renderer run --device sim --taps N --out DIR`` process; its peak resident set
(``ru_maxrss`` from ``os.wait4``) is taken, three runs per N, and the medians are printed with the growth per
tap between the two largest N; then the same for one tap and ``--duration-s`` 300 and 3000 s (the hand rests
after its tap). The servo log is a ring of ``log_capacity_s`` (60 s: ~77 taps) and the simulated hand's plan
is streamed in windows of ``devices.sim.device.PLAN_WINDOW_TICKS`` ticks, so beyond the ring's filling
neither grows; what still does is the run's list of contact events (~1 kB per tap), which ``--taps``' cap
(``renderer.config.MAX_RUN_TAPS``) bounds. ``python -m benchmarks run_memory``.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from renderer.config import MAX_RUN_TAPS

TAPS = (10, 300, 1000, 3000)
DURATIONS_S = (300.0, 3000.0)
REPEATS = 3
ROOT = Path(__file__).resolve().parents[1]


def peak_rss_bytes(taps: int, work: Path, duration_s: float | None = None) -> int:
    """Peak RSS (bytes) of one ``renderer run`` of ``taps`` taps on the sim (its files written under ``work``),
    ``duration_s`` long if given (else the taps' plan)."""
    out = Path(tempfile.mkdtemp(dir=work)) / "run"
    extra = [] if duration_s is None else ["--duration-s", f"{duration_s:g}"]
    proc = subprocess.Popen([sys.executable, "-m", "renderer", "run", "--device", "sim", "--taps", str(taps),
                             *extra, "--out", str(out)], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise RuntimeError(f"renderer run --taps {taps} {' '.join(extra)} failed: {proc.stderr.read().decode()[-500:]}")
    proc.stderr.close()
    return usage.ru_maxrss * 1024   # Linux: kB


def _median(label: str, runs) -> float:
    """Median (bytes) of ``runs`` (a list of peak RSS, bytes), printed on one line under ``label``."""
    m = statistics.median(runs)
    print(f"   {label}: peak RSS median {m / 2**20:7.1f} MB (runs: {', '.join(f'{p / 2**20:.1f}' for p in runs)})",
          flush=True)
    return m


def main() -> None:
    medians, by_duration = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for taps in TAPS:
            medians[taps] = _median(f"taps {taps:5d}", [peak_rss_bytes(taps, Path(tmp)) for _ in range(REPEATS)])
        for d in DURATIONS_S:
            by_duration[d] = _median(f"1 tap, --duration-s {d:5g}",
                                     [peak_rss_bytes(1, Path(tmp), d) for _ in range(REPEATS)])
    a, b = TAPS[-2], TAPS[-1]
    per_tap = (medians[b] - medians[a]) / (b - a)
    d0, d1 = DURATIONS_S
    print(f"   growth {a}->{b} taps: {per_tap / 1e3:.2f} kB per tap (the contact events; the hand's plan is "
          f"streamed); at the cap of {MAX_RUN_TAPS} taps: ~{(medians[b] + per_tap * (MAX_RUN_TAPS - b)) / 2**20:.0f} MB")
    print(f"   growth {d0:g}->{d1:g} s: {(by_duration[d1] - by_duration[d0]) / 2**20:+.1f} MB (the log is a ring of "
          f"60 s: full and wrapped in both)")
