"""Servo loop behaviour on a small mass-spring test device (tests/renderer/fakes.py)."""

import math
import re
import time

import numpy as np
import pytest

from renderer import ContactEvent, RendererConfig, RunResult, ServoLoop
from renderer.loop import LOG_CHANNELS
from renderer.scene import Plane, Scene
from tests.renderer.fakes import MassDevice, tap_trajectory, make_info
from tests.support.stalls import watchdog_stalled


class BoxTransient:
    """Constant force ``a_Ns_m * v_in`` for ``n`` samples (a test transient with the stimuli interface)."""

    name = "box"

    def __init__(self, a_Ns_m=5.0, n=37, sign=1.0):
        self.a, self.n, self.sign = a_Ns_m, n, sign
        self.calls = []

    def max_samples(self, fs_hz):
        return self.n

    def check_device(self, info, fs_hz):
        return None

    def waveform(self, v_in_m_s, grip_N, fs_hz):
        self.calls.append((v_in_m_s, grip_N, fs_hz))
        return np.full(self.n, self.sign * self.a * v_in_m_s)


def crossings(pen):
    inside = pen > 0
    return np.flatnonzero(inside[1:] & ~inside[:-1]) + 1


def test_proportional_only_force_is_minus_k_x_in_steady_contact():
    k = 680.0
    tr = tap_trajectory(0.05, n_taps=1, press_m=0.003, dwell_s=0.4)
    dev = MassDevice(tr, grip_N=2.0)
    res = ServoLoop(dev, RendererConfig(stiffness_N_m=k)).run(duration_s=0.5)
    log = res.log
    pen, fp, cur = log["penetration_m"], log["force_prop_N"], log["current_A"]
    inside = pen > 0
    assert inside.sum() > 2500
    # exactly F = -k x (x = -d along the normal) on every contact tick, zero outside
    np.testing.assert_allclose(fp[inside], k * pen[inside], rtol=1e-12)
    assert np.all(fp[~inside] == 0.0)
    np.testing.assert_allclose(cur, fp / dev.info.force_per_amp_N_A, rtol=1e-12)
    # steady contact: hand spring and wall balance, k_h (x_d - x) = -k x  ->  x = k_h x_d / (k_h + k)
    steady = slice(4000, 5000)
    expected_x = dev.k_h * -0.003 / (dev.k_h + k)
    assert np.median(log["position_m"][steady]) == pytest.approx(expected_x, abs=2 * dev.q)
    assert np.all(np.abs(log["velocity_m_s"][steady]) < 0.01)
    assert len(res.events) == 1 and res.events[0].transient == "none"


def test_transient_starts_first_tick_after_crossing_and_lasts_its_duration():
    tr = tap_trajectory(0.1, n_taps=2)
    dev = MassDevice(tr, grip_N=2.0)
    box = BoxTransient(a_Ns_m=5.0, n=37)
    res = ServoLoop(dev, RendererConfig(stiffness_N_m=680.0), box).run(duration_s=tr.duration_s)
    ft = res.log["force_transient_N"]
    pen = res.log["penetration_m"]
    assert len(res.events) == 2
    assert [c[2] for c in box.calls] == [10000.0, 10000.0]
    for ev in res.events:
        n0 = ev.tick
        assert pen[n0] > 0 >= pen[n0 - 1]  # the event tick is the crossing tick
        assert ft[n0] == 0.0
        np.testing.assert_allclose(ft[n0 + 1:n0 + 38], 5.0 * ev.incoming_velocity_m_s, rtol=1e-12)
        assert ft[n0 + 38] == 0.0
        assert ev.transient == "box" and ev.transient_samples == 37 and ev.grip_N == 2.0
    assert np.count_nonzero(ft) == 2 * 37


