"""Teleoperation on the simulated testbed (issues 18, 37): the section 5.7 testbed (force sensor beneath the
slave's drum, F_f saturation, optional backlash, servo gains from one rule), the contact classification of
Figure 5.10, the environments shared with the virtual environment, safety, commands.

The CIMM model source is one fixture (``cimm_model``, conftest.py): successive isolation (thesis section 3.5,
``devices.identify.successive``) of the simulated master, saved with the project's saver and loaded
with ``load_sim_params`` -- never the simulator's own parameters.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from devices.sim import teleop_kernel as K
from devices.sim.params import default_params
from devices.sim.samples import get_sample
from devices.sim.teleop import BACKLASH_FIG_5_11_M, ENVIRONMENTS, SLAVE_HANDLE_DAMPING_N_S_M, CimmModel, Testbed
from renderer.__main__ import main
from renderer.teleop import options
from renderer.teleop.calibration import calibrate_slave_handle_damping
from renderer.teleop.cli_teleop import CONTROLLER_NAMES, ENVIRONMENT_NAMES, SWEEP_CONDITIONS
from renderer.teleop.commands import largest_lambda, largest_stable, sweep
from renderer.teleop.models import STAND_IN_SOURCE, underestimation_check
from renderer.teleop.session import (BUZZ_S, FF_MAX_N, SERVO_BANDWIDTH_HZ, TeleopConfig, classify_contact,
                                     default_path, quasi_static, resolve_gains, run_session, session_metrics,
                                     tap_metrics)

LAMBDAS = (1.0, 3.0, 6.0, 10.0, 15.0)
LAMBDAS_BACKLASH = (1.0, 2.0, 3.0, 4.0, 6.0, 10.0)
FS = 5000.0


@pytest.fixture(scope="module")
def testbed():
    P = default_params()
    return Testbed(P, P, environment=ENVIRONMENTS["hard"])


@pytest.fixture(scope="module")
def sweep_rows(testbed, cimm_model):
    """Figure 5.10's testbed (no backlash): two taps per lambda (0.08, 0.12 m/s)."""
    return sweep(testbed, cimm_model, LAMBDAS, ["pf", "pf+cimm", "pf+K_lambda"], taps=2, seed=3)


@pytest.fixture(scope="module")
def natural_impacts(testbed, cimm_model):
    """The slave's natural impact: the same two taps at lambda = 0 (no force feedback)."""
    return sweep(testbed, cimm_model, [0.0], ["pf"], taps=2, seed=3)


@pytest.fixture(scope="module")
def sweep_backlash(cimm_model):
    """Figure 5.11's condition: backlash in both transmissions."""
    P = default_params()
    tb = Testbed(P, P, environment=ENVIRONMENTS["hard"], backlash_m=BACKLASH_FIG_5_11_M)
    return sweep(tb, cimm_model, LAMBDAS_BACKLASH, ["pf", "pf+cimm"], taps=2, seed=3)


def _rows(rows, cond, lam):
    return [r for r in rows if r["condition"] == cond and r["lambda"] == lam]


def _losses(rows, cond, lam):
    return float(np.mean([r["contact_losses"] for r in _rows(rows, cond, lam)]))


# ------------------------------------------------------------------ the contact classification (item 2)
def test_classification_is_figure_5_10_in_words():
    """settles: held, decays (lambda = 1, "about 50 ms"); buzzes: held, "prolonged to over 100 ms"; make-break:
    contact lost twice or more after the impact's own 30 ms ("makes and breaks contact ... several times")."""
    assert classify_contact(0, 0.050) == "settles"
    assert classify_contact(1, 0.099) == "settles"
    assert classify_contact(1, 0.101) == "buzzes"
    assert classify_contact(0, math.inf) == "buzzes"
    assert classify_contact(2, 0.030) == "make-break"
    assert BUZZ_S == 0.100


