"""Teleoperation on the simulated testbed (issue 18): Figure 5.10/5.11 behaviour, safety, commands.

The CIMM model source is one fixture (``cimm_model``): successive isolation (thesis section 3.5,
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
from devices.sim.teleop import ENVIRONMENTS, CimmModel, Testbed
from renderer.__main__ import main
from renderer.teleop.cli_teleop import CONTROLLER_NAMES, ENVIRONMENT_NAMES, SWEEP_CONDITIONS
from renderer.teleop.commands import largest_stable, sweep
from renderer.teleop.models import STAND_IN_SOURCE, cimm_params, underestimation_check
from renderer.teleop.session import SLAVE_PD_DEFAULTS, TeleopConfig, default_path, run_session

LAMBDAS = (0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)


@pytest.fixture(scope="module")
def testbed():
    P = default_params()
    return Testbed(P, P, environment=ENVIRONMENTS["hard"])


@pytest.fixture(scope="module")
def cimm_file(tmp_path_factory):
    """The one place the CIMM model comes from: successive isolation of the simulated master (~40 s)."""
    from devices.identify.successive import identify_successive, save_result

    out = tmp_path_factory.mktemp("successive")
    save_result(identify_successive("sim", log=lambda *a, **k: None), out, figures=False)
    return out / "model.json"


@pytest.fixture(scope="module")
def cimm_model(cimm_file):
    params, source = cimm_params(cimm_file)
    assert params.mechanics["k_c_N_m"] != default_params().mechanics["k_c_N_m"]  # identified, not copied
    return CimmModel(params, source=source)


@pytest.fixture(scope="module")
def sweep_rows(testbed, cimm_model):
    # four taps per lambda (0.08-0.12 m/s): the settling times vary by ~5 ms from tap to tap, and the
    # lambda = 1 and 1.5x comparisons below sit ~5 ms from their bounds (docs/teleop.md: spread over seeds)
    return sweep(testbed, cimm_model, LAMBDAS, ["pf", "pf+cimm", "pf+K_lambda"], taps=4, seed=3)


def _settle(rows, cond, lam):
    return float(np.mean([r["settling_s"] for r in rows if r["condition"] == cond and r["lambda"] == lam]))


def test_at_lambda_1_both_controllers_settle_alike_in_30_to_80_ms(sweep_rows):
    """Figure 5.10, first column: at lambda = 1 (mu = 1) the transients decay in about 50 ms with and without
    cancellation, "nearly identical"."""
    for cond in ("pf", "pf+cimm"):
        assert all(r["stable"] for r in sweep_rows if r["condition"] == cond and r["lambda"] == 1.0), cond
    s_pf, s_c = _settle(sweep_rows, "pf", 1.0), _settle(sweep_rows, "pf+cimm", 1.0)
    print(f"settling at lambda 1: pf {s_pf * 1e3:.0f} ms, pf+cimm {s_c * 1e3:.0f} ms")
    assert 0.030 <= s_pf <= 0.080 and 0.030 <= s_c <= 0.080
    assert abs(s_pf - s_c) <= 0.25 * max(s_pf, s_c)


def test_cimm_extends_stable_lambda_at_least_3x(sweep_rows):
    lmax_pf = largest_stable(sweep_rows, "pf")
    lmax_cimm = largest_stable(sweep_rows, "pf+cimm")
    print(f"largest stable lambda: pf {lmax_pf}, pf+cimm {lmax_cimm}")
    assert lmax_pf >= 1.0             # the slave PD of SLAVE_PD_DEFAULTS (600 N/m, 3 N s/m gave 0.75)
    assert lmax_cimm >= 3 * lmax_pf
    # settling with cancellation at 3x lambda_max stays within 1.5x of its value at lambda = 1
    lam3 = min(lam for lam in LAMBDAS if lam >= 3 * lmax_pf)
    s1, s3 = _settle(sweep_rows, "pf+cimm", 1.0), _settle(sweep_rows, "pf+cimm", lam3)
    print(f"pf+cimm settling: lambda 1 {s1 * 1e3:.0f} ms, lambda {lam3} {s3 * 1e3:.0f} ms")
    assert math.isfinite(s1) and s3 <= 1.5 * s1


def test_without_cancellation_settling_grows_then_contact_breaks(sweep_rows):
    lmax_pf = largest_stable(sweep_rows, "pf")
    lo = _settle(sweep_rows, "pf", 0.25)
    hi = _settle(sweep_rows, "pf", lmax_pf)
    print(f"pf settling: lambda 0.25 {lo * 1e3:.0f} ms, lambda {lmax_pf} {hi * 1e3:.0f} ms")
    assert math.isfinite(lo) and hi > 1.1 * lo
    assert _settle(sweep_rows, "pf", 0.5) > lo
    # beyond lambda_max the slave makes and breaks contact repeatedly
    breaks = [r["breaks"] for r in sweep_rows if r["condition"] == "pf" and r["lambda"] >= 2 * lmax_pf]
    assert breaks and min(breaks) >= 5


def test_force_filter_removes_high_frequency_cimm_keeps_it(sweep_rows):
    lk = largest_stable(sweep_rows, "pf+K_lambda")
    hf_k = np.mean([r["hf_energy_fraction"] for r in sweep_rows
                    if r["condition"] == "pf+K_lambda" and r["lambda"] == lk])
    hf_c = np.mean([r["hf_energy_fraction"] for r in sweep_rows
                    if r["condition"] == "pf+cimm" and r["lambda"] == lk])
    print(f"F_f energy above 50 Hz at lambda {lk}: K_lambda {hf_k:.3f}, CIMM {hf_c:.3f}")
    assert hf_c > 3 * hf_k


def test_start_up_check_warns_on_overestimating_model(cimm_model, testbed):
    ok = underestimation_check(cimm_model, testbed.master)
    assert ok["warning"] == "" and ok["max_ratio"] < 1
    soft = CimmModel(cimm_model.params, k_u_N_m=20.0, q_u_N_m5=0.0, source="soft")
    bad = underestimation_check(soft, testbed.master)
    assert bad["max_ratio"] > 1 and "eq. 5.14" in bad["warning"]


def test_currents_limited_and_finite(testbed, cimm_model):
    path, cr = default_path(testbed.servo_rate_hz, 1.0, n_taps=1)
    res = run_session(testbed, TeleopConfig(controller="pf+cimm", lam=15.0), path, cimm=cimm_model,
                      impact_ticks=cr)
    for col, lim in ((K.O_IM, testbed.master.device["current_amplifier_A"]),
                     (K.O_IS, testbed.slave.device["current_amplifier_A"])):
        i = res.col(col)
        assert np.all(np.isfinite(i)) and np.max(np.abs(i)) <= lim + 1e-12
    assert res.counts["master_clip_ticks"] > 0


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
    assert run["unstable_taps"] == 0 and run["fault"] == 0 and len(run["taps"]) == 2
    assert (out / "figure_5_10.png").stat().st_size > 10000
    cols = (out / "traces.csv").read_text().splitlines()[0].split(",")
    assert "x_hat_mi_hf_m" in cols and "F_f_N" in cols
    assert main(["teleop", "--cimm-model", "stand-in", "--out", str(out)]) == 2
    assert "exists and is not empty" in capsys.readouterr().err


def test_sweep_command_and_bad_lambda(tmp_path, capsys):
    out = tmp_path / "sweep"
    assert main(["teleop-sweep", "--lambda", "0.5,3", "--taps", "1", "--conditions", "pf,pf+cimm",
                 "--cimm-model", "stand-in", "--out", str(out)]) == 0
    assert json.loads((out / "run.json").read_text())["cimm_model"]["source"] == STAND_IN_SOURCE
    assert (out / "figure_5_11.png").exists() and "pf+cimm" in (out / "table.md").read_text()
    err = capsys.readouterr().err          # not a terminal: plain progress lines, no bar redrawn with \r
    assert "\r" not in err and "teleop-sweep: 4 of 4 taps done" in err
    assert main(["teleop-sweep", "--lambda", "5:1", "--out", str(tmp_path / "x")]) == 2
    assert "error: --lambda" in capsys.readouterr().err
    assert set(SWEEP_CONDITIONS) >= {"pf", "pf+cimm", "pf+b", "pf+K_mu", "pf+K_lambda"}


def test_cimm_robust_to_30_percent_model_errors(testbed, cimm_model, sweep_rows):
    from renderer.teleop.commands import robustness
    lmax_pf = largest_stable(sweep_rows, "pf")
    table = robustness(testbed, cimm_model, (1.0, 2.0, 3.0), taps=1, seed=4)
    print("robustness (largest stable lambda):", table)
    assert len(table) == 5
    for name, lam in table.items():
        assert lam >= 3 * lmax_pf, name


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


def test_slave_pd_defaults_follow_the_architecture():
    """Position-force uses the softer slave servo (docs/teleop.md, "Slave gains"), bilateral PD the stiffer
    one; explicit gains win and run.json records the resolved numbers."""
    for controller in ("pf", "pf+cimm"):
        cfg = TeleopConfig(controller=controller)
        assert (cfg.kp_s_N_m, cfg.kd_s_Ns_m) == SLAVE_PD_DEFAULTS["pf"] == (200.0, 2.0)
    for controller in ("pd", "pd+hfam"):
        cfg = TeleopConfig(controller=controller)
        assert (cfg.kp_s_N_m, cfg.kd_s_Ns_m) == SLAVE_PD_DEFAULTS["pd"] == (600.0, 3.0)
    cfg = TeleopConfig(controller="pf", kp_s_N_m=600.0, kd_s_Ns_m=3.0)
    assert (cfg.kp_s_N_m, cfg.kd_s_Ns_m) == (600.0, 3.0)
    with pytest.raises(ValueError):
        TeleopConfig(controller="pf", kp_s_N_m=-1.0)
