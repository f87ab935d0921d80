"""3-D rendering: proxy + transient per servo tick on a 10,000-triangle mesh, and the 3-DOF sim's real-time factor.

Figures: (a) one tick of the 3-D law (``renderer.law3.law3_tick``: the god-object proxy against a
10,000-triangle torus through its BVH, the transient's sample along the normal, saturation, observer, log
row) while an endpoint presses into the torus and slides over it with a transient always playing: the median
of per-tick times from Python (each call timed) and of 1000-tick compiled batches; (b) ``renderer run
--device sim:3d --duration-s 30 --taps 40 --no-figure`` as a whole process (median of 7 after a warm-up, with
the load average, and the CPU time each process took, which a loaded machine stretches less), with the 3-D loop compiled ahead of time (``renderer compile-sim``, as ``make bench`` and a
user's first simulated run leave it) and JIT, and the compiled 3-D loop inside one process. Targets: (a) <= 5 us
median, (b) >= 100x real time.
"""

from __future__ import annotations

import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

import stimuli
from devices.sim import Sim3Device, TapTrajectory
from plumbing.jitcache import njit
from renderer import law3 as L3
from renderer.config import RendererConfig
from renderer.loop3 import ServoLoop3
from renderer.scene import Mesh, Scene

REPEATS = 5
TICKS = 20_000
#: whole-process runs per mode (after one warm-up run)
WHOLE_REPEATS = 7


@njit(cache=True, _nrt=False)
def _batch(c, w, obj, tri, node, stack, log, xs, ys, zs, t0, nbuf):
    """``len(xs)`` ticks of the law along the path, the transient restarted whenever it ends."""
    for k in range(xs.shape[0]):
        if w[L3.W_TJ] >= w[L3.W_TLEN]:
            w[L3.W_TJ] = 0.0
            w[L3.W_TLEN] = nbuf
        L3.law3_tick(c, w, obj, tri, node, stack, log, t0 + k * 1e-4, xs[k], ys[k], zs[k], 0.0, 2.0, 0)
    return xs.shape[0]


def _mesh_loop(tmp: Path) -> tuple[ServoLoop3, np.ndarray]:
    path = tmp / "torus.stl"
    torus = trimesh.creation.torus(major_radius=0.025, minor_radius=0.008, major_sections=100, minor_sections=50)
    torus.export(path)
    scene = Scene((Mesh(str(path), offset_m=(0.0, 0.0, -0.02)),))
    dev = Sim3Device()
    dev.set_user(0.0, grip_N=2.0)
    loop = ServoLoop3(dev, RendererConfig(stiffness_N_m=1000.0, scene=scene), stimuli.DecayingSinusoid())
    loop.prepare()
    loop.cap = TICKS
    loop.c[L3.C_CAP] = TICKS
    loop.log = np.zeros((L3.N_LOG, TICKS))
    with dev:
        loop._prime()
    wave = stimuli.DecayingSinusoid().waveform(0.2, 2.0, 1e4)
    loop.tview[:len(wave)] = wave
    # a path around the torus' top, 1 mm inside it, at ~0.1 m/s, bobbing in and out
    k = np.arange(TICKS)
    ang = 2 * np.pi * k / 15_000
    r = 0.025 + 0.004 * np.sin(2 * np.pi * k / 3000)
    zs = -0.02 + np.sqrt(np.maximum(0.008 ** 2 - (r - 0.025) ** 2, 0)) - 0.001 + 0.002 * np.sin(2 * np.pi * k / 700)
    path = np.stack([r * np.cos(ang), r * np.sin(ang), zs])
    return loop, path, len(wave), len(torus.faces)


def bench_tick() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        loop, path, nbuf, n_tri = _mesh_loop(Path(tmp))
        pk, c, w, log, stack = loop.packed, loop.c, loop.w, loop.log, loop.stack
        xs, ys, zs = (np.ascontiguousarray(a) for a in path)
        w0 = w.copy()
        _batch(c, w, pk.obj, pk.tri, pk.node, stack, log, xs[:10], ys[:10], zs[:10], 0.0, nbuf)   # compile
        batch = []
        for _ in range(REPEATS):
            w[:] = w0
            for j in range(0, TICKS, 1000):
                t0 = time.perf_counter_ns()
                _batch(c, w, pk.obj, pk.tri, pk.node, stack, log, xs[j:j + 1000], ys[j:j + 1000], zs[j:j + 1000],
                       j * 1e-4, nbuf)
                batch.append((time.perf_counter_ns() - t0) / 1000.0 / 1000.0)
        w[:] = w0
        tick = L3.law3_tick
        per = []
        contact = 0
        for j in range(TICKS):
            if w[L3.W_TJ] >= w[L3.W_TLEN]:
                w[L3.W_TJ], w[L3.W_TLEN] = 0.0, nbuf
            x, y, z = float(xs[j]), float(ys[j]), float(zs[j])
            t0 = time.perf_counter_ns()
            tick(c, w, pk.obj, pk.tri, pk.node, stack, log, j * 1e-4, x, y, z, 0.0, 2.0, 0)
            per.append((time.perf_counter_ns() - t0) / 1000.0)
            contact += log[16, j] >= 0
    return {"triangles": n_tri, "contact_fraction": contact / TICKS, "tick_us_median_python_call": statistics.median(per),
            "tick_us_p99_python_call": float(np.percentile(per, 99)), "tick_us_median_compiled_batch": statistics.median(batch)}