def _synthetic(kind: str) -> np.ndarray:
    """A force trace (N) at 5 kHz: 20 ms before contact, then a press at 1 N with a 150 Hz transient."""
    t = np.arange(int(0.45 * FS)) / FS
    f = np.zeros_like(t)
    c = t >= 0.02
    tc = t[c] - 0.02
    tau = {"settles": 0.008, "buzzes": 0.060, "make-break": 0.008}[kind]
    f[c] = 1.0 + 0.8 * np.exp(-tc / tau) * np.sin(2 * np.pi * 150 * tc)
    if kind == "make-break":
        for t0 in (0.040, 0.080, 0.120):            # three 3 ms losses of contact
            f[(t >= t0) & (t < t0 + 0.003)] = 0.0
    return f


@pytest.mark.parametrize("kind", ["settles", "buzzes", "make-break"])
def test_tap_metrics_classifies_known_traces(kind):
    f = _synthetic(kind)
    m = tap_metrics(f, np.zeros_like(f), FS, 0, len(f))
    print(kind, m)
    assert m.contact_class == kind
    if kind == "settles":     # an 8 ms decay time constant: inside the band (10 % of 1 N) after ~17 ms
        assert 0.010 < m.settling_s < 0.030 and m.contact_losses == 0
    if kind == "buzzes":      # a 60 ms time constant: ~125 ms
        assert 0.100 < m.settling_s < 0.160 and m.contact_losses == 0
    if kind == "make-break":     # three losses, two of them after the impact's first 30 ms: still make-break
        assert m.contact_losses == 3 and m.breaks == 2


# ------------------------------------------------------------------ the section 5.7 testbed (item 1)
def test_servo_gains_follow_the_stated_rule(testbed):
    """Every PD servo: natural frequency 8 Hz (the user's motion-control bandwidth), damping ratio 0.7, on the
    joystick's moving mass (Table 3.1: 0.01075 + 0.0075 + 0.014 kg)."""
    cfg = resolve_gains(TeleopConfig(controller="pf"), testbed)
    m, w = 0.01075 + 0.0075 + 0.014, 2 * math.pi * 8.0
    assert cfg.kp_s_N_m == pytest.approx(m * w * w) == pytest.approx(81.48, abs=0.01)
    assert cfg.kd_s_Ns_m == pytest.approx(2 * 0.7 * m * w) == pytest.approx(2.269, abs=0.001)
    # closed-loop poles of m s^2 + kd s + kp: |p| = 8 Hz, zeta 0.7
    p = np.roots([m, cfg.kd_s_Ns_m, cfg.kp_s_N_m])
    assert np.allclose(np.abs(p), w) and np.allclose(-p.real / np.abs(p), 0.7)
    pd = resolve_gains(TeleopConfig(controller="pd"), testbed)   # identical joysticks: the same servo each side
    assert (pd.kp_m_N_m, pd.kd_m_Ns_m) == (pd.kp_s_N_m, pd.kd_s_Ns_m) == (cfg.kp_s_N_m, cfg.kd_s_Ns_m)
    assert SERVO_BANDWIDTH_HZ == options.SERVO_BANDWIDTH_HZ == 8.0      # the parsers' default is the rule's
    w12 = 2 * math.pi * 12.0                                              # --servo-bandwidth-hz 12
    fast = resolve_gains(TeleopConfig(controller="pf", servo_bandwidth_hz=12.0), testbed)
    assert (fast.kp_s_N_m, fast.kd_s_Ns_m) == (pytest.approx(m * w12 ** 2), pytest.approx(2 * 0.7 * m * w12))
    with pytest.raises(ValueError, match="servo_bandwidth_hz"):
        TeleopConfig(controller="pf", servo_bandwidth_hz=0.0)
    explicit = resolve_gains(TeleopConfig(controller="pf", kp_s_N_m=600.0, kd_s_Ns_m=3.0), testbed)
    assert (explicit.kp_s_N_m, explicit.kd_s_Ns_m) == (600.0, 3.0)
    with pytest.raises(ValueError):
        TeleopConfig(controller="pf", kp_s_N_m=-1.0)


