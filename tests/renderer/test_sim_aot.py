"""The simulated closed loop compiled ahead of time (renderer.sim_aot) against the JIT one: same law, same
physics, the same log tick for tick; built by the background builder; loaded without numba; never stale."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import stimuli
from devices.sim import SimDevice, TapTrajectory
from renderer import sim_aot
from renderer.config import RendererConfig
from renderer.loop import ServoLoop

ROOT = Path(__file__).resolve().parents[2]


def _cli_run(env, out):
    return subprocess.run([sys.executable, "-m", "renderer", "run", "--device", "sim", "--taps", "1", "--out", str(out)],
                          env=env, cwd=ROOT, capture_output=True, text=True, timeout=180)


@pytest.fixture(scope="module")
def aot_dir(tmp_path_factory):
    """One build for the module, made the way users get it: the first ``renderer run`` on the sim (JIT)
    starts the detached background builder; the next run uses the build."""
    base = tmp_path_factory.mktemp("sim-loop")
    runs = tmp_path_factory.mktemp("runs")
    scratch = tmp_path_factory.mktemp("tmpdir")      # the processes' temporary folder: the build leaves nothing
    env = {**os.environ, "HFAM_SIM_AOT_DIR": str(base), "HFAM_SIM_AOT": "auto", "TMPDIR": str(scratch)}
    first = _cli_run(env, runs / "first")
    assert first.returncode == 0, first.stderr
    assert "compiling the simulated loop ahead of time in the background" in first.stderr
    assert json.loads((runs / "first" / "run.json").read_text())["aot"] is False
    key = subprocess.run([sys.executable, "-c", "from renderer import sim_aot; print(sim_aot.source_key())"],
                         env=env, cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()
    ext = base / key
    deadline = time.monotonic() + 240.0
    while not any(ext.glob("_hfam_sim_loop*")) and time.monotonic() < deadline:
        assert not (base / f"{key}.failed").exists(), (base / f"{key}.failed").read_text()
        time.sleep(0.5)
    assert any(ext.glob("_hfam_sim_loop*")), "the background build did not finish in 240 s"
    assert not (base / f"{key}.lock").exists()          # the builder released its lock
    assert json.loads((ext / "manifest.json").read_text())["key"] == key
    # nothing left in the temporary folder (numba.pycc's compiler check leaves a temp.c and a temp.cxx
    # folder in it unless the build redirects it), and only the build in the build folder
    assert sorted(p.name for p in scratch.iterdir()) == []
    assert sorted(p.name for p in ext.iterdir()) == sorted(["manifest.json", *(p.name for p in ext.glob("_hfam_sim_loop*"))])
    # the next run uses it and starts no builder; its log is the first run's, bit for bit
    second = _cli_run(env, runs / "second")
    assert second.returncode == 0 and "compiling" not in second.stderr, second.stderr
    assert json.loads((runs / "second" / "run.json").read_text())["aot"] is True
    with np.load(runs / "first" / "log.npz") as a, np.load(runs / "second" / "log.npz") as b:
        assert np.array_equal(a["current_A"], b["current_A"]) and np.array_equal(a["position_m"], b["position_m"])
    return base


def _use(monkeypatch, base, mode):
    monkeypatch.setenv("HFAM_SIM_AOT_DIR", str(base))
    monkeypatch.setenv("HFAM_SIM_AOT", mode)
    monkeypatch.setattr(sim_aot, "_loaded", {})


def _run(sample="placeholder", transient=None, velocities=(0.05, 0.1, 0.2), seconds=2.5):
    dev = SimDevice(seed=4)
    if sample != "placeholder":
        dev.set_sample(sample)
    dev.set_user(TapTrajectory(list(velocities), n_taps=3), grip_N=2.0)
    loop = ServoLoop(dev, RendererConfig(), transient)
    return loop.run(duration_s=seconds), dev


@pytest.mark.parametrize("sample,transient", [("placeholder", "pulse"), ("wood_on_foam", None),
                                              ("placeholder", "sinusoid")])
def test_aot_loop_gives_the_jit_log_tick_for_tick(aot_dir, monkeypatch, sample, transient):
    make = {"pulse": stimuli.Pulse, "sinusoid": stimuli.DecayingSinusoid, None: lambda: None}[transient]
    _use(monkeypatch, aot_dir, "off")
    jit, jdev = _run(sample, make())
    _use(monkeypatch, aot_dir, "nobuild")
    assert sim_aot.load() is not None
    aot, adev = _run(sample, make())
    assert jit.timing["ticks"] == aot.timing["ticks"] == 25_000
    assert len(jit.events) == len(aot.events) == 3
    for name in jit.log:
        if name in ("wall_ns", "compute_ns"):
            continue
        assert np.array_equal(jit.log[name], aot.log[name]), name
    assert [e.max_penetration_m for e in jit.events] == [e.max_penetration_m for e in aot.events]
    # the device's own state after the run (its Python side and the physics arrays) agrees as well
    assert np.array_equal(jdev.fused_arrays()[1], adev.fused_arrays()[1])
    assert jdev.read().position_m == adev.read().position_m and jdev.time_s == adev.time_s
    # the taps really happened: the wall (or the real sample, motor current 0 N/m wall above it) was hit
    assert np.max(jit.log["penetration_m"]) > 2e-4
    if transient is not None:
        assert np.max(np.abs(jit.log["force_transient_N"])) > 0.05


def test_aot_physics_step_is_the_kernel_tick(aot_dir, monkeypatch):
    from devices.sim import kernel

    _use(monkeypatch, aot_dir, "nobuild")
    mod = sim_aot.load()
    a, b = SimDevice(seed=2), SimDevice(seed=2)
    for d in (a, b):
        d.set_user(TapTrajectory(0.1), grip_N=1.5)
    b.use_compiled_step(mod.tick)
    rng = np.random.default_rng(0)
    for cmd in rng.normal(0.0, 1.0, 3000):
        a.command(float(cmd))
        b.command(float(cmd))
        sa, sb = a.read(), b.read()
        assert (sa.position_m, sa.accel_m_s2, sa.grip_N, sa.status) == (sb.position_m, sb.accel_m_s2, sb.grip_N,
                                                                        sb.status)
    assert a._tick_fn is kernel.tick and b._tick_fn is mod.tick
    with pytest.raises(ValueError, match="use_compiled_step needs a callable"):
        b.use_compiled_step(None)


@pytest.mark.parametrize("mode", ["off", "nobuild"])
def test_the_compiled_loop_lets_other_threads_run(aot_dir, monkeypatch, mode):
    """run_sim releases the GIL (JIT: ``nogil=True``; the build: numba's release_gil flag set for pycc), so
    a UI, audio or web thread keeps running while a compiled simulated run is inside a chunk. Chunks of
    200 000 ticks (~0.1-0.2 s) here, each timed by a wrapper around ``run_sim``; a thread that timestamps itself
    in a loop runs inside them. Measured as the share of each chunk's 5 ms bins in which the thread ran: holding
    the GIL, it could run in at most one switch interval (5 ms) of a chunk; released, it runs in most bins even
    when the OS shares the cores with other work (a longest gap, measured before, was the OS's: 76 ms in a
    188 ms chunk with 4 test workers on 2 cores)."""
    import threading

    from renderer import loop as loop_module

    _use(monkeypatch, aot_dir, mode)
    monkeypatch.setattr(loop_module, "COMPILED_POLL_TICKS", 200_000)
    run_sim, step = sim_aot.run_sim_function()
    assert (mode == "nobuild") == (type(run_sim).__name__ == "builtin_function_or_method")
    ServoLoop(SimDevice(seed=1), RendererConfig()).run(max_ticks=200)  # JIT warm-up outside the measurement
    chunks = []

    def timed(*args):
        t0 = time.perf_counter()
        k = run_sim(*args)
        if args[-1] > 0:          # a chunk of ticks (the warm-up call asks for none)
            chunks.append((t0, time.perf_counter()))
        return k

    monkeypatch.setattr(sim_aot, "run_sim_function", lambda: (timed, step))
    dev = SimDevice(seed=1)
    dev.set_user(TapTrajectory(0.1, n_taps=1), grip_N=2.0)  # one tap, then the hand rests: long chunks
    loop = ServoLoop(dev, RendererConfig())
    stop, stamps = threading.Event(), []

    def watch():
        last = 0.0
        while not stop.is_set():
            now = time.perf_counter()
            if now - last > 0.001:     # one stamp per ms at most
                stamps.append(now)
                last = now

    thread = threading.Thread(target=watch)
    thread.start()
    try:
        res = loop.run(duration_s=60.0)
    finally:
        stop.set()
        thread.join()
    assert res.timing["aot"] is (mode == "nobuild") and res.timing["ticks"] == 600_000
    t = np.asarray(stamps)
    bins = ran = 0
    long_chunks = [(t0, t1) for t0, t1 in chunks if t1 - t0 > 0.05]   # (the tap's event work ends a chunk early)
    for t0, t1 in long_chunks:
        edges = np.arange(t0, t1 - 0.005, 0.005)          # whole 5 ms bins inside the chunk
        inside = t[(t >= t0) & (t < edges[-1] + 0.005)]
        bins += len(edges)
        ran += len(np.unique(np.floor((inside - t0) / 0.005)))
    assert len(long_chunks) >= 2 and ran / bins > 0.4, (ran, bins, chunks)


def test_a_run_with_the_build_never_imports_numba(aot_dir, tmp_path):
    """The whole point: a simulated ``renderer run`` process with a build loads neither numba nor scipy."""
    code = ("import sys; from renderer.__main__ import main; "
            f"rc = main(['run', '--device', 'sim', '--taps', '2', '--out', {str(tmp_path / 'r')!r}]); "
            "print('NUMBA', 'numba' in sys.modules, 'scipy' in sys.modules, rc)")
    env = {**os.environ, "HFAM_SIM_AOT_DIR": str(aot_dir), "HFAM_SIM_AOT": "nobuild"}
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert "NUMBA False False 0" in out.stdout, out.stdout
    assert "2 events" in out.stdout


def test_a_stale_or_damaged_build_is_not_used(aot_dir, monkeypatch, tmp_path, capsys):
    _use(monkeypatch, aot_dir, "nobuild")
    assert sim_aot.load() is not None
    # other sources (an edited law or kernel) have another key: no build, the JIT path
    monkeypatch.setattr(sim_aot, "source_key", lambda target=sim_aot.LOOP1: "0123456789abcdef")
    monkeypatch.setattr(sim_aot, "_loaded", {})
    assert sim_aot.load() is None
    run_sim, step = sim_aot.run_sim_function()
    from renderer import law

    assert run_sim is law.run_sim and step is None
    # a damaged file under the right key: reported, not used, the results unchanged
    monkeypatch.setattr(sim_aot, "source_key", lambda target=sim_aot.LOOP1: "fedcba9876543210")
    monkeypatch.setattr(sim_aot, "_loaded", {})
    bad = sim_aot.extension_path("fedcba9876543210", aot_dir)
    bad.parent.mkdir()
    bad.write_bytes(b"not an ELF file")
    assert sim_aot.load() is None
    assert "did not load" in capsys.readouterr().err
    # and with HFAM_SIM_AOT=off the good build is not used either
    monkeypatch.undo()
    _use(monkeypatch, aot_dir, "off")
    assert sim_aot.load() is None


def test_mode_is_validated(monkeypatch):
    monkeypatch.setenv("HFAM_SIM_AOT", "sometimes")
    with pytest.raises(ValueError, match="HFAM_SIM_AOT must be one of auto, nobuild, off, got 'sometimes'"):
        sim_aot.mode()


def test_the_key_covers_every_compiled_source():
    """run_sim's callees live in these files; a new file that it imports must join SOURCES."""
    import renderer.law as law

    names = {p.name for p in sim_aot.SOURCES}
    assert {"law.py", "law_layout.py", "scene.py", "kernel.py", "layout.py"} <= names
    assert all(p.is_file() for p in sim_aot.SOURCES)
    called = {Path(f.py_func.__code__.co_filename).name for f in (law.law_tick, law.run_sim)}
    assert called <= names


def test_a_build_that_does_not_load_is_never_installed(tmp_path, monkeypatch):
    """The build is imported in a process of its own before it is installed (a kernel that needed numba's
    runtime, which the build does not link, would leave an undefined symbol): it is an error naming the
    build, or in the background a recorded failure; nothing is installed under the key."""
    def broken(out_dir, target=sim_aot.LOOP1):
        (Path(out_dir) / sim_aot.extension_path(base=tmp_path).name).write_bytes(b"\x7fELF, but not a module")

    monkeypatch.setattr(sim_aot, "_compile", broken)
    with pytest.raises(RuntimeError, match=r"the build .*_hfam_sim_loop.* does not load: ImportError"):
        sim_aot.build(tmp_path)
    assert not sim_aot.extension_path(base=tmp_path).exists()
    sim_aot.build(tmp_path, background=True)
    assert not sim_aot.extension_path(base=tmp_path).exists()
    failed = (tmp_path / f"{sim_aot.source_key()}.failed").read_text()
    assert failed.startswith("RuntimeError: the build") and "does not load" in failed
    assert [p.name for p in tmp_path.iterdir()] == [f"{sim_aot.source_key()}.failed"]   # no leftover build folder
