"""Peak memory of ``renderer run --device sim`` against the number of taps (issue 38, item 4).

Each run is a fresh ``python -m renderer run --device sim --taps N --out DIR`` process; its peak resident set
(``ru_maxrss`` from ``os.wait4``) is taken, three runs per N, and the medians are printed with the growth per
tap between the two largest N. The servo log is a ring of ``log_capacity_s`` (60 s: ~77 taps), so beyond it
the renderer's own memory is flat; what still grows is the simulated hand's plan, computed up front by
``devices.sim`` (position and grip, 16 bytes per servo tick, ~125 kB per tap at 10 kHz), which ``--taps``'
cap (``renderer.config.MAX_RUN_TAPS``) bounds. ``python -m benchmarks run_memory``.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from renderer.config import MAX_RUN_TAPS

TAPS = (10, 100, 200, 400)
REPEATS = 3
ROOT = Path(__file__).resolve().parents[1]


def peak_rss_bytes(taps: int, work: Path) -> int:
    """Peak RSS (bytes) of one ``renderer run`` of ``taps`` taps on the sim (its files written under ``work``)."""
    out = Path(tempfile.mkdtemp(dir=work)) / "run"
    proc = subprocess.Popen([sys.executable, "-m", "renderer", "run", "--device", "sim", "--taps", str(taps),
                             "--out", str(out)], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise RuntimeError(f"renderer run --taps {taps} failed: {proc.stderr.read().decode()[-500:]}")
    proc.stderr.close()
    return usage.ru_maxrss * 1024   # Linux: kB


def main() -> None:
    medians = {}
    with tempfile.TemporaryDirectory() as tmp:
        for taps in TAPS:
            peaks = [peak_rss_bytes(taps, Path(tmp)) for _ in range(REPEATS)]
            medians[taps] = statistics.median(peaks)
            print(f"   taps {taps:5d}: peak RSS median {medians[taps] / 2**20:7.1f} MB "
                  f"(runs: {', '.join(f'{p / 2**20:.1f}' for p in peaks)})", flush=True)
    a, b = TAPS[-2], TAPS[-1]
    per_tap = (medians[b] - medians[a]) / (b - a)
    print(f"   growth {a}->{b} taps: {per_tap / 1e3:.1f} kB per tap (the sim hand's plan: 16 B per tick); at the "
          f"cap of {MAX_RUN_TAPS} taps: ~{(medians[b] + per_tap * (MAX_RUN_TAPS - b)) / 2**20:.0f} MB")
