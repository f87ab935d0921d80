"""HFAM over bilateral PD in teleoperation (section 4.3.1, Figures 1.6 and 4.5), with H_ha from the
project's comprehensive identification of the simulated master held by the teleoperation operator (never
the simulator's true parameters), and the servo gains of the stated rule (8 Hz, damping ratio 0.7).
Scored as eq. 4.4 states it, the master handle's high-passed acceleration against the smoothed, high-passed tip
acceleration it must replicate (``accel_match_target``: the signal the HFAM channel inverts), with the smoothing's
own loss reported apart; and against the raw tip acceleration, 22-1000 Hz (``accel_match``), both with the pipeline
delay removed by cross-correlation. The slave's unheld handle has the calibrated damping
(``devices.sim.teleop.SLAVE_HANDLE_DAMPING_N_S_M``, 3.2 N s/m); the wood's damping is the restitution-based one
(devices/sim/samples.py). The targets (correlation >= 0.9, NRMSE <= 0.45 over three operators; at most one bounce
per tap after the impact's own 30 ms) are measured here (docs/teleop.md, "Bilateral PD and HFAM on wood")."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from devices.sim import teleop_kernel as K
from devices.sim.params import default_params
from devices.sim.teleop import ENVIRONMENTS, Operator, Testbed
from renderer.teleop.hfam import accel_match, accel_match_target, bartlett_hann_fir, design_hfam, identify_master_hha
from renderer.teleop.session import TeleopConfig, default_path, run_session, session_metrics

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


#: the filters ``pd+hfam`` had by default before (tuned against issue 18's 600 N/m slave; section 4.3.1 has neither)
FORMER_K_MU_HZ = 40.0
FORMER_MASTER_PD_HZ = 150.0


def _hfam_config(**kw):
    """The ``pd+hfam`` of the command line: section 4.3.1's bilateral PD plus HFAM, no K_mu, no master-PD low-pass."""
    return TeleopConfig(controller="pd+hfam", **kw)


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
    """What the prescribed smoothing alone allows: an exact inverse after the FIR and the 22 Hz high-pass. Its
    NRMSE is above issue 37's 0.45: no inverse model can meet that target behind ``barthann(15)``."""
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
    # measured 0.927 / 0.486 with barthann(15) (0.929 / 0.468 with Table 3.1's undamped slave handle); worse
    # with 15 nonzero taps (0.902 / 0.560)
    assert 0.45 < bound["barthann15"]["nrmse"] < bound["15 nonzero taps"]["nrmse"]
    assert bound["barthann15"]["correlation"] >= 0.9
    assert bound["barthann15"]["delay_samples"] == 7


def test_pd_alone_master_feels_almost_nothing(wood):
    path, cr = default_path(FS, 1.0, n_taps=3)
    res = run_session(wood, TeleopConfig(controller="pd"), path, impact_ticks=cr)
    m = accel_match(res.col(K.O_AS), res.col(K.O_AM), FS)
    print("PD alone:", m)
    assert m["rms_ratio"] < 0.20   # measured 0.05


def _free_air_tip_rms(res):
    from scipy import signal  # deferred: analysis only
    sos = signal.butter(4, [22, 1000], btype="bandpass", fs=FS, output="sos")
    a = signal.sosfilt(sos, res.col(K.O_AS))
    i0 = int(np.flatnonzero(res.col(K.O_FE) > 0.05)[0])
    return float(np.sqrt(np.mean(a[i0 - 600:i0 - 100] ** 2)))


