"""The demo's simulated tap: one hand for the recordings and every rendering (docs/demo.md, "The simulated tap")."""

import numpy as np
import pytest

from devices.recording import record_taps
from devices.sim import SimDevice, TapTrajectory
from renderer.demo import runs
from renderer.demo.cache import cache_key
from stimuli.hfam.pipeline import TAP_STOP_TIME_S, PipelineSettings, tap_press_depth_m, tap_trajectory_options


@pytest.mark.parametrize("v", [0.05, 0.11, 0.3])
def test_the_hand_comes_to_rest_stop_time_after_contact(v):
    traj = TapTrajectory(v, 1, **tap_trajectory_options(v))
    t_surface = traj.surface_times_s[0]
    d = tap_press_depth_m(v)
    assert d == pytest.approx(v * TAP_STOP_TIME_S / 1.5)
    x = traj.position(np.array([t_surface + 0.9 * TAP_STOP_TIME_S, t_surface + TAP_STOP_TIME_S,
                                t_surface + TAP_STOP_TIME_S + 0.01]))
    assert x[0] > -d + 1e-9            # still moving 0.9 T after contact
    assert x[1] == pytest.approx(-d)   # at rest T after contact ...
    assert x[2] == pytest.approx(-d)   # ... and stays there (dwell)


def test_record_taps_passes_the_trajectory_options():
    """record_taps(trajectory_options=...) reaches the simulated hand: the press changes the recorded taps."""
    accels = []
    for press in (0.002, 0.008):
        dev = SimDevice(sample="wood_on_foam")
        with dev:
            taps = record_taps(dev, [0.1], trajectory_options={"press_depth_m": press}, window_s=0.2)
        assert len(taps) == 1 and taps[0][0] == pytest.approx(0.1, rel=0.1)
        accels.append(taps[0][2])
    # same impact, different push-through after it (the hand brakes 10 vs 40 ms after contact)
    assert np.max(np.abs(accels[0] - accels[1])) > 1.0
    with pytest.raises(ValueError, match="press_depth_m"):
        record_taps(SimDevice(sample="wood_on_foam"), [0.1], trajectory_options={"press_depth_m": -1.0})


def test_tap_sim_uses_the_same_hand():
    """A shorter stop time (shallower aim) penetrates a proportional wall less: tap_sim follows stop_time_s."""
    firm = [r for r in runs.RENDERINGS if r.name == "firm"][0]
    pen = {}
    for stop in (0.03, 0.09):
        dev = SimDevice(seed=3)
        with dev:
            tr = runs.tap_sim(dev, firm, None, 0.1, 2.0, dev.info.servo_rate_hz, stop_time_s=stop)
        assert tr.found
        pen[stop] = tr.penetration_m
    assert pen[0.03] < 0.8 * pen[0.09]


def test_stop_time_is_validated_and_keyed():
    with pytest.raises(ValueError, match="tap_stop_time_s"):
        PipelineSettings(tap_stop_time_s=0.0)
    assert cache_key(PipelineSettings()) != cache_key(PipelineSettings(tap_stop_time_s=0.06))
