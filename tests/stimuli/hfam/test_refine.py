"""Iterative refinement of HFAM transients by playback on the sim and correction (stimuli.hfam.refine)."""

from __future__ import annotations

import pytest

from devices.recording import record_taps
from devices.sim import SimDevice
from stimuli.hfam import BuildSettings, build_library
from stimuli.hfam.refine import RefineSettings, refine_library
from stimuli.recordings import Tap


def test_refinement_lowers_the_error_of_every_cell():
    dev = SimDevice(seed=0, sample="wood_on_foam")
    fs = dev.info.servo_rate_hz
    raw = [t for v in (0.06, 0.1) for t in record_taps(dev, [v], grip_N=2.0,
                                                      trajectory_options={"press_depth_m": v * 0.045 / 1.5})]
    taps = [Tap(i, v, t, a) for i, (v, t, a) in enumerate(raw)]
    model = dev.linear_model(2.0)              # the analytic model (prescribed hand): deliberately imperfect
    bs = BuildSettings(n_velocities=2, peak_current_A=dev.info.current_peak_A, scale_to_limit=True)
    lib, _ = build_library(taps, fs, [("linear", model)], bs, force_per_amp_N_A=dev.info.force_per_amp_N_A)
    lines = []
    new, hist = refine_library(lib, [("linear", model)], lambda: SimDevice(seed=0),
                               RefineSettings(iterations=3, gain=0.7), bs, log=lines.append)
    assert len(hist) == 4 and len(lines) == 4 and "iteration 0" in lines[0]
    before = {(v, g): e for v, g, e, _ in hist[0]["cells"]}
    after = {(v, g): e for v, g, e, _ in hist[-1]["cells"]}
    assert all(after[c] <= before[c] for c in before)
    assert hist[-1]["median_nrmse"] < 0.8 * hist[0]["median_nrmse"]
    assert new.metadata["refinement"]["iterations"] == 3
    assert new.currents_A.shape == lib.currents_A.shape
    assert abs(new.currents_A).max() <= dev.info.current_peak_A + 1e-12


def test_refine_settings_validated():
    with pytest.raises(ValueError, match="iterations"):
        RefineSettings(iterations=0)
    with pytest.raises(ValueError, match="gain"):
        RefineSettings(gain=1.5)
