"""HFAM over bilateral PD in teleoperation (section 4.3.1, Figures 1.6 and 4.5), with H_ha from the
project's comprehensive identification of the simulated master held by the teleoperation operator (never
the simulator's true parameters). Issue 18's targets, 22-1000 Hz with the pipeline delay removed by
cross-correlation (``accel_match``): PD alone, master RMS < 20 % of the tip's; PD + HFAM, correlation
>= 0.8 and normalised RMS error <= 0.5."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from devices.sim import teleop_kernel as K
from devices.sim.params import default_params
from devices.sim.teleop import ENVIRONMENTS, Operator, Testbed
from renderer.teleop.commands import HFAM_K_MU_HZ, HFAM_MASTER_PD_HZ
from renderer.teleop.hfam import accel_match, bartlett_hann_fir, design_hfam, identify_master_hha
from renderer.teleop.session import TeleopConfig, default_path, run_session

FS = 5000.0
# the operator the targets are measured with, spelled out: the NRMSE target holds for this operator, not for
# every one (a 0.1 kg hand/arm gives 0.504 on wood; docs/teleop.md), so a change of the testbed's default
# operator must not silently change what these tests measure
OPERATOR = Operator(k_u_N_m=40.0, b_u_Ns_m=23.0, q_u_N_m5=3.125e13, hand_mass_kg=0.2, muscle_k_N_m=400.0,
                    muscle_b_Ns_m=20.0, compensation_hz=1.0, push_N=0.0)


@pytest.fixture(scope="module")
def hha():
    """H_ha identified with the teleoperation operator holding the master (as the CLI does)."""
    return identify_master_hha(default_params(), FS, operator=OPERATOR)


@pytest.fixture(scope="module")
def wood():
    P = default_params()
    return Testbed(P, P, operator=OPERATOR, environment=ENVIRONMENTS["wood"])


@pytest.fixture(scope="module")
def texture():
    P = default_params()
    return Testbed(P, P, operator=OPERATOR, environment=ENVIRONMENTS["texture"])


def _hfam_config():
    """The ``pd+hfam`` defaults of the command line (K_mu 40 Hz, master PD low-pass 150 Hz)."""
    return TeleopConfig(controller="pd+hfam", k_mu_hz=HFAM_K_MU_HZ, master_pd_lowpass_hz=HFAM_MASTER_PD_HZ)


def _stroke(path):
    """Tangential texture coordinate: 20 mm/s while the operator's path is below 0.5 mm (as the CLI)."""
    return np.cumsum(np.where(path < 0.5e-3, 0.02, 0.0)) / FS


def test_inverse_check_and_stability(hha):
    hf = design_hfam(hha, FS)
    c = hf.check
    print("HFAM start-up check:", c)
    # Tustin (no prewarp) at 5 kHz warps the top of the 22-1000 Hz band by ~16 %: the check reports it.
    # Measured 4.4 dB with the operator-held identification (4.6 dB with the default person).
    assert c["max_mag_error_db"] < 9.0 and c["sections"] <= K.MAX_SOS
    # the fit stands in for the servo delay with a real right-half-plane zero (~600 Hz); the inverse leaves a
    # delay-like all-pass in the band (measured -16 deg at 50 Hz), not a sign flip (+165 deg before the fix)
    assert c["delay_like_rhp_zeros"] >= 1 and abs(c["allpass_phase_50hz_deg"]) < 45.0
    assert np.isclose(hf.fir.sum(), 1.0) and len(hf.fir) == 15 and np.argmax(hf.fir) == 7   # 7-sample delay
    # barthann(15) = MATLAB barthannwin(15): zero end taps; symmetric, so its delay is exactly 7 samples
    assert hf.fir[0] == 0.0 and hf.fir[-1] == 0.0 and np.allclose(hf.fir, hf.fir[::-1])


def test_inverse_that_cannot_match_in_the_band_is_refused(hha):
    # a real right-half-plane zero inside the band (30 Hz) is no stand-in for delay: what the inverse leaves is
    # an all-pass turning the phase by ~-120 deg at 50 Hz, so the HFAM channel would push against the handle
    a = 2 * np.pi * 30.0
    bad = dataclasses.replace(hha, zeros_rad_s=np.append(hha.zeros_rad_s, a),
                              poles_rad_s=np.append(hha.poles_rad_s, -a))
    with pytest.raises(ValueError, match="wrong sign in the band"):
        design_hfam(bad, FS)