def test_force_feedback_saturates_at_the_maximum_feedback_force(testbed, cimm_model):
    """Section 5.7.1: q_u gives 2 mm of deflection at maximum feedback force: 40 N/m * 2 mm + q_u (2 mm)^5."""
    assert FF_MAX_N == pytest.approx(1.08)
    path, cr = default_path(FS, 1.0, n_taps=1)
    res = run_session(testbed, TeleopConfig(controller="pf+cimm", lam=10.0), path, cimm=cimm_model, impact_ticks=cr)
    ff = res.col(K.O_FF)
    print("peak |F_f| at lambda 10:", np.max(np.abs(ff)), "peak F_e:", np.max(res.col(K.O_FE)))
    assert np.max(np.abs(ff)) <= FF_MAX_N + 1e-9
    assert np.sum(np.abs(ff) >= FF_MAX_N - 1e-9) >= 10        # it does saturate (peak F_e x 10 >> 1.08 N)
    assert np.max(res.col(K.O_FE)) * 10 > 3 * FF_MAX_N


def test_force_sensor_is_beneath_the_drum(testbed):
    """The hard environment is the top of the force sensor under the slave's front transmission element: the
    drum touches it (x_d <= 0) while the handle tip stays above the surface it would have struck."""
    assert ENVIRONMENTS["hard"].struck_by == "drum"
    path, cr = default_path(FS, 1.0, n_taps=1)
    res = run_session(testbed, TeleopConfig(controller="pf", lam=0.0), path, impact_ticks=cr)
    i0 = int(np.flatnonzero(res.col(K.O_FE) > 0.05)[0])
    # the encoder reads the motor; the drum sits between motor and linkage: at contact the motor is within
    # the cable's deflection (~F/k_c, microns) of the surface
    assert abs(res.col(K.O_XS)[i0]) < 0.1e-3


# ------------------------------------------------------------------ environments (item 3)
def test_foam_quasi_static_force_is_the_samples_stiffness():
    """A slow press into the teleoperated foam meets the sample's static stiffness (220 N/m, Table 4.1): the
    Maxwell branch relaxes, the slave's press depth times 220 N/m is the force."""
    P = default_params()
    tb = Testbed(P, P, environment=ENVIRONMENTS["foam"])
    path, cr = default_path(FS, 1.0, n_taps=1)
    res = run_session(tb, TeleopConfig(controller="pf", lam=0.0), path, impact_ticks=cr)
    tip = res.col(K.O_XTIP)
    fe = res.col(K.O_FE_TRUE)
    j = int(cr[0]) + int(0.35 * FS)            # late in the dwell
    k_static = get_sample("foam").static_stiffness_N_m
    print("foam: depth", -tip[j], "force", fe[j], "k", fe[j] / -tip[j])
    assert fe[j] / -tip[j] == pytest.approx(k_static, rel=0.1)


# ------------------------------------------------------------------ Figure 5.10 / 5.11 / section 5.8 (measured)
def test_figure_5_10_ordering_losses_grow_with_lambda_and_cimm_holds_better(sweep_rows):
    """What the model reproduces of Figure 5.10: without cancellation contact losses grow with lambda (the impact's
    2 up to lambda = 3, 56-67 from 6); with cancellation no more at any lambda, far fewer from 6 on, and lambda = 15
    with cancellation loses contact about as often as lambda = 3 without (docs/teleop.md, "Measured")."""
    for lam in LAMBDAS:
        print(lam, "pf", _losses(sweep_rows, "pf", lam), "pf+cimm", _losses(sweep_rows, "pf+cimm", lam))
    assert _losses(sweep_rows, "pf", 1.0) < _losses(sweep_rows, "pf", 6.0)
    for lam in LAMBDAS:
        assert _losses(sweep_rows, "pf+cimm", lam) <= _losses(sweep_rows, "pf", lam), lam
        if lam >= 6.0:
            assert _losses(sweep_rows, "pf+cimm", lam) < 0.2 * _losses(sweep_rows, "pf", lam), lam
    assert _losses(sweep_rows, "pf+cimm", 15.0) <= _losses(sweep_rows, "pf", 3.0)
    assert all(r["contact_class"] == "make-break" for r in _rows(sweep_rows, "pf", 6.0))


