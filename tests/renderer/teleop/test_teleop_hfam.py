"""HFAM over bilateral PD in teleoperation (section 4.3.1, Figures 1.6 and 4.5), with H_ha from the
project's comprehensive identification of the simulated master (never its true parameters)."""

from __future__ import annotations

import numpy as np
import pytest

from devices.sim import teleop_kernel as K
from devices.sim.params import default_params
from devices.sim.teleop import ENVIRONMENTS, Testbed
from renderer.teleop.hfam import accel_match, design_hfam, identify_master_hha
from renderer.teleop.session import TeleopConfig, default_path, run_session


@pytest.fixture(scope="module")
def hha():
    return identify_master_hha(default_params(), 5000.0)


@pytest.fixture(scope="module")
def wood():
    P = default_params()
    return Testbed(P, P, environment=ENVIRONMENTS["wood"])


def test_inverse_check_and_stability(hha):
    hf = design_hfam(hha, 5000.0)
    c = hf.check
    print("HFAM start-up check:", c)
    # Tustin (no prewarp) at 5 kHz warps the top of the 22-1000 Hz band by ~16 %: the check reports it.
    # Measured 4.1-4.4 dB with the prescribed hand, 7.4 dB with the default person's identified model.
    assert c["max_mag_error_db"] < 9.0 and c["sections"] <= K.MAX_SOS
    # the fit stands in for the servo delay with a real right-half-plane zero (~600 Hz); the inverse leaves a
    # delay-like all-pass in the band (measured -15 deg at 50 Hz), not a sign flip (+165 deg before the fix)
    assert c["delay_like_rhp_zeros"] >= 1 and abs(c["allpass_phase_50hz_deg"]) < 45.0
    assert np.isclose(hf.fir.sum(), 1.0) and len(hf.fir) == 15 and np.argmax(hf.fir) == 7   # 7-sample delay


def test_pd_alone_master_feels_almost_nothing(wood):
    path, cr = default_path(5000.0, 1.0, n_taps=3)
    res = run_session(wood, TeleopConfig(controller="pd"), path, impact_ticks=cr)
    m = accel_match(res.col(K.O_AS), res.col(K.O_AM), 5000.0)
    print("PD alone:", m)
    assert m["rms_ratio"] < 0.20


def _free_air_tip_rms(res):
    from scipy import signal
    sos = signal.butter(4, [22, 1000], btype="bandpass", fs=5000, output="sos")
    a = signal.sosfilt(sos, res.col(K.O_AS))
    i0 = int(np.flatnonzero(res.col(K.O_FE) > 0.05)[0])
    return float(np.sqrt(np.mean(a[i0 - 600:i0 - 100] ** 2)))


def test_pd_hfam_master_matches_slave_tip(wood, hha):
    hf = design_hfam(hha, 5000.0, max_current_A=4.0)
    path, cr = default_path(5000.0, 1.0, n_taps=3)
    # without K_mu the HFAM-induced master motion re-enters x_c; with the inverse's sign right in the band that
    # loop no longer rings (it rang at ~140 Hz, 35 m/s^2, while the inverse pushed the wrong way below 596 Hz)
    free = run_session(wood, TeleopConfig(controller="pd+hfam"), path, hfam=hf, impact_ticks=cr)
    res = run_session(wood, TeleopConfig(controller="pd+hfam", k_mu_hz=40.0), path, hfam=hf, impact_ticks=cr)
    print("free-air tip RMS (22-1000 Hz): no K_mu", _free_air_tip_rms(free), "K_mu 40 Hz", _free_air_tip_rms(res))
    assert _free_air_tip_rms(free) < 2.0 and _free_air_tip_rms(res) < 1.0   # measured 0.95 and 0.64 m/s^2
    assert res.fault == 0
    i = res.col(K.O_IM)
    assert np.all(np.isfinite(i)) and np.max(np.abs(i)) <= 4.0
    m = accel_match(res.col(K.O_AS), res.col(K.O_AM), 5000.0)
    print("PD + HFAM (wood):", m)
    # measured 0.877 / 0.554 / ratio 0.60 (0.71 / 0.70 / 0.66 with the inverse of the wrong sign in the band)
    assert m["correlation"] >= 0.85
    assert m["nrmse"] <= 0.6
    assert m["rms_ratio"] > 0.5
