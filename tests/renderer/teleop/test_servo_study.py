"""The servo-bandwidth study (``renderer.teleop.servo_study``): section 5.7's targets at every natural frequency of
the servo rule from 6 to 22 Hz, the slave handle's damping re-identified on the natural impact (40 ms, below
Figure 5.10's lambda = 1 value) at each, the contact losses counted after the impact's own 30 ms. What it measures
is why Figure 5.10's lambda = 1 and 10 rows are met by no choice of the servo: soft servos settle too soon or
bounce, stiff ones ring past the thesis's ~50 ms; and that the missing lambda = 3 buzz is the static contact force
of the rule's soft servo (docs/teleop.md)."""

from __future__ import annotations

import json
import math

import pytest

from renderer.__main__ import main
from devices.sim.params import default_params
from devices.sim.teleop import BACKLASH_FIG_5_11_M, ENVIRONMENTS, Testbed
from renderer.teleop.commands import largest_stable, sweep
from renderer.teleop.servo_study import (FIG_5_10_LAMBDAS, FIG_5_11_LAMBDAS, STUDY_BANDWIDTHS_HZ, TARGETS,
                                         check_targets, figure_5_11_model, parse_bandwidths,
                                         servo_study, study_table)


@pytest.fixture(scope="module")
def study(cimm_model):
    """The default grid (6, 8, 10, 12.6, 16, 20, 22 Hz), two taps per lambda, seed 1 (about 10 s)."""
    return {p.servo_bandwidth_hz: p for p in servo_study(cimm_model)}


def _taps(point, cond, lam):
    return sorted((r for r in point.rows if r["condition"] == cond and r["lambda"] == lam),
                  key=lambda r: r["speed_m_s"])


def _check(point, key):
    return next(c for c in point.checks if c.key == key)


def test_every_point_is_identified_and_complete(study):
    assert tuple(study) == STUDY_BANDWIDTHS_HZ
    for f, p in study.items():
        assert [c.key for c in p.checks] == list(TARGETS)
        if f == 10.0:
            # no damping up to 6 N s/m brings the natural impact to 40 ms there (46 ms at 6 N s/m): not identifiable,
            # every target recorded as not met with the reason
            assert math.isnan(p.damping_N_s_m) and all("not identifiable" in c.measured for c in p.checks)
            continue
        # the natural impact settles in 40 ms at every other servo (2.4-3.1 N s/m at 6-8 Hz, 1.3-2.4 above)
        assert 0.0 < p.damping_N_s_m < 6.0, f
        assert abs(p.natural_settling_s - 0.040) < 0.01, f
        assert len(p.rows) == len(FIG_5_10_LAMBDAS) * 2 * 2 and len(p.backlash_rows) == len(FIG_5_11_LAMBDAS) * 2 * 2
    assert study[22.0].damping_N_s_m < study[12.6].damping_N_s_m < study[8.0].damping_N_s_m


def test_no_servo_bandwidth_reproduces_figure_5_10s_lambda_1_and_10(study):
    """pf settling in 40-60 ms at lambda = 1 and pf+cimm within 60 ms at 10: met at no point. The lambda = 3 buzz
    appears with a stiffer servo (12.6 Hz: 112-128 ms, contact held); pf at lambda = 6 makes and breaks wherever the
    testbed was identified."""
    for f, p in study.items():
        for key in ("pf_1_settles", "cimm_10_settles"):
            assert not _check(p, key).met, (f, key, _check(p, key).measured)
        if f != 10.0:
            assert _check(p, "pf_6_make_break").met, f
        assert _check(p, "pf_3_buzzes").met == (f == 12.6), (f, _check(p, "pf_3_buzzes").measured)
    print(study_table(list(study.values())))


def test_soft_servos_settle_too_soon_stiff_servos_ring(study):
    """Why lambda = 1 and 10 miss: at 6-8 Hz pf's lambda = 1 taps settle in 24-47 ms (the slow tap below 40 ms),
    from 12.6 Hz they outlast 60 ms; cancellation's lambda = 10 transient grows with the servo (57-62 ms at 8 Hz,
    74-76 at 12.6, 96-113 from 16 Hz)."""
    for f in (6.0, 8.0):
        assert min(r["settling_s"] for r in _taps(study[f], "pf", 1.0)) < 0.040, f
    for f in (12.6, 16.0, 20.0, 22.0):
        assert max(r["settling_s"] for r in _taps(study[f], "pf", 1.0)) > 0.060, f
    slow = [max(r["settling_s"] for r in _taps(study[f], "pf+cimm", 10.0)) for f in (8.0, 12.6, 16.0)]
    assert slow[0] < slow[1] < slow[2] and slow[0] > 0.055
    # the natural impact bounces within its first 30 ms with the rule's 8 Hz servo, never with 22 Hz
    assert max(r["contact_losses"] for r in _taps(study[8.0], "pf", 0.0)) >= 2
    assert max(r["contact_losses"] for r in _taps(study[22.0], "pf", 0.0)) == 0