def test_slave_handle_damping_is_its_calibration_on_the_natural_impact():
    """The default damping of the slave's unheld handle is what ``calibrate_slave_handle_damping`` finds: the value
    at which a tap with no force feedback (lambda = 0, 0.08 and 0.12 m/s, four noise seeds each) settles in 40 ms
    on the mean ("the slave's natural impact", below Figure 5.10's lambda = 1 "about 50 ms" as Figure 5.11 has it).
    Measured 3.16 N s/m (mean settling 39.8 ms; the mean is flat within 39-41 ms from 2.8 to 4 N s/m) against 202 ms
    with Table 3.1's b_l = 0; stored 3.2. ``xtol`` 0.05 N s/m: finer than the plateau resolves."""
    cal = calibrate_slave_handle_damping(xtol=0.05)
    print(f"calibrated {cal.damping_N_s_m:.3f} N s/m: mean settling {cal.settling_s * 1e3:.1f} ms "
          f"(0 N s/m: {cal.settling_at_zero_s * 1e3:.1f} ms); evaluations "
          f"{[(round(b, 3), round(t * 1e3, 1)) for b, t in cal.evaluations]}")
    assert abs(SLAVE_HANDLE_DAMPING_N_S_M - cal.damping_N_s_m) <= 0.10 * cal.damping_N_s_m
    assert options.SLAVE_HANDLE_DAMPING_N_S_M == SLAVE_HANDLE_DAMPING_N_S_M      # the parsers' default
    assert Testbed(default_params(), default_params()).slave_handle_damping_N_s_m == SLAVE_HANDLE_DAMPING_N_S_M
    assert abs(cal.settling_s - 0.040) <= 0.003           # the root sits on a plateau of the mean
    assert cal.settling_at_zero_s > 2 * BUZZ_S            # Table 3.1 as identified: 202 ms
    with pytest.raises(ValueError, match="do not bracket"):
        calibrate_slave_handle_damping(bracket=(4.0, 6.0))      # 39 ms and less: the 40 ms lies below 4 N s/m


def test_table_3_1_as_identified_the_unheld_handle_rings():
    """With Table 3.1's b_l = 0 (``slave_handle_damping_N_s_m=0``) the slave's natural impact rings for over
    100 ms: its unheld handle oscillates on the linkage between the large-deflection (sqrt(k_l / m_h) / 2 pi =
    85 Hz) and the small-deflection slope (section 3.5.3: k_l + gamma_l (f_lp - f_ln) = 11 700 N/m, 146 Hz;
    measured 115 Hz), and the drum under it passes that to the sensor. With the calibrated default the same tap
    settles in 24 ms (the slowest of the sweep's taps, 0.12 m/s, in 47 ms)."""
    P = default_params()
    path, cr = default_path(FS, 1.0, n_taps=1)
    table31 = Testbed(P, P, environment=ENVIRONMENTS["hard"], slave_handle_damping_N_s_m=0.0)
    res = run_session(table31, TeleopConfig(controller="pf", lam=0.0), path, impact_ticks=cr)
    (m,) = session_metrics(res)
    fe = res.col(K.O_FE)
    i0 = int(np.flatnonzero(fe > 0.05)[0])
    seg = fe[i0 + int(0.05 * FS):i0 + int(0.25 * FS)]
    seg = seg - quasi_static(seg, FS)
    spec = np.abs(np.fft.rfft(seg * np.hanning(len(seg))))
    f_peak = np.fft.rfftfreq(len(seg), 1 / FS)[np.argmax(spec)]
    default = Testbed(P, P, environment=ENVIRONMENTS["hard"])
    (md,) = session_metrics(run_session(default, TeleopConfig(controller="pf", lam=0.0), path, impact_ticks=cr))
    print(f"lambda 0, b_l 0: settling {m.settling_s * 1e3:.0f} ms, ringing at {f_peak:.0f} Hz; "
          f"calibrated {SLAVE_HANDLE_DAMPING_N_S_M} N s/m: {md.settling_s * 1e3:.0f} ms")
    assert m.settling_s > BUZZ_S and 85.0 <= f_peak <= 146.0
    assert md.settling_s <= 0.050


