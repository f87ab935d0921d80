"""HFAM over bilateral PD in teleoperation (section 4.3.1, Figures 1.6 and 4.5), with H_ha from the
project's comprehensive identification of the simulated master held by the teleoperation operator (never
the simulator's true parameters), and the servo gains of the stated rule (8 Hz, damping ratio 0.7).
22-1000 Hz with the pipeline delay removed by cross-correlation (``accel_match``). The slave's unheld handle has
the calibrated damping (``devices.sim.teleop.SLAVE_HANDLE_DAMPING_N_S_M``, 1.8 N s/m). Issue 37's targets
(correlation >= 0.9, NRMSE <= 0.45 over three operators; at most one bounce per tap) are measured here; the
ones not met are pinned to their measured reasons (docs/teleop.md, "Bilateral PD and HFAM on wood")."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from devices.sim import teleop_kernel as K
from devices.sim.params import default_params
from devices.sim.teleop import ENVIRONMENTS, Operator, Testbed
from renderer.teleop.hfam import accel_match, bartlett_hann_fir, design_hfam, identify_master_hha
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
    print("PD + HFAM (wood):", m)
    # measured 0.912 / 0.562 / RMS ratio 0.53, delay 1.8 ms with the rule's gains and the calibrated slave handle
    # (0.885 / 0.554 with the former K_mu and master-PD low-pass); the NRMSE 0.45 is not met: see the bound
    assert m["correlation"] >= 0.90
    assert m["nrmse"] <= 0.60
    assert 1.5e-3 <= m["delay_s"] <= 2.5e-3   # 7 samples of smoothing + the servo cycle


def test_pd_hfam_master_matches_slave_tip_stroking_texture(texture, hha):
    hf = design_hfam(hha, FS, max_current_A=4.0)
    path, cr = default_path(FS, 1.0, n_taps=3)
    res = run_session(texture, _hfam_config(), path, hfam=hf, impact_ticks=cr, stroke_m=_stroke(path))
    assert res.fault == 0
    m = accel_match(res.col(K.O_AS), res.col(K.O_AM), FS)
    print("PD + HFAM (texture):", m)
    # measured 0.913 / 0.560 / RMS ratio 0.53 (0.888 / 0.552 with the former K_mu and master-PD low-pass)
    assert m["correlation"] >= 0.86
    assert m["nrmse"] <= 0.58


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
        out[name] = (res, accel_match(res.col(K.O_AS), res.col(K.O_AM), FS), session_metrics(res), hf)
    return out


def test_hfam_match_over_three_operators(three_operators):
    """Issue 37: correlation >= 0.9, NRMSE <= 0.45 over three operators. Measured 0.912 / 0.903 / 0.884 (default /
    light / firm) and 0.539-0.644: correlation met but for the firm, heavy operator, who pins the handle; NRMSE
    not met (the smoothing alone bounds it at 0.486)."""
    for name, (res, m, _, _) in three_operators.items():
        print(name, m)
        assert res.fault == 0
        assert m["correlation"] >= 0.86, name
        assert m["nrmse"] <= 0.67, name
    assert three_operators["default"][1]["correlation"] >= 0.9 and three_operators["light"][1]["correlation"] >= 0.9
    assert three_operators["firm"][1]["nrmse"] > three_operators["default"][1]["nrmse"]


def test_the_former_filters_lowered_the_match(three_operators):
    """The K_mu (40 Hz) and master-PD low-pass (150 Hz) pd+hfam had by default, tuned against issue 18's 600 N/m
    slave and absent from section 4.3.1: with the rule's servos they lower the correlation for every operator
    (measured 0.885 / 0.872 / 0.843) and add contact losses (7-9 per tap against 2-8)."""
    path, cr = default_path(FS, 1.0, n_taps=3)
    P = default_params()
    for name, (res, m, mets, hf) in three_operators.items():
        tb = Testbed(P, P, operator=OPERATORS[name], environment=ENVIRONMENTS["wood"])
        old = run_session(tb, _hfam_config(k_mu_hz=FORMER_K_MU_HZ, master_pd_lowpass_hz=FORMER_MASTER_PD_HZ), path,
                          hfam=hf, impact_ticks=cr)
        mo = accel_match(old.col(K.O_AS), old.col(K.O_AM), FS)
        losses_old = sum(t.contact_losses for t in session_metrics(old))
        print(name, "former filters:", mo, "losses", losses_old)
        assert mo["correlation"] < m["correlation"] - 0.01, name
        assert losses_old >= sum(t.contact_losses for t in mets), name


def test_slave_bounces_on_wood_are_the_elastic_impact(three_operators):
    """Issue 37: at most one bounce per tap, not met -- measured 2 (default), 6-8 (light) and 2-3 (firm) contact
    losses per tap under PD + HFAM (6-10 with PD alone), against 20-58 with Table 3.1's undamped slave handle.
    The reason, measured: the wood sample is nearly elastic (Hunt-Crossley alpha = 0.3 s/m, the project's; Table
    4.1 gives its 70 000 N/m), so the unheld handle rebounds and the 8 Hz servo (0.16 N on the 2 mm press)
    catches it only after several bounces. The same PD taps on wood with the hard surface's alpha = 10 s/m lose
    contact once; more handle damping (8 N s/m) still leaves the impact's double bounce on the wood itself (2 per
    tap)."""
    losses = {name: [t.contact_losses for t in mets] for name, (_, _, mets, _) in three_operators.items()}
    print("contact losses per tap:", losses)
    assert min(min(v) for v in losses.values()) >= 2 and max(max(v) for v in losses.values()) <= 10
    P = default_params()
    path, cr = default_path(FS, 1.0, n_taps=3)
    out = {}
    for name, env, damping in (("table 3.1", ENVIRONMENTS["wood"], 0.0),
                               ("alpha 10", dataclasses.replace(ENVIRONMENTS["wood"], alpha_s_m=10.0), None),
                               ("b 8", ENVIRONMENTS["wood"], 8.0)):
        kw = {} if damping is None else {"slave_handle_damping_N_s_m": damping}
        tb = Testbed(P, P, operator=OPERATOR, environment=env, **kw)
        res = run_session(tb, TeleopConfig(controller="pd"), path, impact_ticks=cr)
        out[name] = [t.contact_losses for t in session_metrics(res)]
    print("PD, contact losses per tap:", out)   # measured [36, 33, 34], [1, 1, 1], [2, 2, 2]
    assert min(out["table 3.1"]) >= 20
    assert max(out["alpha 10"]) <= 1
    assert out["b 8"] == [2, 2, 2]


def test_with_a_linear_linkage_every_operator_meets_the_correlation(three_operators):
    """The firm operator's correlation miss (0.884) is the joystick's hysteretic linkage: with the master's linkage a
    linear spring at its small-signal stiffness (H_ha identified on it, nothing else changed) every operator's
    correlation is above 0.9 (measured 0.909 / 0.905 / 0.915) and the NRMSE near the smoothing's 0.486 bound
    (0.484 / 0.486 / 0.507). Section 4.3's testbed had "relatively stiff linkage elements"."""
    from devices.sim.linear import linear_linkage_params

    P = default_params()
    M = linear_linkage_params(P)
    path, cr = default_path(FS, 1.0, n_taps=3)
    for name, op in OPERATORS.items():
        tb = Testbed(M, P, operator=op, environment=ENVIRONMENTS["wood"])
        hf = design_hfam(identify_master_hha(M, FS, operator=op), FS, max_current_A=4.0)
        res = run_session(tb, _hfam_config(), path, hfam=hf, impact_ticks=cr)
        m = accel_match(res.col(K.O_AS), res.col(K.O_AM), FS)
        print(name, "linear master linkage:", m)
        assert res.fault == 0
        assert m["correlation"] >= 0.9, name
        assert m["nrmse"] < three_operators[name][1]["nrmse"] and m["nrmse"] <= 0.52, name