def test_one_tap_one_event_with_a_loose_bouncing_grip():
    # a loose grip (0.5 N): the 20 ms pulse throws the handle 4.5 mm back up, twice per tap
    import stimuli

    tr = tap_trajectory(0.15, n_taps=3)
    dev = MassDevice(tr, grip_N=0.5)
    cfg = RendererConfig(stiffness_N_m=680.0, rearm_margin_m=0.002)
    res = ServoLoop(dev, cfg, stimuli.Pulse()).run(duration_s=tr.duration_s)
    pen = res.log["penetration_m"]
    cross = crossings(pen)
    assert len(res.events) == 3
    assert len(cross) >= 6  # it really bounced: more surface crossings than taps
    bounce = max(-pen[a:b].min() for a, b in zip(cross[:-1], cross[1:]) if (b - a) < 1500)
    assert bounce > cfg.rearm_margin_m  # and higher than the margin alone could catch
    # the events are the first crossing of each tap
    for ev, t_cross in zip(res.events, tr.crossings_s):
        assert ev.t_s == pytest.approx(t_cross, abs=0.01)
    # without the hold time the same taps fire extra events (the failure the latch prevents)
    res2 = ServoLoop(MassDevice(tr, grip_N=0.5), cfg.replace(rearm_hold_s=0.0), stimuli.Pulse()).run(
        duration_s=tr.duration_s)
    assert len(res2.events) > 3


def test_small_bounce_below_margin_is_latched():
    tr = tap_trajectory(0.15, n_taps=2)
    dev = MassDevice(tr, grip_N=1.0)
    box = BoxTransient(a_Ns_m=4.55, n=200)  # the Table 4.1 pulse
    res = ServoLoop(dev, RendererConfig(rearm_hold_s=0.0), box).run(duration_s=tr.duration_s)
    assert len(crossings(res.log["penetration_m"])) >= 4
    assert len(res.events) == 2


def test_separate_limits_clip_each_channel_at_its_own_level():
    info = make_info(current_continuous_A=1.0, current_peak_A=1.2, current_amplifier_A=5.0)
    tr = tap_trajectory(0.1, n_taps=1, press_m=0.01)
    # huge stiffness (one encoder count = 7.9 N) and transient: each channel saturates at its own limit
    cfg = RendererConfig(stiffness_N_m=1e6)

    def run(cfg, sign=1.0):
        box = BoxTransient(a_Ns_m=1000.0, n=20, sign=sign)
        res = ServoLoop(MassDevice(tr, info=info, grip_N=10.0), cfg, box).run(duration_s=0.3)
        n0 = res.events[0].tick
        win = slice(n0 + 1, n0 + 21)
        return res, res.log["penetration_m"][win] > 0, res.log["current_A"][win], res.log["clipped"][win]

    res, inside, cur, clip = run(cfg)
    assert inside.sum() >= 5
    np.testing.assert_allclose(cur[inside], 1.0 + 1.2, rtol=1e-12)  # sum below the amplifier's 5 A
    assert np.all(clip[inside] == 3)
    np.testing.assert_allclose(cur[~inside], 1.2, rtol=1e-12)
    assert np.all(clip[~inside] == 2)
    assert res.log["force_transient_N"][res.events[0].tick + 5] == pytest.approx(
        1000.0 * res.events[0].incoming_velocity_m_s)  # the log keeps the unsaturated request
    later = res.log["penetration_m"] > 0
    later[:res.events[0].tick + 30] = False
    assert later.sum() > 1000
    np.testing.assert_allclose(res.log["current_A"][later], 1.0, rtol=1e-12)
    assert np.all(res.log["clipped"][later] == 1)
    assert not res.events[0].clipped
    assert res.timing["clipped_ticks"]["transient"] == 20
    # a lower amplifier limit from the config clips the sum, and the event records it
    res, inside, cur, clip = run(cfg.replace(current_amplifier_A=2.0))
    np.testing.assert_allclose(cur[inside], 2.0, rtol=1e-12)
    assert np.all(clip[inside] == 7)
    assert res.events[0].clipped
    # a negative transient is limited at -peak independently: 1.0 - 1.2
    res, inside, cur, clip = run(cfg, sign=-1.0)
    np.testing.assert_allclose(cur[inside], -0.2, rtol=1e-9)
    assert inside.sum() >= 5