def test_pd_hfam_master_matches_slave_tip_on_wood(wood, hha):
    hf = design_hfam(hha, FS, max_current_A=4.0)
    path, cr = default_path(FS, 1.0, n_taps=3)
    # the HFAM-induced master motion re-enters x_c; with the inverse's sign right in the band that loop does not
    # ring (it rang at ~140 Hz, 35 m/s^2, while the inverse pushed the wrong way below 596 Hz)
    res = run_session(wood, _hfam_config(), path, hfam=hf, impact_ticks=cr)
    former = run_session(wood, _hfam_config(k_mu_hz=FORMER_K_MU_HZ), path, hfam=hf, impact_ticks=cr)
    print("free-air tip RMS (22-1000 Hz): defaults", _free_air_tip_rms(res), "with the former 40 Hz K_mu",
          _free_air_tip_rms(former))
    # measured 0.54 m/s^2, and 3.8 with the former K_mu: with the rule's 8 Hz slave servo that low-pass only adds
    # lag to the PD loop, which then rings near 20 Hz in free air (docs/teleop.md)
    assert _free_air_tip_rms(res) < 1.0 and _free_air_tip_rms(former) > 2 * _free_air_tip_rms(res)
    assert res.fault == 0
    i = res.col(K.O_IM)
    assert np.all(np.isfinite(i)) and np.max(np.abs(i)) <= 4.0
    m = accel_match(res.col(K.O_AS), res.col(K.O_AM), FS)
    e = accel_match_target(res.col(K.O_AS), res.col(K.O_AM), FS)
    print("PD + HFAM (wood):", m, e)
    # against eq. 4.4's target: measured 0.926 / 0.388 (RMS ratio 0.84); what the smoothing itself takes out of the
    # high-passed tip: 0.919 / 0.505 (the bound below); against the raw tip 0.882 / 0.601 / RMS ratio 0.51, delay 1.8 ms
    assert e["match"]["correlation"] >= 0.92 and e["match"]["nrmse"] <= 0.42
    assert 0.45 < e["smoothing_loss"]["nrmse"] < 0.55 and e["smoothing_loss"]["delay_samples"] == 7
    assert m["correlation"] >= 0.86 and m["nrmse"] <= 0.63
    assert 1.5e-3 <= m["delay_s"] <= 2.5e-3   # 7 samples of smoothing + the servo cycle


def test_pd_hfam_master_matches_slave_tip_stroking_texture(texture, hha):
    hf = design_hfam(hha, FS, max_current_A=4.0)
    path, cr = default_path(FS, 1.0, n_taps=3)
    res = run_session(texture, _hfam_config(), path, hfam=hf, impact_ticks=cr, stroke_m=_stroke(path))
    assert res.fault == 0
    m = accel_match(res.col(K.O_AS), res.col(K.O_AM), FS)
    e = accel_match_target(res.col(K.O_AS), res.col(K.O_AM), FS)["match"]
    print("PD + HFAM (texture):", m, e)
    # measured against eq. 4.4's target 0.923 / 0.394; against the raw tip 0.878 / 0.604 / RMS ratio 0.51
    assert e["correlation"] >= 0.9 and e["nrmse"] <= 0.43
    assert m["correlation"] >= 0.86 and m["nrmse"] <= 0.63


# three operators: grip and hand/arm mass spread (half and double the default grip impedance and mass)
OPERATORS = {"default": OPERATOR,
             "light": dataclasses.replace(OPERATOR, k_u_N_m=20.0, b_u_Ns_m=11.5, hand_mass_kg=0.1),
             "firm": dataclasses.replace(OPERATOR, k_u_N_m=80.0, b_u_Ns_m=46.0, hand_mass_kg=0.4)}


@pytest.fixture(scope="module")
def three_operators():
    """PD + HFAM on wood for each operator, H_ha identified with that operator holding the master."""
    P = default_params()
    out = {}
    path, cr = default_path(FS, 1.0, n_taps=3)
    for name, op in OPERATORS.items():
        tb = Testbed(P, P, operator=op, environment=ENVIRONMENTS["wood"])
        hf = design_hfam(identify_master_hha(P, FS, operator=op), FS, max_current_A=4.0)
        res = run_session(tb, _hfam_config(), path, hfam=hf, impact_ticks=cr)
        out[name] = (res, accel_match_target(res.col(K.O_AS), res.col(K.O_AM), FS)["match"], session_metrics(res), hf)
    return out


def test_hfam_match_over_three_operators(three_operators):
    """Correlation >= 0.9 and NRMSE <= 0.45 over three operators, against eq. 4.4's target. Measured 0.926 / 0.922 /
    0.905 (default / light / firm) and 0.388 / 0.389 / 0.457: correlation met for all three, NRMSE for two (the
    firm, heavy operator pins the handle)."""
    for name, (res, m, _, _) in three_operators.items():
        print(name, m)
        assert res.fault == 0
        assert m["correlation"] >= 0.9, name
        assert m["nrmse"] <= 0.48, name
    assert three_operators["default"][1]["nrmse"] <= 0.45 and three_operators["light"][1]["nrmse"] <= 0.45
    assert three_operators["firm"][1]["nrmse"] > three_operators["default"][1]["nrmse"]


