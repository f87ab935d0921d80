"""Whole HFAM pipeline on the simulated device: record real taps, build, play the transient back.

Real parts: taps are recorded from the nonlinear sim tapping its wood-on-foam
sample with the motor off, the library is built through the sim's analytic
LTI models, and a transient is played open-loop into the nonlinear sim (with
friction and hysteresis the linear model leaves out).
"""

import numpy as np
import pytest
from scipy import signal

from devices.sim import SimDevice
from stimuli.hfam import BuildSettings, band_sos, build_library, highpass_target, nrmse_corr
from stimuli.hfam.pipeline import record_sim_taps


@pytest.fixture(scope="module")
def built():
    dev = SimDevice()
    fs, taps = record_sim_taps((0.05, 0.1, 0.15), device=dev)
    models = [(f"grip{g}", dev.linear_model(g)) for g in (2.5, 5.0)]
    # issue 16: the wood tile's impact click makes the 5 N transient at 0.15 m/s need 4.7 A; scaled to the
    # 4 A peak as the shipped library is (stimuli.hfam.pipeline.build_sim_library; thesis Figure 4.13)
    lib, report = build_library(taps, fs, models,
                                BuildSettings(peak_current_A=dev.info.current_peak_A, scale_to_limit=True),
                                force_per_amp_N_A=dev.info.force_per_amp_N_A)
    return dev, fs, taps, lib, report


def test_recorded_sim_taps_look_like_impacts(built):
    _, fs, taps, _, _ = built
    assert fs == 10000.0
    assert [round(tp.v_in_m_s, 2) for tp in taps] == [0.05, 0.1, 0.15]
    peaks = [np.max(np.abs(tp.accel_m_s2[tp.t_s > 0])) for tp in taps]
    assert peaks == sorted(peaks) and peaks[0] > 5.0  # harder taps, bigger transients


def test_forward_model_verification_on_sim_models(built):
    _, _, _, lib, report = built
    assert lib.currents_A.shape == (3, 2, 1000)
    # against the recording high-passed without phase turn (the causal high-pass's own output was the
    # target before, NRMSE < 0.12 against it; the causal library scores 0.287-0.296 / corr 0.962 by this
    # measure); measured 0.180-0.274, corr >= 0.963: the 2.5 N model's slower zeros keep it above 0.25
    rows = report.verification
    assert max(r["nrmse"] for r in rows) < 0.28
    assert np.mean([r["nrmse"] for r in rows]) < 0.24
    assert min(r["corr"] for r in rows) > 0.96


def test_grip_range_check_against_sim_device(built):
    dev, fs, _, lib, _ = built
    with pytest.raises(ValueError, match=r"grip levels 2.5..5.0 N do not cover"):
        lib.check_device(dev.info, fs)


def test_transient_played_on_nonlinear_sim_reproduces_recording(built):
    """Open-loop playback on the held, nonlinear sim: correlation > 0.9 with the desired acceleration."""
    _, fs, _, lib, _ = built
    sim = SimDevice()
    # hand holding the handle still, 2 cm above the (absent) sample: the prescribed hand, which is what the
    # library's linear_model() inverse models (issue 16: with the default person, corr 0.55)
    sim.set_user(0.02, grip_N=2.5, hand="prescribed")
    cur = lib.current(0.1, 2.5)
    acc = []
    with sim:
        for _ in range(300):  # settle
            sim.command(0.0)
        for k in range(1300):
            sim.command(float(cur[k]) if k < cur.size else 0.0)
            acc.append(sim.read().accel_m_s2)
    pad = 100
    y = np.concatenate([np.zeros(pad), acc])
    # the desired acceleration: high-passed without phase turn (measured 0.399 / 0.919 on the 3 g wood tile;
    # 0.370 / 0.934 on the old 0.12 kg block, where the causal library was 0.461 / 0.890 against it, 0.394 /
    # 0.919 against its own causally high-passed target)
    d = np.concatenate([np.zeros(pad), highpass_target(lib.desired_accel_m_s2[1], fs, 10.0, zero_phase=True),
                        np.zeros(300)])
    bp = band_sos(fs, (20.0, 1000.0))
    err, corr = nrmse_corr(signal.sosfiltfilt(bp, y)[pad:pad + 1000], signal.sosfiltfilt(bp, d)[pad:pad + 1000])
    assert corr > 0.9 and err < 0.42, (err, corr)


def _rendered_tap_accel(sample, fs, n):
    """Acceleration for n samples after the contact event of one simulated tap on a catalog sample."""
    from devices.sim import TapTrajectory
    from renderer import RendererConfig, ServoLoop

    dev = SimDevice()
    dev.set_user(TapTrajectory(0.1, n_taps=1), grip_N=2.5)
    with dev:
        loop = ServoLoop(dev, RendererConfig(stiffness_N_m=sample.stiffness_N_m), transient=sample.make_transient())
        res = loop.run(until=lambda _: dev.trajectory_done, max_ticks=20000)
    k = int(round(res.events[0].t_s * fs))
    return res.log["accel_m_s2"][k:k + n + 40]


def test_hfam_rendering_resembles_the_real_sample_more_than_proportional():
    """Catalog samples rendered by the renderer on the sim vs the sim's real wood-on-foam tap (0.1 m/s)."""
    from stimuli import load_catalog

    fs, real = record_sim_taps((0.1,), grip_N=2.5)
    n = 500
    target = real[0].accel_m_s2[real[0].t_s > 0][:n]
    bp = band_sos(fs, (20.0, 1000.0))
    target = signal.sosfiltfilt(bp, target)
    cat = {s.name: s for s in load_catalog()}
    best = {}
    for name in ("firm", "hfam_firm"):
        acc = _rendered_tap_accel(cat[name], fs, n)
        # best alignment within 4 ms: event detection, output delay and the library's onset delay
        best[name] = max(nrmse_corr(signal.sosfiltfilt(bp, acc[s:s + n]), target)[1] for s in range(40))
    assert best["hfam_firm"] > 0.6 and best["hfam_firm"] > best["firm"] + 0.3, best