def test_limits_above_the_device_are_rejected_before_motion():
    dev = MassDevice()
    with pytest.raises(ValueError, match="current_peak_A=9.0 exceeds the device's"):
        ServoLoop(dev, RendererConfig(current_peak_A=9.0)).run(duration_s=0.01)
    assert dev.tick == 0


def _thermal_run(tmax_K, n_taps=12):
    info = make_info(thermal_time_constant_s=2.0, winding_max_temp_rise_K=tmax_K, current_continuous_A=1.0)
    tr = tap_trajectory(0.2, n_taps=n_taps, dwell_s=0.1, lift_s=0.08, pause_s=0.02)
    dev = MassDevice(tr, grip_N=2.0, info=info)
    # a strong 40 ms transient near the peak limit (3.6 A at 0.2 m/s) on every tap
    box = BoxTransient(a_Ns_m=0.9 * 4.0 * info.force_per_amp_N_A / 0.2, n=400)
    res = ServoLoop(dev, RendererConfig(stiffness_N_m=680.0), box).run(duration_s=tr.duration_s)
    return info, res


def test_thermal_model_attenuates_then_ends_repeated_strong_taps():
    info, res = _thermal_run(tmax_K=60.0)
    temp = res.log["temp_rise_K"]
    ft = res.log["force_transient_N"]
    assert len(res.events) == 12
    assert temp.max() < info.winding_max_temp_rise_K  # never reaches the winding limit
    assert temp.max() > 0.7 * info.winding_max_temp_rise_K  # ... but got close: the model was exercised
    strength = [np.abs(ft[ev.tick + 1:ev.tick + 401]).mean() for ev in res.events]
    first = 0.9 * 4.0 * info.force_per_amp_N_A / 0.2 * res.events[0].incoming_velocity_m_s
    assert strength[0] == pytest.approx(first, rel=1e-9)  # first tap: full strength throughout
    assert strength[-1] < 0.85 * strength[0]  # later taps attenuated as the winding heats up
    assert all(b <= a + 1e-9 for a, b in zip(strength[1:], strength[2:]))
    # starting hot (above the end threshold, 0.9 * 60 K): the transient is not played at all
    dev = MassDevice(tap_trajectory(0.2, n_taps=1), info=info)
    hot = ServoLoop(dev, RendererConfig(initial_temp_rise_K=58.0), BoxTransient(n=400)).run(duration_s=0.3)
    assert hot.events[0].thermal_gain == 0.0 and hot.events[0].transient_samples == 0
    assert np.all(hot.log["force_transient_N"] == 0.0)
    assert hot.log["temp_rise_K"].max() <= 58.0
    # the thermal model in the log is the first-order I^2 R model of the commanded current
    from renderer.thermal import simulate_temperature

    np.testing.assert_allclose(simulate_temperature(res.log["current_A"], info, 10000.0), temp, rtol=1e-9)
    # reference: with a generous winding limit nothing is attenuated and the temperature climbs past 60 K
    _, free = _thermal_run(tmax_K=500.0, n_taps=18)
    assert free.log["temp_rise_K"].max() > 60.0
    assert all(ev.thermal_gain == 1.0 for ev in free.events)


def test_nan_sensor_input_never_reaches_the_device():
    tr = tap_trajectory(0.1, n_taps=1)
    nan_ticks = {50, 51, 52, 1000, 1001, 1002, 1003, 1500}
    dev = MassDevice(tr, nan_at=nan_ticks)
    res = ServoLoop(dev, RendererConfig(), BoxTransient()).run(duration_s=0.2)
    applied = np.array(dev.applied)
    assert np.all(np.isfinite(applied))
    assert dev.rejected_commands == 0  # the loop itself never produced a NaN command
    flags = res.log["sensor_flags"]
    # log index n holds device tick n + 1 (the loop primes the device with one zero-current cycle)
    assert set(np.flatnonzero(flags & 1) + 1) == nan_ticks
    assert np.all(np.isfinite(res.log["position_m"]))
    assert res.log["position_m"][999] == res.log["position_m"][998]  # held at the last good value
    assert res.timing["bad_sensor_samples"] == len(nan_ticks)
    assert res.stop_reason == "duration"