def test_figure_5_10_targets_with_the_calibrated_slave(sweep_rows, natural_impacts):
    """Figure 5.10 / section 5.8 with the calibrated slave (natural impact 40 ms), the contact losses counted after
    the impact's own 30 ms (docs/teleop.md, targets table).

    Met: pf at lambda = 6 makes and breaks contact (50+ losses per tap); cancellation holds contact at every lambda
    to 10. Not met, measured: pf at lambda = 1 settles, but in 28 and 43 ms (target 40-60: the slower tap meets it,
    the 0.08 m/s one settles before the band); at lambda = 3 it settles in 23-51 ms, no buzz (its static contact
    force, ~0.1 N on the rule's 8 Hz servo and 2 mm press, is never outweighed long by the oscillation:
    ``test_servo_study``); cancellation at lambda = 15 loses contact after the impact (3 times at 0.12 m/s), and
    its lambda = 15 transient is 1.68x its lambda = 1 one."""
    for lam in LAMBDAS:
        for c in ("pf", "pf+cimm"):
            print(lam, c, [(r["contact_losses"], r["breaks"], round(r["settling_s"] * 1e3, 1), r["contact_class"])
                           for r in sorted(_rows(sweep_rows, c, lam), key=lambda r: r["speed_m_s"])])
    print("natural impact (lambda 0):",
          [(r["contact_losses"], round(r["settling_s"] * 1e3, 1)) for r in natural_impacts])
    # the natural impact: it bounces within its first 30 ms, then holds contact
    assert all(r["contact_losses"] >= 1 and r["breaks"] == 0 for r in natural_impacts)
    # met
    assert all(r["contact_class"] == "make-break" and r["breaks"] >= 20 for r in _rows(sweep_rows, "pf", 6.0))
    assert largest_stable(sweep_rows, "pf+cimm") == 10.0
    # not met: lambda = 1 settles, one tap below 40 ms; lambda = 3 settles (no buzz); lambda 15 loses contact
    pf1 = sorted(_rows(sweep_rows, "pf", 1.0), key=lambda r: r["speed_m_s"])
    assert all(r["contact_class"] == "settles" for r in pf1) and pf1[0]["settling_s"] < 0.040 <= pf1[1]["settling_s"]
    assert all(r["contact_class"] == "settles" and r["settling_s"] < BUZZ_S for r in _rows(sweep_rows, "pf", 3.0))
    s1 = np.mean([r["settling_s"] for r in _rows(sweep_rows, "pf+cimm", 1.0)])
    s15 = np.mean([r["settling_s"] for r in _rows(sweep_rows, "pf+cimm", 15.0)])
    assert s15 > 1.3 * s1
    cimm10 = [r["settling_s"] for r in _rows(sweep_rows, "pf+cimm", 10.0)]
    assert 0.050 <= np.mean(cimm10) <= 0.060                                       # 55 and 61 ms: met on the mean
    assert largest_lambda(sweep_rows, "pf", ("settles",)) == 3.0


def test_figure_5_11_backlash_limits(sweep_backlash):
    """With backlash (Figure 5.11's condition) pf holds contact up to lambda = 2 (one 0.12 m/s tap makes and breaks
    at 3; 25+ losses from 4): the thesis's "about 2.5" (2-3.5). Cancellation with the identified (accurate) model
    holds contact to 10, above the thesis's 4.5 (4-6): Figure 5.11's own cancellation used "a simpler,
    less-accurate model" (``test_servo_study``)."""
    for lam in LAMBDAS_BACKLASH:
        print(lam, "pf", [r["contact_losses"] for r in _rows(sweep_backlash, "pf", lam)],
              "pf+cimm", [r["contact_losses"] for r in _rows(sweep_backlash, "pf+cimm", lam)])
    for lam in LAMBDAS_BACKLASH:
        assert max(r["breaks"] for r in _rows(sweep_backlash, "pf+cimm", lam)) == 0, lam
    assert min(r["breaks"] for r in _rows(sweep_backlash, "pf", 6.0)) >= 20
    assert largest_stable(sweep_backlash, "pf") == 2.0 and largest_stable(sweep_backlash, "pf+cimm") == 10.0