def test_the_former_filters_lowered_the_match(three_operators):
    """The K_mu (40 Hz) and master-PD low-pass (150 Hz) pd+hfam had by default, tuned against issue 18's 600 N/m
    slave and absent from section 4.3.1: with the rule's servos they lower the match for every operator (against
    eq. 4.4's target, measured 0.860 / 0.878 / 0.866 against 0.926 / 0.922 / 0.905)."""
    path, cr = default_path(FS, 1.0, n_taps=3)
    P = default_params()
    for name, (res, m, mets, hf) in three_operators.items():
        tb = Testbed(P, P, operator=OPERATORS[name], environment=ENVIRONMENTS["wood"])
        old = run_session(tb, _hfam_config(k_mu_hz=FORMER_K_MU_HZ, master_pd_lowpass_hz=FORMER_MASTER_PD_HZ), path,
                          hfam=hf, impact_ticks=cr)
        mo = accel_match_target(old.col(K.O_AS), old.col(K.O_AM), FS)["match"]
        print(name, "former filters:", mo)
        assert mo["correlation"] < m["correlation"] - 0.02, name
        assert mo["nrmse"] > m["nrmse"], name


def test_slave_bounces_on_wood_are_the_impacts(three_operators):
    """At most one bounce per tap after the impact's own 30 ms: met for every operator (measured 0 after it; 1-2
    from the impact on under PD + HFAM). The wood's Hunt-Crossley damping comes from a restitution of 0.65 at
    0.1 m/s (5.25 s/m, devices/sim/samples.py); the earlier 0.3 s/m (restitution 0.98) bounced the unheld handle 3
    times per tap from the impact on under PD (still 0 after 30 ms with the calibrated handle), Table 3.1's
    undamped handle 11-15 (3-7 after 30 ms), the hard surface's alpha = 10 s/m or 8 N s/m of handle damping once."""
    for name, (_, _, mets, _) in three_operators.items():
        print(name, [(t.contact_losses, t.breaks) for t in mets])
        assert all(t.breaks == 0 and t.contact_losses <= 2 for t in mets), name
    P = default_params()
    path, cr = default_path(FS, 1.0, n_taps=3)
    out = {}
    for name, env, damping in (("table 3.1", ENVIRONMENTS["wood"], 0.0),
                               ("alpha 10", dataclasses.replace(ENVIRONMENTS["wood"], alpha_s_m=10.0), None),
                               ("alpha 0.3", dataclasses.replace(ENVIRONMENTS["wood"], alpha_s_m=0.3), None),
                               ("b 8", ENVIRONMENTS["wood"], 8.0)):
        kw = {} if damping is None else {"slave_handle_damping_N_s_m": damping}
        tb = Testbed(P, P, operator=OPERATOR, environment=env, **kw)
        res = run_session(tb, TeleopConfig(controller="pd"), path, impact_ticks=cr)
        out[name] = [(t.contact_losses, t.breaks) for t in session_metrics(res)]
    print("PD, contact losses per tap (from the impact, after 30 ms):", out)
    assert min(a for a, _ in out["table 3.1"]) >= 8 and min(b for _, b in out["table 3.1"]) >= 2
    assert max(a for a, _ in out["alpha 10"]) <= 1 and max(a for a, _ in out["b 8"]) <= 1
    assert min(a for a, _ in out["alpha 0.3"]) >= 3


def test_with_a_linear_linkage_every_operator_matches(three_operators):
    """The joystick's hysteretic linkage (section 3.5.3) against a linear spring at its small-signal stiffness in the
    master (H_ha identified on it, nothing else changed): against eq. 4.4's target every operator's correlation
    stays above 0.9 (measured 0.918 / 0.915 / 0.928) and the firm operator's NRMSE falls from 0.457 to 0.378.
    Section 4.3's testbed had "relatively stiff linkage elements"."""
    from devices.sim.linear import linear_linkage_params

    P = default_params()
    M = linear_linkage_params(P)
    path, cr = default_path(FS, 1.0, n_taps=3)
    for name, op in OPERATORS.items():
        tb = Testbed(M, P, operator=op, environment=ENVIRONMENTS["wood"])
        hf = design_hfam(identify_master_hha(M, FS, operator=op), FS, max_current_A=4.0)
        res = run_session(tb, _hfam_config(), path, hfam=hf, impact_ticks=cr)
        m = accel_match_target(res.col(K.O_AS), res.col(K.O_AM), FS)["match"]
        print(name, "linear master linkage:", m)
        assert res.fault == 0
        assert m["correlation"] >= 0.9 and m["nrmse"] <= 0.45, name
    assert m["nrmse"] < three_operators["firm"][1]["nrmse"] - 0.05      # the firm operator, the loop's last