def test_persistent_bad_sensor_stops_with_zero_output():
    tr = tap_trajectory(0.1, n_taps=1, height_m=0.003)
    dev = MassDevice(tr, nan_from=600)
    res = ServoLoop(dev, RendererConfig(max_bad_samples=5)).run(duration_s=1.0)
    assert res.stop_reason == "sensor"
    assert res.timing["ticks"] == 603  # device ticks 600..604 bad: log ticks 599..603
    assert dev.applied[-1] == 0.0 and dev.last_command_A == 0.0
    assert np.all(np.isfinite(dev.applied))
    assert "5 invalid sensor samples in a row" in res.error


def test_out_of_range_position_is_invalid():
    dev = MassDevice(x0_m=0.01)
    dev.nan_at = set()
    res_dev = MassDevice(x0_m=0.01)
    res_dev.state.position_m = 5.0  # a first sample far outside position_limit_m
    res = ServoLoop(MassDevice(x0_m=0.3), RendererConfig(max_bad_samples=3)).run(duration_s=0.01)
    assert res.stop_reason == "sensor"
    assert res.log["sensor_flags"][0] & 1


def test_exception_inside_the_loop_leaves_the_device_at_zero():
    tr = tap_trajectory(0.1, n_taps=1, press_m=0.005)
    dev = MassDevice(tr, raise_at=1500)  # during contact, with current flowing
    loop = ServoLoop(dev, RendererConfig())
    with pytest.raises(RuntimeError, match="injected failure"):
        loop.run(duration_s=1.0)
    assert max(abs(x) for x in dev.applied[:-1]) > 0.1
    assert dev.applied[-1] == 0.0 and dev.last_command_A == 0.0
    assert loop.result.stop_reason == "exception"
    assert "injected failure" in loop.result.error
    assert loop.result.timing["ticks"] == 0 or len(loop.result.log["t_s"]) > 0


class ExplodingTransient(BoxTransient):
    def waveform(self, v_in_m_s, grip_N, fs_hz):
        raise ZeroDivisionError("boom")


def test_exception_in_the_transient_zeroes_the_output():
    tr = tap_trajectory(0.1, n_taps=1)
    dev = MassDevice(tr)
    with pytest.raises(ZeroDivisionError):
        ServoLoop(dev, RendererConfig(stiffness_N_m=680.0), ExplodingTransient()).run(duration_s=1.0)
    assert dev.applied[-1] == 0.0


def test_ctrl_c_zeroes_the_output_and_keeps_the_partial_result():
    tr = tap_trajectory(0.1, n_taps=1, press_m=0.005)
    dev = MassDevice(tr)
    loop = ServoLoop(dev, RendererConfig())

    def interrupt(lp):
        if lp.ticks >= 1600:
            raise KeyboardInterrupt
        return False

    with pytest.raises(KeyboardInterrupt):
        loop.run(duration_s=1.0, until=interrupt)
    assert dev.applied[-1] == 0.0
    assert loop.result.stop_reason == "interrupted"
    assert len(loop.result.log["t_s"]) == 1600
    assert len(loop.result.events) == 1


class StallingDevice(MassDevice):
    def read(self):
        if self.tick == 300:
            time.sleep(1.5)   # far beyond the watchdog below, which a loaded machine's own stalls stay under
        return super().read()