def test_force_filter_removes_high_frequency_cimm_keeps_it(sweep_rows):
    hf_k = np.mean([r["hf_energy_fraction"] for r in _rows(sweep_rows, "pf+K_lambda", 3.0)])
    hf_c = np.mean([r["hf_energy_fraction"] for r in _rows(sweep_rows, "pf+cimm", 3.0)])
    print(f"F_f energy above 50 Hz at lambda 3: K_lambda {hf_k:.3f}, CIMM {hf_c:.3f}")
    assert hf_c > 3 * hf_k


def test_start_up_check_warns_on_overestimating_model(cimm_model, testbed):
    ok = underestimation_check(cimm_model, testbed.master)
    assert ok["warning"] == "" and ok["max_ratio"] < 1
    soft = CimmModel(cimm_model.params, k_u_N_m=20.0, q_u_N_m5=0.0, source="soft")
    bad = underestimation_check(soft, testbed.master)
    assert bad["max_ratio"] > 1 and "eq. 5.14" in bad["warning"]


def test_currents_limited_and_finite(testbed, cimm_model):
    path, cr = default_path(testbed.servo_rate_hz, 1.0, n_taps=1)
    # the F_f saturation off, so that the amplifier's own clamp is what limits the master current
    res = run_session(testbed, TeleopConfig(controller="pf+cimm", lam=15.0, ff_max_N=0.0), path, cimm=cimm_model,
                      impact_ticks=cr)
    for col, lim in ((K.O_IM, testbed.master.device["current_amplifier_A"]),
                     (K.O_IS, testbed.slave.device["current_amplifier_A"])):
        i = res.col(col)
        assert np.all(np.isfinite(i)) and np.max(np.abs(i)) <= lim + 1e-12
    assert res.counts["master_clip_ticks"] > 0
    # with the default saturation the master current stays at 1.08 N / (rho k_t / h)
    res = run_session(testbed, TeleopConfig(controller="pf+cimm", lam=15.0), path, cimm=cimm_model, impact_ticks=cr)
    kf = 15.0 * 0.0235 / 0.15
    assert np.max(np.abs(res.col(K.O_IM))) <= FF_MAX_N / kf + 1e-9 and res.counts["master_clip_ticks"] == 0


def test_nan_and_divergence_stop_with_zero_output(testbed):
    path, cr = default_path(testbed.servo_rate_hz, 1.0, n_taps=1)
    bad = path.copy()
    bad[2000:] = np.nan
    res = run_session(testbed, TeleopConfig(controller="pf", lam=1.0), bad, impact_ticks=cr)
    assert res.fault == K.FAULT_NAN and res.fault_tick >= 2000
    assert res.traces[res.fault_tick, K.O_IM] == 0 and res.traces[res.fault_tick, K.O_IS] == 0
    assert np.all(res.traces[res.fault_tick + 1:, K.O_IM] == 0)
    res = run_session(testbed, TeleopConfig(controller="pf", lam=3.0, divergence_m=5e-4), path, impact_ticks=cr)
    assert res.fault == K.FAULT_DIVERGED
    assert res.traces[res.fault_tick, K.O_IM] == 0 and res.traces[res.fault_tick, K.O_IS] == 0


def test_slave_stops_when_master_link_lost(testbed):
    path, cr = default_path(testbed.servo_rate_hz, 1.0, n_taps=1)
    lost = int(cr[0]) - 400          # mid-descent, slave moving at ~0.1 m/s
    res = run_session(testbed, TeleopConfig(controller="pf", lam=0.5), path, impact_ticks=cr, link_lost_tick=lost)
    xs = res.traces[:, K.O_XS]
    assert np.all(res.traces[lost:, K.O_IM] == 0)
    late = xs[lost + 1000:lost + 2000]       # 200-400 ms after the loss
    assert np.ptp(late) < 5e-5               # slave held still
    assert np.all(res.traces[lost:, K.O_XC] == res.traces[lost, K.O_XC])