def _whole_process(mode: str, repeats: int) -> tuple[list[float], list[float]]:
    """Wall times (s) of ``renderer run --device sim:3d --duration-s 30 --taps 40 --no-figure`` processes
    with ``HFAM_SIM_AOT=mode`` (after one run that warms the OS file cache), and the CPU time (s, user +
    system) of each process and the processes it waited for (its ``git``): what the run costs, which the
    other work on a shared machine stretches less than its wall time."""
    walls, cpus = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats + 1):
            ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            proc = subprocess.run([sys.executable, "-m", "renderer", "run", "--device", "sim:3d", "--duration-s", "30",
                                   "--taps", "40", "--no-figure", "--force", "--out", str(Path(tmp) / f"r{r}")],
                                  check=True, capture_output=True, text=True, env=dict(os.environ, HFAM_SIM_AOT=mode))
            wall = time.perf_counter() - t0
            ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            if r:
                walls.append(wall)
                cpus.append(ru1.ru_utime - ru0.ru_utime + ru1.ru_stime - ru0.ru_stime)
            assert "300000 ticks" in proc.stdout, proc.stdout[-300:]
    return walls, cpus


def bench_sim(repeats: int = WHOLE_REPEATS) -> dict:
    dev = Sim3Device()
    dev.set_user(TapTrajectory(0.1, n_taps=40), grip_N=2.0)
    loop = ServoLoop3(dev, RendererConfig(stiffness_N_m=680.0))
    loop.run(duration_s=0.5)        # compile / load
    dev.set_user(TapTrajectory(0.1, n_taps=40), grip_N=2.0)
    t0 = time.perf_counter()
    res = loop.run(duration_s=30.0)
    wall = time.perf_counter() - t0
    # the whole process: with the loop compiled ahead of time (renderer.sim_aot, built first, as `make bench`
    # and a user's first simulated run do), then JIT with a warm numba cache
    subprocess.run([sys.executable, "-m", "renderer", "compile-sim"], check=True, capture_output=True)
    out = {"in_process_realtime_factor": 30.0 / wall, "events": len(res.events)}
    for label, mode in (("aot", "nobuild"), ("jit", "off")):
        load0 = os.getloadavg()[0]
        walls, cpus = _whole_process(mode, repeats)
        out[label] = {"runs_s": walls, "median_s": statistics.median(walls),
                      "realtime_factor": 30.0 / statistics.median(walls),
                      "cpu_runs_s": cpus, "cpu_median_s": statistics.median(cpus),
                      "load_average": (load0 + os.getloadavg()[0]) / 2}
    out["whole_process_s"] = out["aot"]["median_s"]
    out["whole_process_realtime_factor"] = out["aot"]["realtime_factor"]
    return out


def main() -> dict:
    a = bench_tick()
    print(f"   3-D law tick on a {a['triangles']}-triangle mesh (contact {100 * a['contact_fraction']:.0f} % of ticks, "
          f"transient playing): median {a['tick_us_median_python_call']:.2f} us per call from Python "
          f"(p99 {a['tick_us_p99_python_call']:.2f}), {a['tick_us_median_compiled_batch']:.2f} us per tick in "
          "compiled batches (target <= 5 us)", flush=True)
    b = bench_sim()
    print(f"   3-DOF sim, 30 s: compiled 3-D loop {b['in_process_realtime_factor']:.0f}x real time in one process",
          flush=True)
    for label, what in (("aot", "loop compiled ahead of time"), ("jit", "JIT, warm numba cache")):
        r = b[label]
        print(f"   whole `renderer run --device sim:3d --duration-s 30` process ({what}): median {r['median_s']:.3f} s "
              f"= {r['realtime_factor']:.1f}x real time (runs {', '.join(f'{w:.3f}' for w in r['runs_s'])}; load "
              f"average {r['load_average']:.1f} on {os.cpu_count()} cores; target >= 100x, ratio "
              f"{r['realtime_factor'] / 100:.2f}); CPU time median {r['cpu_median_s']:.3f} s = "
              f"{30.0 / r['cpu_median_s']:.1f}x", flush=True)
    return {**a, **b}


if __name__ == "__main__":
    main()