def test_smoothing_bounds_the_match(wood):
    """What the prescribed smoothing alone allows: an exact inverse after the FIR and the 22 Hz high-pass."""
    from scipy import signal  # deferred: analysis only

    path, cr = default_path(FS, 1.0, n_taps=3)
    res = run_session(wood, TeleopConfig(controller="pd"), path, impact_ticks=cr)
    tip = res.col(K.O_AS)
    hp = signal.butter(2, 22.0, "highpass", fs=FS, output="sos")
    nonzero_ends = signal.windows.barthann(17)[1:-1]
    bound = {}
    for name, fir in (("barthann15", bartlett_hann_fir()), ("15 nonzero taps", nonzero_ends / nonzero_ends.sum())):
        bound[name] = accel_match(tip, signal.sosfilt(hp, np.convolve(tip, fir)[:len(tip)]), FS)
    print("exact inverse after the smoothing:", bound)
    # measured 0.935 / 0.487 with barthann(15); 0.912 / 0.565 with 15 nonzero taps (the target is out of reach)
    assert bound["barthann15"]["nrmse"] < 0.5 < bound["15 nonzero taps"]["nrmse"]
    assert bound["barthann15"]["delay_samples"] == 7


def test_pd_alone_master_feels_almost_nothing(wood):
    path, cr = default_path(FS, 1.0, n_taps=3)
    res = run_session(wood, TeleopConfig(controller="pd"), path, impact_ticks=cr)
    m = accel_match(res.col(K.O_AS), res.col(K.O_AM), FS)
    print("PD alone:", m)
    assert m["rms_ratio"] < 0.20   # measured 0.085


def _free_air_tip_rms(res):
    from scipy import signal  # deferred: analysis only
    sos = signal.butter(4, [22, 1000], btype="bandpass", fs=FS, output="sos")
    a = signal.sosfilt(sos, res.col(K.O_AS))
    i0 = int(np.flatnonzero(res.col(K.O_FE) > 0.05)[0])
    return float(np.sqrt(np.mean(a[i0 - 600:i0 - 100] ** 2)))


def test_pd_hfam_master_matches_slave_tip_on_wood(wood, hha):
    hf = design_hfam(hha, FS, max_current_A=4.0)
    path, cr = default_path(FS, 1.0, n_taps=3)
    # without K_mu the HFAM-induced master motion re-enters x_c; with the inverse's sign right in the band that
    # loop no longer rings (it rang at ~140 Hz, 35 m/s^2, while the inverse pushed the wrong way below 596 Hz)
    free = run_session(wood, TeleopConfig(controller="pd+hfam"), path, hfam=hf, impact_ticks=cr)
    res = run_session(wood, _hfam_config(), path, hfam=hf, impact_ticks=cr)
    print("free-air tip RMS (22-1000 Hz): no K_mu", _free_air_tip_rms(free), "defaults", _free_air_tip_rms(res))
    assert _free_air_tip_rms(free) < 2.0 and _free_air_tip_rms(res) < 2.0   # measured 0.95 and 1.1 m/s^2
    assert res.fault == 0
    i = res.col(K.O_IM)
    assert np.all(np.isfinite(i)) and np.max(np.abs(i)) <= 4.0
    m = accel_match(res.col(K.O_AS), res.col(K.O_AM), FS)
    print("PD + HFAM (wood):", m)
    # issue 18 targets; measured 0.908 / 0.477 / RMS ratio 0.68, delay 1.8 ms (before: 0.71 / 0.70 / 0.66)
    assert m["correlation"] >= 0.8
    assert m["nrmse"] <= 0.5
    assert 1.5e-3 <= m["delay_s"] <= 2.5e-3   # 7 samples of smoothing + the servo cycle


def test_master_pd_lowpass_helps(wood, hha):
    """The master PD unfiltered pulls back the handle motion HFAM creates (measured NRMSE 0.495 vs 0.477)."""
    hf = design_hfam(hha, FS, max_current_A=4.0)
    path, cr = default_path(FS, 1.0, n_taps=3)
    m = {}
    for lp in (0.0, HFAM_MASTER_PD_HZ):
        res = run_session(wood, TeleopConfig(controller="pd+hfam", k_mu_hz=HFAM_K_MU_HZ, master_pd_lowpass_hz=lp),
                          path, hfam=hf, impact_ticks=cr)
        m[lp] = accel_match(res.col(K.O_AS), res.col(K.O_AM), FS)
    print("master PD low-pass off / on:", m)
    assert m[HFAM_MASTER_PD_HZ]["nrmse"] < m[0.0]["nrmse"] - 0.01
    assert m[HFAM_MASTER_PD_HZ]["rms_ratio"] > m[0.0]["rms_ratio"]


def test_pd_hfam_master_matches_slave_tip_stroking_texture(texture, hha):
    hf = design_hfam(hha, FS, max_current_A=4.0)
    path, cr = default_path(FS, 1.0, n_taps=3)
    res = run_session(texture, _hfam_config(), path, hfam=hf, impact_ticks=cr, stroke_m=_stroke(path))
    assert res.fault == 0
    m = accel_match(res.col(K.O_AS), res.col(K.O_AM), FS)
    print("PD + HFAM (texture):", m)
    # measured 0.913 / 0.481 / RMS ratio 0.66 (before: 0.74 / 0.69 / 0.60)
    assert m["correlation"] >= 0.8
    assert m["nrmse"] <= 0.5