def test_teleop_command_writes_run_folder_and_refuses_overwrite(tmp_path, capsys, cimm_file):
    out = tmp_path / "run"
    assert main(["teleop", "--controller", "pf+cimm", "--lambda", "2", "--taps", "2", "--cimm-model",
                 str(cimm_file), "--out", str(out)]) == 0
    run = json.loads((out / "run.json").read_text())
    assert run["cimm_model"]["source"] == f"file: {cimm_file}"
    assert run["fault"] == 0 and len(run["taps"]) == 2
    assert all(tap["contact_class"] in ("settles", "buzzes", "make-break") for tap in run["taps"])
    assert run["controller"]["kp_s_N_m"] == pytest.approx(81.48, abs=0.01)   # the derived gains are recorded
    assert run["controller"]["ff_max_N"] == pytest.approx(1.08)
    assert (out / "figure_5_10.png").stat().st_size > 10000
    cols = (out / "traces.csv").read_text().splitlines()[0].split(",")
    assert "x_hat_mi_hf_m" in cols and "F_f_N" in cols
    assert main(["teleop", "--cimm-model", "stand-in", "--out", str(out)]) == 2
    assert "exists and is not empty" in capsys.readouterr().err


def test_teleop_servo_and_slave_flags_and_renamed_speed(tmp_path, capsys):
    """--slave-handle-damping-N-s-m (0: Table 3.1 as identified) and --servo-bandwidth-hz reach the session and
    run.json; the old --speed still works with a notice; a negative damping is one clear error."""
    out = tmp_path / "t31"
    assert main(["teleop", "--controller", "pf", "--taps", "1", "--speed", "0.12", "--slave-handle-damping-N-s-m",
                 "0", "--servo-bandwidth-hz", "12", "--no-figures", "--out", str(out)]) == 0
    assert "--speed is deprecated; use --speed-m-s" in capsys.readouterr().err
    run = json.loads((out / "run.json").read_text())
    assert run["testbed"]["slave_handle_damping_N_s_m"] == 0.0
    assert run["controller"]["servo_bandwidth_hz"] == 12.0
    assert run["controller"]["kp_s_N_m"] == pytest.approx(0.03225 * (2 * math.pi * 12.0) ** 2)
    # Table 3.1's undamped handle at 0.12 m/s: the natural impact rings past 100 ms (measured 227 ms)
    assert run["taps"][0]["settling_s"] is None or run["taps"][0]["settling_s"] > BUZZ_S
    assert main(["teleop", "--slave-handle-damping-N-s-m", "-1", "--out", str(tmp_path / "bad")]) == 2
    assert "error: --slave-handle-damping-N-s-m must be a number >= 0" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_sweep_command_and_bad_lambda(tmp_path, capsys):
    out = tmp_path / "sweep"
    assert main(["teleop-sweep", "--lambda", "0.5,3", "--taps", "1", "--conditions", "pf,pf+cimm",
                 "--cimm-model", "stand-in", "--out", str(out)]) == 0
    assert json.loads((out / "run.json").read_text())["cimm_model"]["source"] == STAND_IN_SOURCE
    assert (out / "figure_5_11.png").exists() and "pf+cimm" in (out / "table.md").read_text()
    assert "largest lambda that settles | largest lambda that holds contact" in (out / "table.md").read_text()
    trials = (out / "trials.csv").read_text().splitlines()
    head = trials[0].split(",")
    assert "contact_class" in head and "press_depth_mm" in head and len(trials) == 5
    k = head.index("contact_class")
    assert all(line.split(",")[k] in ("settles", "buzzes", "make-break") for line in trials[1:])
    assert all(float(line.split(",")[head.index("press_depth_mm")]) == 2.0 for line in trials[1:])
    err = capsys.readouterr().err          # not a terminal: plain progress lines, no bar redrawn with \r
    assert "\r" not in err and "teleop-sweep: 4 of 4 taps done" in err
    assert main(["teleop-sweep", "--lambda", "5:1", "--out", str(tmp_path / "x")]) == 2
    assert "error: --lambda" in capsys.readouterr().err
    assert set(SWEEP_CONDITIONS) >= {"pf", "pf+cimm", "pf+b", "pf+K_mu", "pf+K_lambda"}