def test_watchdog_zeroes_on_overrun_on_hardware():
    # a device that is not simulated (the watchdog guards real motors; a stalled sim just runs late)
    dev = StallingDevice(tap_trajectory(0.1, n_taps=1, height_m=0.0), grip_N=2.0, x0_m=0.0,
                         info=make_info(simulated=False))
    res = ServoLoop(dev, RendererConfig(watchdog_overrun_s=0.5)).run(duration_s=1.0)
    assert res.stop_reason == "watchdog"
    # its message names the period, as the suite's stall rule reads it (tests/support/stalls.py)
    assert watchdog_stalled(res.error), res.error
    assert not watchdog_stalled(re.sub(r"period \d+ us", "period 19000 us", res.error))   # a period under 20 ms
    # stalled reading device tick 300 (log tick 299); a loaded machine's own stall of over 0.5 s earlier would
    # trip the same watchdog sooner, which is as much a pass
    assert 0 < res.timing["ticks"] <= 299
    assert dev.applied[-1] == 0.0 and dev.last_command_A == 0.0
    assert res.timing["overruns"] >= 1


def test_realtime_pacing_holds_the_rate():
    dev = MassDevice(grip_N=2.0)
    res = ServoLoop(dev, RendererConfig()).run(duration_s=0.2, realtime=True)
    assert res.timing["ticks"] == 2000
    assert res.timing["wall_time_s"] >= 0.2
    # pacing never runs ahead of wall-clock time: tick n starts after its deadline (n + 1) * 100 us
    # (how close to the deadline is measured in benchmarks/bench_renderer.py, not here: the machine is shared)
    deadlines = (np.arange(2000) + 1) * 100_000
    assert np.all(res.log["wall_ns"] >= deadlines)


def test_motor_disabled_detects_events_without_current():
    tr = tap_trajectory(0.1, n_taps=2)
    dev = MassDevice(tr)
    res = ServoLoop(dev, RendererConfig(motor_enabled=False), BoxTransient()).run(duration_s=tr.duration_s)
    assert len(res.events) == 2
    assert all(ev.transient_samples == 0 for ev in res.events)
    assert np.all(res.log["current_A"] == 0.0) and all(x == 0.0 for x in dev.applied)
    assert res.events[0].max_penetration_m > 0.002  # nothing stopped the hand


def test_transient_longer_than_buffer_rejected_before_the_loop():
    dev = MassDevice()
    with pytest.raises(ValueError, match=r"needs up to 5000 samples .* buffer holds 2500"):
        ServoLoop(dev, RendererConfig(), BoxTransient(n=5000)).run(duration_s=0.1)
    assert dev.tick == 0 and dev.applied == []


def test_library_missing_grip_range_rejected_before_the_loop():
    stimuli = pytest.importorskip("stimuli")
    info = make_info(grip_range_N=(0.0, 10.0))
    lib = stimuli.HfamLibrary([0.05, 0.2], [1.0, 3.0], np.zeros((2, 2, 1000)), 10000.0, info.force_per_amp_N_A)
    dev = MassDevice(info=info)
    with pytest.raises(ValueError, match="grip"):
        ServoLoop(dev, RendererConfig(), lib).run(duration_s=0.1)
    assert dev.tick == 0


def test_hfam_library_played_through_current_into():
    stimuli = pytest.importorskip("stimuli")
    info = make_info(grip_range_N=(0.0, 10.0))
    t = np.arange(1000)
    shape = np.sin(2 * np.pi * t / 100) * np.exp(-t / 200)
    currents = np.stack([np.stack([0.5 * shape] * 2), np.stack([2.0 * shape] * 2)])
    lib = stimuli.HfamLibrary([0.05, 0.2], [0.0, 10.0], currents, 10000.0, info.force_per_amp_N_A)
    tr = tap_trajectory(0.125, n_taps=1)
    res = ServoLoop(MassDevice(tr, info=info), RendererConfig(), lib).run(duration_s=tr.duration_s)
    ev = res.events[0]
    expected = lib.current(ev.incoming_velocity_m_s, ev.grip_N) * info.force_per_amp_N_A
    np.testing.assert_allclose(res.log["force_transient_N"][ev.tick + 1:ev.tick + 1001], expected, rtol=1e-12)
    assert ev.transient == "hfam" and ev.transient_samples == 1000