def test_the_lambda_3_buzz_needs_the_static_force_to_outweigh_the_oscillation(study):
    """At 12.6 Hz the servo presses the slave on the surface harder (202 N/m against 81.5) than the lambda = 3
    oscillation pulls it off: contact held, the transient prolonged past 100 ms. At 8 Hz the same taps settle."""
    buzz = _taps(study[12.6], "pf", 3.0)
    assert all(r["contact_class"] == "buzzes" and r["settling_s"] > 0.100 for r in buzz), buzz
    assert all(r["quasi_static_N"] > r["oscillation_N"] for r in buzz)
    soft = _taps(study[8.0], "pf", 3.0)
    assert all(r["contact_class"] == "settles" for r in soft) and all(r["quasi_static_N"] < 0.15 for r in soft)


def test_bilateral_pd_on_wood_holds_after_the_impacts_bounce(study):
    """At most one bounce per tap on wood, counted after the impact's 30 ms: met at every identified servo
    (measured 0 per tap; from the impact on 1-5, test below)."""
    for f, p in study.items():
        if f != 10.0:
            assert _check(p, "pd_one_bounce").met and max(p.pd_losses) == 0, (f, p.pd_losses)


def test_counting_from_the_impact_on_turns_the_soft_servos_taps_into_make_break(cimm_model, study):
    """The count from the impact on (``--count-from-impact``, the classification before the project's): the
    natural impact bounces 2-3 times within its first 30 ms at 6-8 Hz, so every such tap counts as make-break and
    Figure 5.11's limits fall to 0 there; the taps are the same, only the counting differs."""
    # the damping the study identified at each point (the identification does not count contact losses: the
    # same damping, so the same taps, without identifying it again)
    counted = {f: servo_study(cimm_model, bandwidths_hz=(f,), damping_N_s_m=study[f].damping_N_s_m,
                              count_from_impact=True)[0] for f in (8.0, 22.0)}
    for f, p in counted.items():
        assert [r["settling_s"] for r in p.rows] == [r["settling_s"] for r in study[f].rows]
    assert all(r["contact_class"] == "make-break" for r in _taps(counted[8.0], "pf", 0.0))
    assert not _check(counted[8.0], "fig511_pf").met and not _check(counted[8.0], "fig511_cimm").met
    assert _check(study[8.0], "fig511_pf").met                       # 3, counted after the impact's bounce
    assert min(counted[8.0].pd_losses) >= 1


def test_figure_5_11s_simpler_model_is_not_what_limits_cancellation(cimm_model, study):
    """Figure 5.11 was run "with a simpler, less-accurate model of the human-master dynamics": the study's Figure 5.11
    sweep uses the identified model with its linkage made linear. With either model cancellation holds contact to
    lambda = 10 with the backlash at the rule's 8 Hz, above the thesis's 4-6 (its 4.5)."""
    simple = figure_5_11_model(cimm_model)
    assert simple.params.mechanics["hysteresis"] is False and cimm_model.params.mechanics["hysteresis"] is True
    assert "simpler model" in simple.source and simple.k_u_N_m == cimm_model.k_u_N_m
    P = default_params()
    tb = Testbed(P, P, environment=ENVIRONMENTS["hard"], backlash_m=BACKLASH_FIG_5_11_M,
                 slave_handle_damping_N_s_m=study[8.0].damping_N_s_m)
    accurate = sweep(tb, cimm_model, FIG_5_11_LAMBDAS, ["pf+cimm"], taps=2, seed=1)
    assert largest_stable(accurate, "pf+cimm") >= 8.0
    assert not _check(study[8.0], "fig511_cimm").met


