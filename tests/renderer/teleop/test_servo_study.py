"""The servo-bandwidth study (issue 37, ``renderer.teleop.servo_study``): section 5.7's targets at every natural
frequency of the servo rule from 6 to 22 Hz, the slave handle's damping re-identified on the natural impact at
each. What it measures is the reason issue 37's remaining Figure 5.10 targets are not met by choosing the servo:
below ~13 Hz the taps bounce, above it their transients outlast the thesis's ~50 ms (docs/teleop.md)."""

from __future__ import annotations

import json
import math

import pytest

from renderer.__main__ import main
from devices.sim.params import default_params
from devices.sim.teleop import BACKLASH_FIG_5_11_M, ENVIRONMENTS, Testbed
from renderer.teleop.commands import largest_stable, sweep
from renderer.teleop.servo_study import (FIG_5_10_LAMBDAS, FIG_5_11_LAMBDAS, STUDY_BANDWIDTHS_HZ, TARGETS,
                                         after_grace, check_targets, figure_5_11_model, parse_bandwidths,
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
        # the natural impact settles in 50 ms at every servo: the damping was found (0.38-2.03 N s/m measured)
        assert 0.0 < p.damping_N_s_m < 6.0, f
        assert abs(p.natural_settling_s - 0.050) < 0.01, f
        assert len(p.rows) == len(FIG_5_10_LAMBDAS) * 2 * 2 and len(p.backlash_rows) == len(FIG_5_11_LAMBDAS) * 2 * 2
        assert [c.key for c in p.checks] == list(TARGETS)
    # the stiffer the servo, the less handle damping the same 50 ms natural impact needs above 12.6 Hz
    assert study[22.0].damping_N_s_m < study[16.0].damping_N_s_m < study[12.6].damping_N_s_m


def test_no_servo_bandwidth_reproduces_figure_5_10(study):
    """pf settling at lambda = 1, pf buzzing at 3 and pf+cimm settling within 60 ms at 10: met at no point."""
    for f, p in study.items():
        for key in ("pf_1_settles", "pf_3_buzzes", "cimm_10_settles"):
            assert not _check(p, key).met, (f, key, _check(p, key).measured)
        # the one Figure 5.10 pf target every servo meets: lambda = 6 makes and breaks (44-63 losses measured)
        assert _check(p, "pf_6_make_break").met, f
    print(study_table(list(study.values())))


def test_soft_servos_bounce_stiff_servos_ring(study):
    """Why: below ~13 Hz the slave bounces off the surface (the natural impact itself 1-4 times at 6-8 Hz), from
    16 Hz it holds contact but its transient lasts longer than Figure 5.10's ~50 ms."""
    for f, p in study.items():
        pf1, c10 = _taps(p, "pf", 1.0), _taps(p, "pf+cimm", 10.0)
        if f <= 12.6:
            # pf at lambda = 1 loses contact 2-5 times per tap (measured)
            assert all(r["contact_losses"] >= 2 for r in pf1), (f, pf1)
        else:
            # contact held (at most the impact's own bounce), transient 98 ms to never (measured)
            assert all(r["contact_losses"] <= 1 and r["settling_s"] > 0.080 for r in pf1), (f, pf1)
        if f >= 10.0:
            # pf+cimm at lambda = 10 holds contact, settling 65-127 ms, growing with the servo (measured)
            assert all(r["contact_losses"] <= 1 and r["settling_s"] > 0.060 for r in c10), (f, c10)
    slow = [max(r["settling_s"] for r in _taps(study[f], "pf+cimm", 10.0)) for f in (10.0, 16.0, 22.0)]
    assert slow[0] < slow[1] < slow[2]
    # the natural impact: bounces with the rule's 8 Hz servo, none with section 4.3.1's 22 Hz slave PD
    assert max(r["contact_losses"] for r in _taps(study[8.0], "pf", 0.0)) >= 2
    assert max(r["contact_losses"] for r in _taps(study[22.0], "pf", 0.0)) == 0


def test_bilateral_pd_bounces_at_every_servo(study):
    """At most one bounce per tap on wood: no servo meets it (measured 2-11 per tap; fewest at 10-12.6 Hz)."""
    for f, p in study.items():
        assert not _check(p, "pd_one_bounce").met, f
        assert min(p.pd_losses) >= 2, (f, p.pd_losses)
    assert max(study[8.0].pd_losses) > max(study[12.6].pd_losses)


def test_counting_losses_after_the_impacts_bounce_still_leaves_figure_5_10_unmet(cimm_model, study):
    """The variant that lets the impact's own bounce pass (losses after 30 ms, ``--grace``): the natural impact then
    holds contact at every servo, but cancellation's lambda = 10 still settles within 60 ms at no point, and
    wherever pf+cimm holds contact up to lambda = 15 its lambda = 10 transient lasts 65 ms or more (measured 65-127)."""
    graced = {p.servo_bandwidth_hz: p for p in servo_study(cimm_model, grace=True)}
    for f, p in graced.items():
        assert max(r["contact_losses"] for r in _taps(p, "pf", 0.0)) <= 1, f
        assert not _check(p, "cimm_10_settles").met, (f, _check(p, "cimm_10_settles").measured)
        if _check(p, "cimm_stable_15").met:
            assert min(r["settling_s"] for r in _taps(p, "pf+cimm", 10.0)) > 0.062, f
        # the same taps: only the counting differs
        assert [r["settling_s"] for r in p.rows] == [r["settling_s"] for r in study[f].rows]
        assert all(g["contact_losses"] <= r["contact_losses"] for g, r in zip(p.rows, study[f].rows))
    assert sum(_check(p, "cimm_stable_15").met for p in graced.values()) >= 4
    # bilateral PD on wood: the bounces are the impact's (none after 30 ms at 10-20 Hz; 6-7 at 6 Hz)
    assert all(max(graced[f].pd_losses) == 0 for f in (10.0, 12.6, 16.0, 20.0))
    assert min(graced[6.0].pd_losses) >= 2
    # Figure 5.11 at the rule's 8 Hz: both limits in the thesis's ranges (measured pf 2.5, pf+cimm 5)
    assert _check(graced[8.0], "fig511_pf").met and _check(graced[8.0], "fig511_cimm").met


def test_figure_5_11s_simpler_model_is_what_brings_cancellation_into_4_to_6(cimm_model, study):
    """Figure 5.11 was run "with a simpler, less-accurate model of the human-master dynamics": the study's Figure 5.11
    sweep uses the identified model with its linkage made linear. With the accurate model instead (same backlash,
    the rule's 8 Hz, losses after the impact's 30 ms) pf+cimm holds contact to lambda = 10, above the thesis's 4-6."""
    simple = figure_5_11_model(cimm_model)
    assert simple.params.mechanics["hysteresis"] is False and cimm_model.params.mechanics["hysteresis"] is True
    assert "simpler model" in simple.source and simple.k_u_N_m == cimm_model.k_u_N_m
    P = default_params()
    tb = Testbed(P, P, environment=ENVIRONMENTS["hard"], backlash_m=BACKLASH_FIG_5_11_M,
                 slave_handle_damping_N_s_m=study[8.0].damping_N_s_m)
    accurate = after_grace(sweep(tb, cimm_model, FIG_5_11_LAMBDAS, ["pf+cimm"], taps=2, seed=1))
    assert largest_stable(accurate, "pf+cimm") >= 8.0   # measured 10


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
    assert abs(rec["points"][0]["slave_handle_damping_N_s_m"] - 1.79) < 0.1   # the stored 1.8's calibration
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
                 "--grace", "--cimm-model", str(cimm_file), "--out", str(out2)]) == 0
    rec2 = json.loads((out2 / "study.json").read_text())
    assert rec2["points"][0]["slave_handle_damping_N_s_m"] == 1.8
    assert rec2["contact_losses_counted_from_s"] == 0.030 and rec["contact_losses_counted_from_s"] == 0.0
    for bad, msg in ((["--servo-bandwidth-hz", "8,0"], "--servo-bandwidth-hz"),
                     (["--fixed-slave-handle-damping-N-s-m", "-1"], "--fixed-slave-handle-damping-N-s-m"),
                     (["--taps", "0"], "--taps")):
        assert main(["teleop-servo-study", *bad, "--cimm-model", str(cimm_file), "--out", str(tmp_path / "x")]) != 0
        assert msg in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
