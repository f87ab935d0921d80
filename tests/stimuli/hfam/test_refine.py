"""Iterative refinement of HFAM transients by playback on the sim and correction (stimuli.hfam.refine)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from devices.recording import record_taps
from devices.sim import SimDevice
from stimuli.hfam import BuildSettings, build_library
from stimuli.hfam.refine import RefineSettings, _normal_equations, box_step, recording_targets, refine_library
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
    # the cells held at the refinement's clip are listed (and only they): section 4.4.3's saturation, which the
    # renderer's amplifier limit no longer shows for a refined library
    ref = new.metadata["refinement"]
    limit = ref["current_limit_A"]
    assert limit == pytest.approx(RefineSettings().headroom * dev.info.current_peak_A)
    peaks = np.max(np.abs(new.currents_A), axis=-1)
    listed = {(v, g) for v, g, _ in ref["cells_at_limit"]}
    for i, v in enumerate(new.velocities_m_s):
        for j, g in enumerate(new.grips_N):
            assert ((float(v), float(g)) in listed) == bool(peaks[i, j] >= 0.99 * limit), (v, g, peaks[i, j])


def test_refine_settings_validated():
    with pytest.raises(ValueError, match="iterations"):
        RefineSettings(iterations=0)
    with pytest.raises(ValueError, match="gain"):
        RefineSettings(gain=1.5)


def _sim_library(velocities=(0.06, 0.1)):
    dev = SimDevice(seed=0, sample="wood_on_foam")
    fs = dev.info.servo_rate_hz
    raw = [t for v in velocities for t in record_taps(dev, [v], grip_N=2.0,
                                                      trajectory_options={"press_depth_m": v * 0.045 / 1.5})]
    taps = [Tap(i, v, t, a) for i, (v, t, a) in enumerate(raw)]
    bs = BuildSettings(n_velocities=len(velocities), peak_current_A=dev.info.current_peak_A, scale_to_limit=True)
    return dev, bs, taps, fs


def test_lag_alignment_separates_delay_from_shape():
    """A response late by the device's own delay is not a shape error (RefineSettings.max_lag_s)."""
    dev, bs, taps, fs = _sim_library()
    model = dev.linear_model(1.0)
    lib, _ = build_library(taps, fs, [("linear", model)], bs, force_per_amp_N_A=dev.info.force_per_amp_N_A)
    _, plain = refine_library(lib, [("linear", model)], lambda: SimDevice(seed=0),
                              RefineSettings(iterations=1, max_lag_s=0.0), bs)
    _, aligned = refine_library(lib, [("linear", model)], lambda: SimDevice(seed=0),
                                RefineSettings(iterations=1, max_lag_s=0.001), bs)
    # the same played transients (iteration 0): aligned within 1 ms their error can only be lower
    e0 = [c[2] for c in plain[0]["cells"]]
    e1 = [c[2] for c in aligned[0]["cells"]]
    assert all(b <= a + 1e-12 for a, b in zip(e0, e1))
    assert len(e0) == len(e1) == 2


def test_amplitude_matched_model_sets_pick_the_nearest_sweep():
    """Each cell's correction goes through the model set whose sweep amplitude is nearest to a quarter of its
    peak current; a set without the cell's grip is an error that names the grip."""
    dev, bs, taps, fs = _sim_library()
    m2 = dev.linear_model(2.0)
    lib, _ = build_library(taps, fs, [("linear", m2)], bs, force_per_amp_N_A=dev.info.force_per_amp_N_A)
    peak = float(abs(lib.currents_A).max())
    # a set at a far amplitude holding another grip only: if it were picked, the 2 N cell would find no model
    far = [("other grip", dev.linear_model(3.0))]
    new, hist = refine_library(lib, [("linear", m2)], lambda: SimDevice(seed=0), RefineSettings(iterations=2), bs,
                               model_sets=[(0.25 * peak, [("linear", m2)]), (100.0, far)])
    assert hist[-1]["median_nrmse"] <= hist[0]["median_nrmse"]
    with pytest.raises(ValueError, match="no model for grip 2"):
        refine_library(lib, [("linear", m2)], lambda: SimDevice(seed=0), RefineSettings(iterations=1), bs,
                       model_sets=[(0.25 * peak, far), (100.0, [("linear", m2)])])


def test_refine_settings_lag_validated():
    with pytest.raises(ValueError, match="max_lag_s"):
        RefineSettings(max_lag_s=0.01)


def test_second_stage_aims_at_the_recordings():
    """Given the recordings, the refinement continues towards them (``recording_iterations`` passes, a line
    search over the correction's smoothing); the second stage never makes a cell worse."""
    dev, bs, taps, fs = _sim_library()
    model = dev.linear_model(2.0)
    lib, _ = build_library(taps, fs, [("linear", model)], bs, force_per_amp_N_A=dev.info.force_per_amp_N_A)
    recs = recording_targets(lib, taps, bs)
    assert recs.shape == lib.desired_accel_m_s2.shape
    # the builder's target is this recording smoothed (zero-phase, 500 Hz): same timing, less click
    smooth = signal.butter(bs.smooth_order, bs.smooth_hz, fs=fs, output="sos")
    for r, d in zip(recs, lib.desired_accel_m_s2):
        mid = slice(50, r.size - 50)
        assert np.corrcoef(signal.sosfiltfilt(smooth, r)[mid], d[mid])[0, 1] > 0.999
    new, hist = refine_library(lib, [("linear", model)], lambda: SimDevice(seed=0),
                               RefineSettings(iterations=1, recording_iterations=2), bs, recordings_m_s2=recs)
    stages = [h["target"] for h in hist]
    assert stages == ["smoothed", "smoothed", "recording", "recording", "recording"]
    first, last = hist[2]["cells"], hist[-1]["cells"]
    assert all(b[2] <= a[2] + 1e-12 for a, b in zip(first, last))
    assert new.metadata["refinement"]["recording_iterations"] == 2
    assert abs(new.currents_A).max() <= 0.95 * dev.info.current_peak_A + 1e-12
    with pytest.raises(ValueError, match="shape"):
        refine_library(lib, [("linear", model)], lambda: SimDevice(seed=0), RefineSettings(iterations=1), bs,
                       recordings_m_s2=recs[:, :-1])