def test_check_targets_reads_the_classes():
    """The checks on hand-made rows: each target met, then each missed, by the rule the docs state."""
    def row(cond, lam, cls, settling_s, losses=0, speed=0.1):
        return {"condition": cond, "lambda": lam, "speed_m_s": speed, "contact_class": cls,
                "settling_s": settling_s, "contact_losses": losses}
    rows = [row("pf", 1.0, "settles", 0.050), row("pf", 3.0, "buzzes", 0.150, 1), row("pf", 6.0, "make-break", math.inf, 9)]
    rows += [row("pf+cimm", lam, "settles", 0.050) for lam in (1.0, 3.0, 6.0, 10.0)]
    rows += [row("pf+cimm", 15.0, "settles", 0.064)]
    back = [row("pf", lam, "settles" if lam <= 2.5 else "make-break", 0.05) for lam in FIG_5_11_LAMBDAS]
    back += [row("pf+cimm", lam, "settles" if lam <= 5 else "make-break", 0.05) for lam in FIG_5_11_LAMBDAS]
    checks = {c.key: c for c in check_targets(rows, back, [1, 0, 1])}
    assert all(c.met for c in checks.values()), {k: c.measured for k, c in checks.items()}
    assert checks["fig511_pf"].measured == "2.5" and checks["fig511_cimm"].measured == "5"
    # 61 ms at lambda = 10 misses "within 60 ms"; 66 ms at 15 is 1.32x its 50 ms at 1; two bounces on wood
    rows[6] = row("pf+cimm", 10.0, "settles", 0.061)
    rows[7] = row("pf+cimm", 15.0, "settles", 0.066)
    missed = {c.key: c for c in check_targets(rows, back, [1, 2, 1])}
    assert not missed["cimm_10_settles"].met and not missed["cimm_stable_15"].met and not missed["pd_one_bounce"].met
    assert "1.32x" in missed["cimm_stable_15"].measured


def test_parse_bandwidths_names_the_option():
    assert parse_bandwidths("8, 12.6,22") == [8.0, 12.6, 22.0]
    for bad in ("", "8,-1", "8,nan", "eight"):
        with pytest.raises(ValueError, match="--servo-bandwidth-hz"):
            parse_bandwidths(bad)


def test_servo_study_command_writes_its_folder_and_refuses_overwrite(tmp_path, capsys, cimm_file):
    out = tmp_path / "study"
    argv = ["teleop-servo-study", "--servo-bandwidth-hz", "8,22", "--cimm-model", str(cimm_file), "--out", str(out)]
    assert main(argv) == 0
    rec = json.loads((out / "study.json").read_text())
    assert [p["servo_bandwidth_hz"] for p in rec["points"]] == [8.0, 22.0]
    assert rec["cimm_model"] == f"file: {cimm_file}" and rec["fixed_slave_handle_damping_N_s_m"] is None
    assert abs(rec["points"][0]["slave_handle_damping_N_s_m"] - 3.16) < 0.15  # the stored 3.2's calibration
    table = (out / "table.md").read_text()
    assert all(text in table for text in TARGETS.values()) and "| 8 Hz | 22 Hz |" in table
    trials = (out / "trials.csv").read_text().splitlines()
    assert len(trials) == 1 + 2 * (len(FIG_5_10_LAMBDAS) + len(FIG_5_11_LAMBDAS)) * 2 * 2
    assert "most targets met at one servo bandwidth" in capsys.readouterr().out
    # a second run into the same folder is refused, and the first run's files are intact
    before = (out / "study.json").read_bytes()
    assert main(argv) != 0
    assert "not empty" in capsys.readouterr().err
    assert (out / "study.json").read_bytes() == before
    # a fixed damping is used as given at every point
    out2 = tmp_path / "fixed"
    assert main(["teleop-servo-study", "--servo-bandwidth-hz", "16", "--fixed-slave-handle-damping-N-s-m", "1.8",
                 "--count-from-impact", "--cimm-model", str(cimm_file), "--out", str(out2)]) == 0
    rec2 = json.loads((out2 / "study.json").read_text())
    assert rec2["points"][0]["slave_handle_damping_N_s_m"] == 1.8
    assert rec2["contact_losses_counted_from_s"] == 0.0 and rec["contact_losses_counted_from_s"] == 0.030
    for bad, msg in ((["--servo-bandwidth-hz", "8,0"], "--servo-bandwidth-hz"),
                     (["--fixed-slave-handle-damping-N-s-m", "-1"], "--fixed-slave-handle-damping-N-s-m"),
                     (["--taps", "0"], "--taps")):
        assert main(["teleop-servo-study", *bad, "--cimm-model", str(cimm_file), "--out", str(tmp_path / "x")]) != 0
        assert msg in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
