"""Renderer benchmarks: controller compute per tick, closed-loop speed with the sim, real-time pacing, GIL isolation.

``python -m benchmarks renderer`` (or ``.venv/bin/python benchmarks/bench_renderer.py [--quick]``).
The machine is shared and noisy: every figure is a median over repeats.

1. compute: time from ``read()`` returning to ``command()`` being called
   (collision, events, transient, saturation, thermal), measured inside the
   loop, replaying a recorded sim tap sequence through a device whose
   read/command do nothing (so the numbers exclude device I/O). Also the
   whole tick (incl. logging and loop bookkeeping) with that device.
2. closed loop: the nonlinear sim device as fast as possible, x real time.
3. pacing: 10 s at 10 kHz in real time with the sim (sleep-then-spin and
   pure spin): achieved rate, p99/max period error, CPU use.
4. GIL: a busy UI/disk thread in the parent; servo loop in the same process
   versus in its own process (renderer.process).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

import stimuli
from devices.base import Device, DeviceState
from devices.sim import SimDevice, TapTrajectory
from renderer import RendererConfig, ServoLoop
from renderer.process import run_in_process
from renderer.run_figure import save_run_figure
from renderer.scene import Box, Scene, Sphere, Wall


def _sim(n_taps=10, velocity=0.15, grip=2.0):
    dev = SimDevice()
    traj = TapTrajectory(velocity, n_taps=n_taps)
    dev.set_user(traj, grip_N=grip)
    return dev, traj


def make_replay_device(position_m, accel_m_s2, grip_N):
    """A Device replaying recorded sensor arrays; read/command cost only an index step (no physics)."""
    class ReplayDevice(Device):
        def __init__(self):
            super().__init__()

            self.info = SimDevice().info
            self.x = [float(v) for v in position_m]
            self.a = [float(v) for v in accel_m_s2]
            self.g = [float(v) for v in grip_N]
            self.k = 0
            self.n = len(self.x)
            self.state = DeviceState()
            self.dt = 1.0 / self.info.servo_rate_hz

        def _open(self):
            pass

        def _close(self):
            pass

        def read(self):
            return self.state

        def command(self, current_A):
            k = self.k + 1
            if k == self.n:
                k = 0
            self.k = k
            st = self.state
            st.t_s = k * self.dt
            st.position_m = self.x[k]
            st.accel_m_s2 = self.a[k]
            st.grip_N = self.g[k]

        def _send_current(self, current_A):
            pass

    return ReplayDevice()


def bench_compute(repeats=5):
    dev, traj = _sim(n_taps=6)
    rec = ServoLoop(dev, RendererConfig(), stimuli.Pulse()).run(until=lambda lp: dev.trajectory_done)
    log = rec.log
    p50, p99, tick, event = [], [], [], []
    for _ in range(repeats):
        rdev = make_replay_device(log["position_m"], log["accel_m_s2"], log["grip_N"])
        res = ServoLoop(rdev, RendererConfig(), stimuli.Pulse()).run(max_ticks=len(log["position_m"]))
        assert len(res.events) == len(rec.events)
        p50.append(res.timing["compute_p50_us"])
        p99.append(res.timing["compute_p99_us"])
        tick.append(res.timing["wall_time_s"] / res.timing["ticks"] * 1e6)
        # the event work runs after command() on the crossing tick: it lengthens the next period
        per = np.diff(res.log["wall_ns"]) / 1000.0
        base = float(np.median(per))
        event.extend(per[ev.tick] - base for ev in res.events if ev.tick + 1 < len(res.log["wall_ns"]))
    print(f"   compute per tick (no device I/O, {len(log['position_m'])} ticks, {len(rec.events)} taps, pulse): "
          f"median {statistics.median(p50):.2f} us, p99 {statistics.median(p99):.2f} us "
          f"(targets <= 2 / <= 10 us)")
    print(f"   whole tick incl. logging + trivial device calls: {statistics.median(tick):.2f} us")
    print(f"   event work at a crossing (velocity fit, transient lookup; after command(), a cold code path): median "
          f"{statistics.median(event):.0f} us, max {max(event):.0f} us over {len(event)} events")
    # a composed 3-D scene (generic collision path instead of the inlined wall)

    scene = Scene((Wall(0.0), Sphere((0.0, 0.0, -0.1), 0.09), Box((0.0, 0.0, -0.05), (0.02, 0.02, 0.045))))
    rdev = make_replay_device(log["position_m"], log["accel_m_s2"], log["grip_N"])
    res = ServoLoop(rdev, RendererConfig(scene=scene), stimuli.Pulse()).run(max_ticks=len(log["position_m"]))
    print(f"   compute per tick, 3-object scene (wall + sphere + box): median {res.timing['compute_p50_us']:.2f} us, "
          f"p99 {res.timing['compute_p99_us']:.2f} us")
    return statistics.median(p50), statistics.median(p99)


def bench_closed_loop(repeats=3, seconds=5.0):
    """As fast as possible on the nonlinear sim: the compiled loop (law and physics in renderer.law.run_sim,
    the default for simulated devices) and the per-tick loop (one law_tick between read() and command(),
    what hardware runs), inside the process; then a whole 30 s ``renderer run`` process (target: >= 100x)."""
    out = {}
    for label, compiled in (("compiled", True), ("per tick", False)):
        dev, _ = _sim()
        ServoLoop(dev, RendererConfig(), compiled_sim=compiled).run(max_ticks=100)  # numba JIT warm-up
        factors, cpu_factors, cpu = [], [], []
        for _ in range(repeats):
            dev, _ = _sim()
            res = ServoLoop(dev, RendererConfig(), compiled_sim=compiled).run(duration_s=seconds)
            factors.append(res.timing["realtime_factor"])
            cpu_factors.append(res.timing["realtime_factor_cpu"])
            cpu.append(res.timing["cpu_percent"])
        out[label] = statistics.median(factors)
        print(f"   closed loop, nonlinear sim, {label}: {statistics.median(factors):.1f}x real time at 10 kHz "
              f"(runs {', '.join(f'{f:.1f}' for f in factors)}; target >= 100x, ratio "
              f"{statistics.median(factors) / 100:.2f}); per CPU second {statistics.median(cpu_factors):.1f}x "
              f"(the process got {statistics.median(cpu):.0f} % of a core)")
    print(f"   compiled / per tick: {out['compiled'] / out['per tick']:.2f}x")
    # a whole 30 s process: 40 taps (~31 s of plan) so the hand taps all the way, stopped at 30 s; the
    # loop compiled ahead of time (renderer.sim_aot, built first), then the JIT path with a warm numba cache
    subprocess.run([sys.executable, "-m", "renderer", "compile-sim"], check=True, capture_output=True)
    for label, mode in (("ahead-of-time compiled loop", "nobuild"), ("JIT, warm numba cache", "off")):
        walls = []
        with tempfile.TemporaryDirectory() as tmp:
            for r in range(max(repeats, 5) + 1):
                t0 = time.perf_counter()
                proc = subprocess.run([sys.executable, "-m", "renderer", "run", "--device", "sim", "--duration-s",
                                       "30", "--taps", "40", "--no-figure", "--force", "--out",
                                       os.path.join(tmp, f"run{r}")],
                                      check=True, capture_output=True, text=True,
                                      env=dict(os.environ, HFAM_SIM_AOT=mode))
                if r:  # the first run warms the OS file cache
                    walls.append(time.perf_counter() - t0)
                assert "300000 ticks" in proc.stdout, proc.stdout[-300:]
        med = statistics.median(walls)
        print(f"   whole process, renderer run --device sim --duration-s 30 --taps 40 ({label}): median {med:.3f} s "
              f"= {30 / med:.1f}x real time (runs {', '.join(f'{w:.3f}' for w in walls)}; target >= 100x, ratio "
              f"{30 / med / 100:.2f})")
        out["whole_process_30s" if mode == "nobuild" else "whole_process_30s_jit"] = 30 / med
    return out


def bench_pacing(seconds=10.0, modes=("sleep_spin", "spin")):
    out = {}
    for mode in modes:
        dev, _ = _sim(n_taps=30)
        ServoLoop(dev, RendererConfig()).run(max_ticks=100)
        res = ServoLoop(dev, RendererConfig(pacing=mode)).run(duration_s=seconds, realtime=True)
        tm = res.timing
        out[mode] = tm
        print(f"   real time {seconds:g} s at 10 kHz, pacing={mode}: achieved {tm['achieved_rate_hz']:.1f} Hz "
              f"(target >= 9990), period p50 {tm['period_p50_us']:.1f} us, error p99 "
              f"{tm['period_error_p99_us']:.1f} us / max {tm['period_error_max_us']:.0f} us, "
              f"overruns {tm['overruns']} ({100 * tm['overruns'] / tm['ticks']:.2f} %), lateness after the "
              f"deadline p50/p99 {tm['lateness_p50_us']:.1f}/{tm['lateness_p99_us']:.1f} us, "
              f"CPU {tm['cpu_percent']:.0f} %")
    return out


def _busy_ui_thread(stop: threading.Event):
    """Stand-in for UI/audio/disk work: pure-Python work, numpy and file writes."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "blob.bin")
        data = np.random.default_rng(0).standard_normal(200_000)
        while not stop.is_set():
            s = 0
            for i in range(20000):  # pure Python: holds the GIL
                s += i * i
            np.sort(data)
            with open(path, "wb") as fh:
                fh.write(data.tobytes())


