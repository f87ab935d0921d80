"""The simulated hand's plan is streamed in windows (issue 38: memory constant in the number of taps), with the
same numbers, bit for bit, as the whole plan sampled up front."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

import stimuli
from devices.sim import SimDevice, ScriptedTrajectory, TapTrajectory
from devices.sim import device as sim_device
from renderer.config import RendererConfig
from renderer.loop import ServoLoop

FS = 10_000.0


def _random_plan(rng) -> TapTrajectory:
    return TapTrajectory(list(rng.uniform(0.02, 0.4, size=int(rng.integers(1, 5)))), n_taps=int(rng.integers(1, 30)),
                         approach_height_m=float(rng.uniform(0.002, 0.03)),
                         press_depth_m=float(rng.uniform(0.001, 0.01)), pause_s=float(rng.uniform(0.0, 0.2)))


def test_any_stretch_of_the_plan_is_the_whole_plans_slice_bit_for_bit():
    rng = np.random.default_rng(11)
    for _ in range(20):
        tr = _random_plan(rng)
        for fs in (FS, 3_000.0, 12_345.0):
            whole = tr.sample(fs)
            assert whole.size == tr.n_ticks(fs)
            for _ in range(15):
                lo = int(rng.integers(-10, whole.size + 10))
                hi = lo + int(rng.integers(0, 30_000))
                part = tr.sample_range(fs, lo, hi)
                assert np.array_equal(part, whole[max(lo, 0):max(min(hi, whole.size), max(lo, 0))])
            # the stretches a device streams, joined, are the whole plan
            joined = np.concatenate([tr.sample_range(fs, a, a + 997) for a in range(0, whole.size, 997)])
            assert np.array_equal(joined, whole)


def test_a_scripted_plan_streams_the_same_ticks():
    t = np.linspace(0.0, 3.0, 50)
    tr = ScriptedTrajectory(t, 0.01 * np.sin(3 * t))
    whole = tr.sample(FS)
    assert np.array_equal(np.concatenate([tr.sample_range(FS, a, a + 4_096) for a in range(0, whole.size, 4_096)]),
                          whole)


def test_the_plan_keeps_its_schedule_not_its_samples():
    """100 000 taps (~22 h at 10 kHz: 1.3 GB as samples) cost a few MB; the device holds one window."""
    tracemalloc.start()
    try:
        tr = TapTrajectory([0.05, 0.1, 0.2], n_taps=100_000)
        dev = SimDevice(sample="wood_on_foam")
        dev.set_user(tr, grip_N=lambda t: 2.0 + 0.0 * np.asarray(t))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert tr.n_ticks(FS) > 700_000_000
    assert peak < 20e6, peak
    traj, grip, k = dev.fused_plan()
    assert traj.size == grip.size == sim_device.PLAN_WINDOW_TICKS and k == 0
    assert tr.velocities_m_s[:4] == (0.05, 0.1, 0.2, 0.05) and len(tr.surface_times_s) == 100_000


def _python_run(dev, plan, grip):
    dev.set_user(plan, grip_N=grip)
    rows = []
    for k in range(int(plan.duration_s * FS) + 3_000):      # past the plan's end: the hand holds
        st = dev.read()
        rows.append((st.position_m, st.accel_m_s2, st.grip_N, dev.true_state()["hand_position_m"]))
        dev.command(0.4 * np.sin(k / 40.0))
    return np.array(rows), np.array([v for v in dev.true_state().values() if not isinstance(v, bool)])


def _loop_run(dev, plan, hand, until_every=None):
    dev.set_user(plan, grip_N=2.0, hand=hand)
    if until_every is None:   # chunks as long as the window allows
        res = ServoLoop(dev, RendererConfig(), stimuli.Pulse()).run(duration_s=plan.duration_s + 0.5)
    else:                     # chunks of a few ticks, a window ending at a chunk's end or inside one
        res = ServoLoop(dev, RendererConfig(until_every=until_every), stimuli.Pulse()).run(
            duration_s=plan.duration_s + 0.5, until=lambda lp: False)
    events = np.array([(e.t_s, e.incoming_velocity_m_s, e.max_penetration_m, e.peak_accel_m_s2) for e in res.events])
    return np.asarray(res.log["position_m"]), np.asarray(res.log["accel_m_s2"]), events


@pytest.mark.parametrize("path", ["python", "compiled", "compiled_until"])
def test_a_streamed_plan_runs_the_same_ticks_as_the_whole_plan(monkeypatch, path):
    """Windows of 1 000 ticks (dozens of refills, in ``command()`` or between the compiled loop's chunks) against
    the whole plan in one window: every reading, the hand's state and the events bit for bit."""
    plan = TapTrajectory([0.06, 0.15], n_taps=3)
    runs = []
    for window in (10**9, 1_000):
        monkeypatch.setattr(sim_device, "PLAN_WINDOW_TICKS", window)
        dev = SimDevice(sample="wood_on_foam", seed=5)
        if path == "python":
            runs.append(_python_run(dev, plan, lambda t: 1.5 + 0.5 * np.cos(np.asarray(t))))
        else:
            runs.append(_loop_run(dev, plan, None, 4 if path == "compiled_until" else None))
        traj, _, _ = dev.fused_plan()
        assert traj.size <= max(window, plan.n_ticks(FS))
    for whole, streamed in zip(*runs):
        assert whole.size > 0 and np.array_equal(whole, streamed)
    if path != "python":
        assert len(runs[0][2]) == 3                              # a contact event per tap
