"""Lab Streaming Layer: what publishing costs the servo loop (``renderer run --lsl``, ``study run --lsl``).

The simulated device's compiled loop runs a 5 s tapping window three ways -- no callback, the ``until``
callback alone (returns False), and the callback with the state stream (:class:`plumbing.lsl.ServoStream`, 1 kHz
of the 10 kHz loop) -- and, streaming, with a consumer that has stalled (the publishing thread blocked: the
queue fills and chunks are dropped, the servo goes on). Printed: the callback's cost per call (median and 99th
percentile, microseconds: the servo's time between two ``until_every`` chunks) and each run's wall time
(medians of 5); the publishing thread's push happens outside the callback.
"""

from __future__ import annotations

import statistics
import threading
import time

import numpy as np

from devices.registry import make_device
from devices.sim import TapTrajectory
from plumbing.lsl import ServoStream, open_publisher
from renderer import RendererConfig, ServoLoop


class Timed:
    """Wrap a callback and time each call."""

    def __init__(self, inner) -> None:
        self.inner, self.costs = inner, []

    def begin(self, loop) -> None:
        if hasattr(self.inner, "begin"):
            self.inner.begin(loop)

    def __call__(self, loop) -> bool:
        t = time.perf_counter_ns()
        r = self.inner(loop)
        self.costs.append(time.perf_counter_ns() - t)
        return r


def run_once(callback) -> float:
    dev = make_device("sim", seed=1)
    dev.open()
    dev.set_user(TapTrajectory([0.1] * 6, n_taps=6), grip_N=2.0)
    loop = ServoLoop(dev, RendererConfig(stiffness_N_m=680.0))
    if callback is not None:
        callback.begin(loop)
    t = time.perf_counter()
    loop.run(duration_s=5.0, until=callback)
    wall = time.perf_counter() - t
    dev.close()
    return wall


def main() -> None:
    publisher, why = open_publisher("bench", "hfam-bench", 1000.0)
    if publisher is None:
        print(f"   skipped: {why}")
        return
    rows = []
    for label, make in (("no callback", lambda: None), ("until callback only", lambda: Timed(lambda lp: False)),
                        ("state stream 1 kHz", lambda: Timed(ServoStream(publisher)))):
        walls, costs = [], []
        for _ in range(5):
            cb = make()
            walls.append(run_once(cb))
            costs += cb.costs if cb is not None else []
        rows.append((label, walls, costs))
    # a stalled consumer: the thread cannot push (blocked), the queue fills, chunks are dropped
    gate = threading.Event()
    blocked = publisher.outlets["state"]
    orig = blocked.push_chunk
    blocked.push_chunk = lambda *a, **k: (gate.wait(), orig(*a, **k))
    cb = Timed(ServoStream(publisher))
    walls = [run_once(cb) for _ in range(3)]
    rows.append(("stalled consumer", walls, cb.costs))
    dropped = publisher.dropped
    gate.set()
    record = publisher.close()
    base = statistics.median(rows[0][1])
    for label, walls, costs in rows:
        c = np.asarray(costs, float) / 1000.0
        cost = f"callback p50 {np.median(c):6.1f} us, p99 {np.percentile(c, 99):6.1f} us" if len(c) else " " * 38
        print(f"   {label:22s} {cost}; 5 s window in {statistics.median(walls):.3f} s wall "
              f"({statistics.median(walls) / base:.2f}x the loop alone)")
    print(f"   stalled consumer: {dropped} chunks dropped, the servo never waited; {record['samples']} samples pushed")