def test_sim_rate_mismatch_rejected():
    with pytest.raises(ValueError, match="rate_hz=5000 differs"):
        ServoLoop(MassDevice(), RendererConfig(rate_hz=5000.0)).run(duration_s=0.1)


def test_three_d_scene_on_a_one_dof_device():
    from renderer.scene import Scene, Sphere, Wall

    # a sphere bulging 2 mm above the wall: contact starts at z = +2 mm
    scene = Scene((Wall(0.0), Sphere((0.0, 0.0, -0.048), 0.05)))
    tr = tap_trajectory(0.1, n_taps=1)
    res = ServoLoop(MassDevice(tr), RendererConfig(scene=scene)).run(duration_s=tr.duration_s)
    ev = res.events[0]
    assert res.log["position_m"][ev.tick] == pytest.approx(0.002, abs=2e-5)
    inside = res.log["penetration_m"] > 0
    np.testing.assert_allclose(res.log["force_prop_N"][inside], 680.0 * res.log["penetration_m"][inside])


def _rise(t_s: float) -> float:
    """Desired hand height (m): from 0 up at 0.1 m/s to 8 mm, held (a push up into a ceiling at 5 mm)."""
    return min(0.1 * t_s, 0.008)


@pytest.mark.parametrize("normal,nz", [((0.0, 0.0, -1.0), -1.0), ((0.0, 0.6, 0.8), 0.8)],
                         ids=["ceiling", "tilted"])
def test_transient_pushes_out_along_the_normal(normal, nz):
    """A contact transient pushes the handle out of the surface it hit, like the proportional force.

    Eq. 4.7/4.8 give the transient's magnitude (A |v_in|, positive at onset); on the 1-DOF device its
    force is the z component of that force along the surface's outward normal: ``F_t n_z``, as the
    wall's ``k d n_z`` (eq. 2.1). A ceiling (n_z = -1) hit from below is pushed down, not further up."""
    if nz < 0:
        dev, scene = MassDevice(_rise, x0_m=0.0), Scene((Plane((0.0, 0.0, 0.005), normal),))
    else:
        dev, scene = MassDevice(tap_trajectory(0.1, n_taps=1)), Scene((Plane((0.0, 0.0, 0.0), normal),))
    res = ServoLoop(dev, RendererConfig(scene=scene), BoxTransient(a_Ns_m=5.0, n=37)).run(duration_s=0.2)
    ev = res.events[0]
    ft, fp = res.log["force_transient_N"], res.log["force_prop_N"]
    assert ev.incoming_velocity_m_s == pytest.approx(0.1 * abs(nz), rel=0.1)  # speed along the normal
    np.testing.assert_allclose(ft[ev.tick + 1:ev.tick + 38], 5.0 * ev.incoming_velocity_m_s * nz, rtol=1e-12)
    assert np.sign(fp[ev.tick + 1]) == np.sign(nz)  # the same direction as the wall's own push


def test_save_and_load_round_trip(tmp_path):
    tr = tap_trajectory(0.1, n_taps=2)
    res = ServoLoop(MassDevice(tr), RendererConfig(), BoxTransient()).run(duration_s=tr.duration_s)
    res.save(tmp_path / "out")
    header = (tmp_path / "out" / "events.csv").read_text().splitlines()[0]
    assert header.startswith("t_s,incoming_velocity_m_s,grip_N,max_penetration_m,peak_accel_m_s2,transient,clipped")
    import json

    run = json.loads((tmp_path / "out" / "run.json").read_text())
    for key in ("sim_time_s", "wall_time_s", "ticks", "rate_hz", "period_p50_us", "period_p99_us",
                "period_max_us", "overruns"):
        assert key in run
    assert run["ticks"] == len(res.log["t_s"]) == round(tr.duration_s * 1e4)
    import importlib.metadata
    import platform

    versions = run["software_version"]   # what produced it: Python, the result-affecting packages, the code
    assert versions["python"] == platform.python_version()
    for dist in ("numpy", "scipy", "numba", "pandas", "statsmodels", "matplotlib"):
        assert versions[dist] == importlib.metadata.version(dist)
    assert versions["hfam-haptics"] == importlib.metadata.version("hfam-haptics")
    assert versions["git_commit"] is None or len(versions["git_commit"]) == 40
    back = RunResult.load(tmp_path / "out")
    assert back.events == res.events
    assert set(back.log) == {c[0] for c in LOG_CHANNELS}
    for name in back.log:
        np.testing.assert_array_equal(back.log[name], res.log[name])
    assert back.log["clipped"].dtype == np.uint8 and back.log["wall_ns"].dtype == np.int64