def test_box_step_respects_the_current_limit_and_lowers_the_model_error():
    """At the current limit the correction is the box-constrained least-squares step through the model: it
    keeps the transient within +/- peak and lowers the band-passed model error that clipping an
    unconstrained step leaves higher."""
    dev = SimDevice(seed=0)
    fs = dev.info.servo_rate_hz
    model = dev.linear_model(2.0)
    n_t, peak = 400, 1.0
    sos = signal.butter(2, [20.0, 1000.0], btype="bandpass", fs=fs, output="sos")
    K, QK, L, n_fft = _normal_equations(model, fs, n_t, sos, 0.03, 1.0)
    t = np.arange(n_t) / fs
    wanted = 3.0 * np.sin(2 * np.pi * 60 * t) * np.exp(-t / 0.02)      # needs 3 A; the limit is 1 A
    current = np.clip(0.5 * wanted, -peak, peak)

    def band_response(u):
        return np.fft.irfft(K * np.fft.rfft(u, n_fft), n_fft)[:n_t]
    error = band_response(wanted) - band_response(current)
    du = box_step(K, QK, L, n_fft, error, current, peak)
    assert np.all(np.abs(current + du) <= peak + 1e-12)
    after = np.linalg.norm(band_response(current + du) - band_response(wanted))
    clipped = np.linalg.norm(band_response(np.clip(wanted, -peak, peak)) - band_response(wanted))
    assert after < 0.9 * np.linalg.norm(error) and after < clipped


def test_refine_settings_second_stage_validated():
    for kw, msg in (({"band_order": 0}, "band_order"), ({"recording_iterations": -1}, "recording_iterations"),
                    ({"candidate_smooth_hz": (500.0, 1200.0)}, "candidate_smooth_hz"),
                    ({"backtracks": -1}, "backtracks"), ({"limit_regularisation": -0.1}, "limit_regularisation"),
                    ({"limit_out_of_band_weight": math.nan}, "limit_out_of_band_weight"),
                    ({"limit_solver_iterations": 0}, "limit_solver_iterations")):
        with pytest.raises(ValueError, match=msg):
            RefineSettings(**kw)


def test_compiled_tap_is_the_read_command_loop_tick_for_tick():
    """play_on_wall's compiled tap (stimuli/hfam/_fasttap.py over the sim's fused arrays) and its
    read()/command() loop (any device) give the same accelerations, incoming speed and device state."""
    from devices.sim import SimDevice
    from stimuli.hfam.refine import play_on_wall, play_tap

    rng = np.random.default_rng(0)
    for v, g in ((0.05, 1.0), (0.1, 2.0), (0.3, 3.0)):
        current = rng.normal(0.0, 0.5, 600)
        fast, slow = SimDevice(seed=3), SimDevice(seed=3)
        slow.fused_arrays = None                # hides the compiled path: the generic loop
        a_fast, v_fast = play_on_wall(fast, current, v, g, 680.0)
        a_slow, v_slow = play_on_wall(slow, current, v, g, 680.0)
        assert np.array_equal(a_fast, a_slow, equal_nan=True) and v_fast == v_slow, (v, g)
        assert np.isfinite(a_fast).all() and 0.5 * v < v_fast < 1.5 * v
        assert np.max(np.abs(a_fast)) > 1.0      # the transient and the wall really moved the handle
        assert (fast.time_s, fast.read().position_m, fast.rejected_commands, fast.last_command_A) == \
            (slow.time_s, slow.read().position_m, slow.rejected_commands, slow.last_command_A)
    # play_tap's extra outputs (the HFAM scoring's): the commanded current and the approach's accelerations, on
    # a wall and on the real sample with the motor off
    for kw in ({"wall_N_m": 680.0}, {"wall_N_m": 0.0, "sample": "wood_on_foam", "motor_on": False}):
        current = rng.normal(0.0, 1.5, 600)
        fast, slow = SimDevice(seed=5), SimDevice(seed=5)
        slow.fused_arrays = None
        wall = kw.pop("wall_N_m")
        t_fast = play_tap(fast, current, 0.2, 3.0, wall, **kw)
        t_slow = play_tap(slow, current, 0.2, 3.0, wall, **kw)
        for field in ("accel_m_s2", "pre_accel_m_s2", "command_A"):
            assert np.array_equal(getattr(t_fast, field), getattr(t_slow, field)), field
        assert t_fast.v_in_m_s == t_slow.v_in_m_s and t_fast.pre_accel_m_s2.size == 100
        assert np.isfinite(t_fast.command_A).all() and np.isfinite(t_fast.pre_accel_m_s2).all()
        if wall:
            # the command is the wall's current plus the transient (sample k on tick k + 1), before the clamp
            assert np.max(np.abs(t_fast.command_A)) > 4.0
            wall_part = np.r_[t_fast.command_A[0], t_fast.command_A[1:] - current[:-1]]
            assert np.all(wall_part >= 0.0) and 0.05 < wall_part.max() < 3.0     # -k x / kf below the surface
        else:
            # no wall: the command is the current alone (ignored by the motor-off device)
            assert np.array_equal(t_fast.command_A, np.r_[0.0, current[:-1]])
            assert np.max(np.abs(t_fast.accel_m_s2)) > 50.0   # the real wood on foam's impact, motor off