def bench_gil(seconds=3.0):
    rows = {}
    for label in ("same process", "own process"):
        stop = threading.Event()
        th = threading.Thread(target=_busy_ui_thread, args=(stop,), daemon=True)
        th.start()
        try:
            if label == "same process":
                dev, _ = _sim(n_taps=10)
                ServoLoop(dev, RendererConfig()).run(max_ticks=100)
                res = ServoLoop(dev, RendererConfig(watchdog_overrun_s=1.0)).run(duration_s=seconds, realtime=True)
            else:
                res = run_in_process("sim", RendererConfig(watchdog_overrun_s=1.0), None, duration_s=seconds,
                                     realtime=True)
        finally:
            stop.set()
            th.join()
        tm = res.timing
        rows[label] = tm
        print(f"   busy UI/disk thread, servo loop in {label}: achieved {tm['achieved_rate_hz']:.0f} Hz, period "
              f"error p99 {tm['period_error_p99_us']:.0f} us / max {tm['period_error_max_us']:.0f} us, "
              f"overruns {tm['overruns']} ({100 * tm['overruns'] / tm['ticks']:.2f} %), lateness p99 "
              f"{tm['lateness_p99_us']:.0f} us")
    return rows


def bench_run_figure(repeats=3):
    """The run figure ``renderer run`` draws after a 30 s simulated run (``--no-figure`` skips it)."""
    dev, _ = _sim(n_taps=40)
    res = ServoLoop(dev, RendererConfig()).run(duration_s=30.0)
    times, cpu = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats + 1):
            t0, c0 = time.perf_counter(), time.process_time()
            save_run_figure(res, os.path.join(tmp, f"fig{r}"))
            if r:  # the first draw also imports matplotlib
                times.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
    med = statistics.median(times)
    print(f"   run figure of a 30 s run (run.png + run.svg + run.plot.csv, {res.timing['ticks']} ticks): median "
          f"{med:.3f} s wall, {statistics.median(cpu):.3f} s CPU of {repeats} (after matplotlib's import; the wall "
          f"time grows with the machine's load)")
    return med


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    quick = "--quick" in argv
    bench_compute(repeats=3 if quick else 5)
    bench_closed_loop(repeats=3, seconds=2.0 if quick else 5.0)
    bench_run_figure(repeats=3)
    bench_pacing(seconds=2.0 if quick else 10.0)
    bench_gil(seconds=2.0 if quick else 3.0)


if __name__ == "__main__":
    main()