def test_log_keeps_the_most_recent_window_when_full():
    res = ServoLoop(MassDevice(), RendererConfig(log_capacity_s=0.05)).run(duration_s=0.2)
    assert res.timing["ticks"] == 2000 and res.timing["log_wrapped"]
    t = res.log["t_s"]
    assert len(t) == 500
    np.testing.assert_allclose(np.diff(t), 1e-4, rtol=1e-6)
    assert t[-1] == pytest.approx(0.2, abs=1e-9)  # log tick n reads device tick n + 1


class OnDeviceFake(MassDevice):
    on_device_rendering = True

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.info = make_info(capabilities=("streaming", "on_device"))
        self.configured = None
        self.stopped = False
        self.reads = 0

    def configure_rendering(self, wall, limits, transient):
        self.configured = (wall, limits, transient)

    def read(self):
        self.reads += 1
        self._step(0.0)  # the device renders by itself; time passes between frames
        return super().read()

    def pop_events(self):
        if self.reads == 100:
            return [{"t_s": 0.01, "incoming_velocity_m_s": 0.1, "grip_N": 2.0, "max_penetration_m": 0.001,
                     "peak_accel_m_s2": 30.0, "transient": "pulse", "clipped": False, "extra": 1}]
        return []

    def stop_rendering(self):
        self.stopped = True


def test_on_device_rendering_hook():
    dev = OnDeviceFake()
    box = BoxTransient()
    res = ServoLoop(dev, RendererConfig(stiffness_N_m=340.0, damping_N_s_m=1.0), box).run(max_ticks=300)
    wall, limits, transient = dev.configured
    # the wall's passivity observer goes to the device too: its limit at the continuous limit (1.26 A x the
    # device's force per amp), its leak per device tick (renderer.passivity.passivity_constants)
    f_c = 1.26 * dev.info.force_per_amp_N_A
    limit = f_c * f_c / (2 * 340.0) + f_c * 1e-3
    leak = 1.0 - math.exp(-1.0 / dev.info.servo_rate_hz)
    assert wall == pytest.approx({"height_m": 0.0, "stiffness_N_m": 340.0, "damping_N_s_m": 1.0,
                                  "rearm_margin_m": 0.002, "instability_limit_J": limit,
                                  "instability_leak": leak}, rel=1e-12)
    assert 0.01 < limit < 0.03 and leak > 0
    assert limits == {"continuous_A": 1.26, "peak_A": 4.0, "amplifier_A": 4.0}
    assert transient is box
    assert dev.stopped and dev.applied[-1] == 0.0
    assert res.events == [ContactEvent(0.01, 0.1, 2.0, 0.001, 30.0, "pulse", False)]
    assert len(res.log["t_s"]) == 300 and res.timing["on_device"]


def test_until_and_attributes():
    dev = MassDevice()
    seen = []

    def stop(lp):
        seen.append(lp.ticks)
        return lp.ticks >= 100

    res = ServoLoop(dev, RendererConfig(until_every=10)).run(until=stop)
    assert res.stop_reason == "until"
    assert seen[:3] == [10, 20, 30]
    assert res.timing["ticks"] == 100
    assert math.isclose(res.log["t_s"][-1], 0.01)