def test_cimm_robust_to_30_percent_model_errors(testbed, cimm_model, sweep_rows):
    """+/-30 % in the model's user stiffness or hand mass changes what cancellation does by little: every variant
    holds contact at least as far as the nominal model (lambda 10; the variants 15) and loses contact after the
    impact's bounce less than once per tap over lambda 1-15 (measured 0-0.2 against the nominal's 0.8, one tap per
    lambda at 0.1 m/s), against 32 per tap without cancellation."""
    from renderer.teleop.commands import robustness
    table = robustness(testbed, cimm_model, LAMBDAS, taps=1, seed=4)
    pf = float(np.mean([r["breaks"] for r in sweep_rows if r["condition"] == "pf"]))
    print("robustness:", table, "pf losses per tap after the impact's 30 ms:", pf)
    assert len(table) == 5
    nominal = table["nominal"]
    for name, v in table.items():
        assert v["largest_stable_lambda"] >= min(10.0, nominal["largest_stable_lambda"]), name
        assert v["mean_contact_losses"] < 1.0 and v["mean_contact_losses"] < 0.05 * pf, name


def test_cli_choice_lists_match_the_testbed_and_the_controllers():
    """The light parser module keeps plain name tuples (fast --help); they must be the real ones."""
    from devices.sim.teleop import ENVIRONMENTS
    from renderer.teleop.session import CONTROLLERS

    assert ENVIRONMENT_NAMES == tuple(sorted(ENVIRONMENTS))
    assert CONTROLLER_NAMES == tuple(CONTROLLERS)


def test_teleop_help_does_not_import_the_numba_testbed():
    import subprocess
    import sys

    code = ("import sys; from renderer.__main__ import main\n"
            "try:\n    main(['teleop', '--help'])\nexcept SystemExit:\n    pass\n"
            "print('numba' in sys.modules, 'devices.sim' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60).stdout
    assert out.strip().splitlines()[-1] == "False False", out


def test_cimm_model_linear_linkage_is_the_identified_model_made_linear(monkeypatch, cimm_file):
    """``--cimm-model linear-linkage``: Figure 5.11's "simpler, less-accurate model" -- the identified master (here the
    session's identification, not the user cache) with its hysteretic linkage replaced by one linear spring."""
    from renderer.teleop import models

    monkeypatch.setattr(models, "identified_params", lambda log=print: models.cimm_params(cimm_file))
    full, _ = models.cimm_params(cimm_file)
    p, src = models.cimm_params(models.LINEAR_LINKAGE)
    assert p.mechanics["hysteresis"] is False and full.mechanics["hysteresis"] is True
    assert p.mechanics["k_lp_N_m"] == p.mechanics["k_ln_N_m"] > 0
    assert "simpler model" in src and str(cimm_file) in src
    # everything but the linkage is the identified model's
    for k in ("m_m_kg", "m_d_kg", "m_h_kg", "k_c_N_m", "c_m_N", "c_d_N"):
        assert p.mechanics[k] == full.mechanics[k], k


def test_a_teleop_run_that_fails_while_writing_leaves_no_half_written_folder(tmp_path, capsys, monkeypatch):
    """The run's folder is written beside --out and swapped in whole: a full disk while the figure is drawn
    (after the traces were written) leaves no --out and no staging folder, and says which output failed."""
    import errno

    import renderer.teleop.commands as commands

    def full_disk(res, path, title):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(commands, "figure_510", full_disk)
    out = tmp_path / "run"
    assert main(["teleop", "--controller", "pf", "--taps", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and str(out) in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == []   # no run folder, no staging folder, no lock
    monkeypatch.undo()
    assert main(["teleop", "--controller", "pf", "--taps", "1", "--out", str(out)]) == 0
    assert {"traces.csv", "run.json", "figure_5_10.png"} <= {p.name for p in out.iterdir()}
