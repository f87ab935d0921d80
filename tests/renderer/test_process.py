"""The servo loop in its own process (hardware mode): results, errors and stop requests cross the boundary."""

import functools
import multiprocessing as mp
import threading
import time

import pytest

from renderer import RendererConfig, run_in_process
from tests.renderer.fakes import make_failing_device, make_tap_device, make_tap_device_announced


def test_run_in_process_returns_the_result():
    res = run_in_process(make_tap_device, RendererConfig(), None, duration_s=0.3, realtime=False)
    assert res.stop_reason == "duration"
    assert res.timing["ticks"] == 3000
    assert len(res.events) == 1
    assert res.events[0].incoming_velocity_m_s == pytest.approx(0.1, rel=0.05)


def test_run_in_process_stop_event_ends_a_realtime_run():
    ctx = mp.get_context("spawn")
    stop, made = ctx.Event(), ctx.Event()

    def stop_once_running():
        # the child's start-up (a spawned interpreter importing numpy and numba, then the loop's set-up) takes
        # 0.5-3 s depending on the machine's load: count from the run's first tick, not from now
        if made.wait(30.0):
            time.sleep(1.0)
        stop.set()

    stopper = threading.Thread(target=stop_once_running, daemon=True)
    stopper.start()
    try:
        res = run_in_process(functools.partial(make_tap_device_announced, made), RendererConfig(), None,
                             realtime=True, stop_event=stop, timeout_s=30.0)
    finally:
        stop.set()
        stopper.join(35.0)
    assert res.stop_reason == "until"
    assert 0.2 < res.timing["wall_time_s"] < 10.0


def test_run_in_process_errors():
    with pytest.raises(ValueError, match="rate_hz=5000 differs"):
        run_in_process(make_tap_device, RendererConfig(rate_hz=5000.0), None, duration_s=0.1)
    with pytest.raises(RuntimeError, match="injected failure") as info:
        run_in_process(make_failing_device, RendererConfig(), None, duration_s=1.0, realtime=False)
    assert info.value.partial_result.stop_reason == "exception"
    assert info.value.partial_result.timing["ticks"] == 199


def test_run_in_process_with_a_device_string():
    stimuli = pytest.importorskip("stimuli")
    res = run_in_process("sim", RendererConfig(), stimuli.Pulse(), duration_s=0.5)
    assert res.timing["ticks"] == 5000 and res.transient == "pulse"
    assert res.device["name"] == "sim-joystick"