def test_no_per_tick_allocation():
    import tracemalloc

    def peak(ticks):
        dev = MassDevice(tap_trajectory(0.1, n_taps=3), grip_N=2.0, substeps=1, record=False)
        loop = ServoLoop(dev, RendererConfig(log_capacity_s=0.1), BoxTransient(n=100))
        loop.prepare()
        tracemalloc.start()
        try:
            loop.run(max_ticks=ticks)
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    short, long = peak(2000), peak(6000)
    # 3x the ticks (and 2 events instead of 1) must not need more memory: the log is a preallocated ring
    assert long - short < 20_000, (short, long)


def test_entry_damping_only_while_entering():
    k, b = 680.0, 3.0
    tr = tap_trajectory(0.2, n_taps=1)
    res = ServoLoop(MassDevice(tr), RendererConfig(stiffness_N_m=k, damping_N_s_m=b)).run(duration_s=tr.duration_s)
    log = res.log
    pen, vel, fp = log["penetration_m"], log["velocity_m_s"], log["force_prop_N"]
    entering = (pen > 0) & (vel < 0)
    leaving = (pen > 0) & (vel >= 0)
    assert entering.sum() > 20 and leaving.sum() > 20
    np.testing.assert_allclose(fp[entering], k * pen[entering] - b * vel[entering], rtol=1e-12)
    np.testing.assert_allclose(fp[leaving], k * pen[leaving], rtol=1e-12)
    # the per-tick estimate is the sliding least-squares slope of the logged positions (renderer.velocity)
    from renderer.velocity import ls_velocity

    np.testing.assert_allclose(vel[100:], ls_velocity(log["position_m"], 1e4, 20)[100:], atol=1e-9)


def test_request_stop_from_another_thread():
    import threading

    dev = MassDevice()
    loop = ServoLoop(dev, RendererConfig())

    def stop_once_running():
        # the request comes once the loop has run 600 ticks (it counts what it sends: dev.applied), not after
        # a wall-clock delay the loop's start-up may outlast on a loaded machine
        while len(dev.applied) < 600:
            time.sleep(0.001)
        loop.request_stop()

    stopper = threading.Thread(target=stop_once_running, daemon=True)
    stopper.start()
    res = loop.run(duration_s=5.0, realtime=True)
    stopper.join(timeout=5.0)
    assert res.stop_reason == "stopped"
    assert 500 < res.timing["ticks"] < 40000
    assert dev.applied[-1] == 0.0


def test_stalled_simulation_is_not_stopped_by_the_watchdog():
    dev = StallingDevice(grip_N=2.0)
    res = ServoLoop(dev, RendererConfig(watchdog_overrun_s=0.02)).run(duration_s=0.05, realtime=True)
    assert res.stop_reason == "duration" and res.timing["overruns"] >= 1


def test_events_csv_with_numpy_scalars(tmp_path):
    ev = ContactEvent(np.float64(0.5), np.float64(0.1), np.float32(2.0), np.float64(0.001), 3.0, "pulse",
                      np.bool_(True), np.int64(7))
    res = RunResult(events=[ev], log={"t_s": np.zeros(2)}, timing={"ticks": 2})
    res.save(tmp_path)
    row = (tmp_path / "events.csv").read_text().splitlines()[1]
    assert row == "0.5,0.1,2.0,0.001,3.0,pulse,true,7,0,1.0"
    assert RunResult.load(tmp_path).events[0] == ContactEvent(0.5, 0.1, 2.0, 0.001, 3.0, "pulse", True, 7)


def test_starting_inside_the_surface_fires_no_event_until_it_left():
    # the hand holds the handle 2 mm inside the wall: no crossing from outside, no event, but full wall force
    res = ServoLoop(MassDevice(x0_m=-0.002, grip_N=2.0), RendererConfig()).run(duration_s=0.2)
    assert res.events == []
    assert np.all(res.log["force_prop_N"][:10] > 0)
