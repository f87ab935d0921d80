"""HFAM scoring: the open-loop and refined libraries against the real tap on the sim, the
unseen conditions, saturation flagging and the thermal option (stimuli/hfam/scoring.py, docs/hfam_library.md).

One pipeline (identify, record, build, refine: the demo's defaults, on the one-dof device ``sim:onedof``) and one
scoring run per module, plus one unrefined pipeline and open-loop scoring on the hysteretic joystick (``--linkage
hysteretic``, ~30 s); every number asserted is recomputed here from the sim.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import stats

from devices.sim import SimDevice, TapTrajectory
from stimuli.__main__ import main
from stimuli.hfam import scoring as S
from stimuli.hfam.pipeline import PipelineSettings, Progress, build_pipeline
from stimuli.library import HfamLibrary
from tests.support.demo import default_pipeline_entry

CLAIM_KEYS = ["id", "section", "thesis", "target", "measured", "measured_text", "holds"]


@pytest.fixture(scope="module")
def pipe(tmp_path_factory):
    """The demo's pipeline (default PipelineSettings), built once per test run (tests/support/demo.py); read only."""
    return default_pipeline_entry(tmp_path_factory)


@pytest.fixture(scope="module")
def libs(pipe):
    """(open_loop, refined, raised, models) of the pipeline."""
    return S.pipeline_libraries(pipe)


@pytest.fixture(scope="module")
def scores(libs):
    """The whole scoring with its defaults."""
    return S.score_pipeline(*libs[:3], libs[3])


@pytest.fixture(scope="module")
def joystick_pipe(tmp_path_factory):
    """The demo's pipeline on the hysteretic joystick (``--linkage hysteretic``) up to the open-loop library: the
    open-loop target is about the library before any refinement, so none is run (saves ~10 s)."""
    out = tmp_path_factory.mktemp("hfam_pipeline_joystick")
    device = S.pipeline_device(out, "hysteretic")
    build_pipeline(out, PipelineSettings(device=device, refine_iterations=0, refine_recording_iterations=0),
                   Progress(3, quiet=True))
    return out


@pytest.fixture(scope="module")
def joystick(joystick_pipe):
    """(open-loop cells, model mismatch) of the hysteretic joystick over the open-loop grid."""
    open_loop, _, _, models = S.pipeline_libraries(joystick_pipe)
    st = S.ScoreSettings(linkage="hysteretic")
    return (S.score_library(open_loop, S.OPEN_LOOP_SPEEDS_M_S, S.GRIPS_N, st),
            S.model_mismatch(open_loop, models, S.OPEN_LOOP_SPEEDS_M_S, S.GRIPS_N, st))


def test_the_open_loop_library_is_the_one_the_pipeline_refined(pipe, libs):
    """Rebuilt from the pipeline folder by its own build step: the same velocities, grips and targets as the
    refined library, the same currents where the refinement did not touch them (grip 0 N), and a rebuild
    gives the same currents."""
    open_loop, refined = libs[0], HfamLibrary.load(pipe / "library.npz")
    assert np.array_equal(open_loop.velocities_m_s, refined.velocities_m_s)
    assert np.array_equal(open_loop.grips_N, refined.grips_N)
    assert np.array_equal(open_loop.desired_accel_m_s2, refined.desired_accel_m_s2)
    assert "refinement" in refined.metadata and "refinement" not in open_loop.metadata
    assert np.array_equal(open_loop.currents_A[:, 0], refined.currents_A[:, 0])       # 0 N: not refined
    assert np.max(np.abs(refined.currents_A[:, 1:] - open_loop.currents_A[:, 1:])) > 0.05
    assert np.array_equal(S.pipeline_libraries(pipe)[0].currents_A, open_loop.currents_A)


def test_claims_are_one_row_per_target_with_the_issue_keys(scores):
    claims = S.hfam_claims(scores)
    assert [c["id"] for c in claims] == ["hfam_open_loop", "hfam_refined_unseen", "hfam_saturation"]
    for c in claims:
        assert list(c) == CLAIM_KEYS
        assert isinstance(c["holds"], bool) and math.isfinite(c["measured"])
        assert c["section"] in ("4.4.1", "4.4.3") and c["thesis"] and c["target"] and c["measured_text"]
    json.dumps(claims)                                   # the demo writes them to fidelity.csv / JSON
    ol, rf = S.summarise(scores.open_loop), S.summarise(scores.refined)
    assert claims[0]["measured"] == ol["median_nrmse"]
    assert claims[0]["holds"] == (ol["median_nrmse"] <= 0.30 and ol["worst_nrmse"] <= 0.40 and ol["min_corr"] >= 0.9)
    assert claims[1]["holds"] == (rf["median_nrmse"] <= 0.28 and rf["worst_nrmse"] <= 0.38)


def test_open_loop_target(scores):
    """Item 5's open-loop target on the one-dof device (the default, section 4.4.3's testbed): met with no cell
    saturated (measured: median 0.202, worst 0.266, lowest correlation 0.966)."""
    assert len(scores.open_loop) == 18 and not any(c.saturated for c in scores.open_loop)
    m = S.summarise(scores.open_loop)
    assert m["median_nrmse"] <= 0.30 and m["worst_nrmse"] <= 0.40 and m["min_corr"] >= 0.9, m
    # the smoothed targets themselves sit 0.15-0.3 from the real tap (one per library velocity: all 12 recordings
    # are selected since the "high incoming acceleration" check looks before the impact only; it dropped 3)
    floor = [r["nrmse"] for r in scores.target_floor]
    assert len(floor) == 12 and all(0.1 < f < 0.3 for f in floor), floor


def test_open_loop_scores_follow_the_model_mismatch_on_the_joystick(joystick):
    """Why the open loop misses on the hysteretic joystick: over the grid, a cell's NRMSE against the real tap
    rises with how far the sim's response to its transient is from the inversion's LTI model (superposition),
    which rises with tap speed."""
    cells, mismatch = joystick
    by_cell = {(c.velocity_m_s, c.grip_N): c.nrmse for c in cells}
    mism = {(r["velocity_m_s"], r["grip_N"]): r["nrmse"] for r in mismatch}
    keys = sorted(by_cell)
    rho = stats.spearmanr([by_cell[k] for k in keys], [mism[k] for k in keys]).statistic
    assert rho > 0.7, rho
    slow = [mism[k] for k in keys if k[0] <= 0.08]
    fast = [mism[k] for k in keys if k[0] >= 0.11]
    assert np.mean(fast) > np.mean(slow) + 0.05, (slow, fast)
    assert all(by_cell[k] > 0.8 * mism[k] for k in keys)


def test_open_loop_target_misses_on_the_joystick(joystick):
    """The same pipeline and scoring on the Table 3.1 joystick (its hysteretic linkage, section 3.5.3): the
    open-loop library misses item 5's target, as section 4.2.2 expects of a nonlinear part that is not "fixed or
    replaced to enable the use of a linear model"."""
    cells, _ = joystick
    m = S.summarise(cells)
    assert not (m["median_nrmse"] <= 0.30 and m["worst_nrmse"] <= 0.40), m


def test_the_open_loop_miss_is_the_linkage_hysteresis(scores, joystick):
    """The joystick's model mismatch (the sim's response to a transient against the identified LTI model) grows
    with tap speed, i.e. with the transient's current, as the hysteretic linkage's resonance moves with amplitude
    (section 3.5.3); on the one-dof device it stays flat and low at every speed, and the fast cells the joystick
    loses come back."""
    joy_cells, joy_mism = joystick
    hyst = {(c.velocity_m_s, c.grip_N): c for c in joy_cells}
    lin = {(c.velocity_m_s, c.grip_N): c for c in scores.open_loop}
    assert set(hyst) == set(lin)
    for name, rows, flat in (("hysteretic", joy_mism, False), ("linear", scores.model_mismatch, True)):
        slow = np.mean([r["nrmse"] for r in rows if r["velocity_m_s"] <= 0.08])
        fast = np.mean([r["nrmse"] for r in rows if r["velocity_m_s"] >= 0.11])
        if flat:
            assert abs(fast - slow) < 0.05 and max(r["nrmse"] for r in rows) < 0.3, (name, slow, fast)
        else:
            assert fast > slow + 0.05, (name, slow, fast)
    for k in hyst:
        if k[0] >= 0.14 and not hyst[k].saturated:
            assert lin[k].nrmse < hyst[k].nrmse - 0.05, k
    assert S.summarise(scores.open_loop)["median_nrmse"] < S.summarise(joy_cells)["median_nrmse"] - 0.05


def test_refined_library_generalises_for_the_recording_person(scores):
    """The refined library at speeds between its velocities and grips between its levels, tapped by the
    person it was refined with: within the issue's refined targets."""
    own = [c for c in scores.refined if c.person == S.DEFAULT_PERSON_NAME]
    assert len(own) == 6
    # only the fastest unseen speed reaches the refined library's current clip (saturated, excluded from the
    # summary); it generalises there too
    sat = [c for c in own if c.saturated]
    assert len(sat) <= 2 and all(c.velocity_m_s > 0.14 for c in sat), [(c.velocity_m_s, c.grip_N) for c in sat]
    assert all(c.nrmse <= 0.38 for c in own), [(c.velocity_m_s, c.grip_N, c.nrmse) for c in own]
    m = S.summarise(own)
    assert m["median_nrmse"] <= 0.28 and m["worst_nrmse"] <= 0.38, m
    assert m["min_corr"] >= 0.9


def test_refined_target_over_both_persons(scores):
    """Item 5's refined target at unseen conditions over both persons: met on the one-dof device with the fingertip
    person (measured median 0.246, worst 0.357; it missed, median 0.281 / worst 0.412, while the grip impedance sat
    on the handle itself and the two persons' real taps differed by 0.32-0.36 instead of 0.18-0.25)."""
    m = S.summarise(scores.refined)
    assert m["median_nrmse"] <= 0.28 and m["worst_nrmse"] <= 0.38


def test_second_person_is_farther_from_own_real_tap_than_from_the_recordings(scores):
    """The refined library plays for the second person closer to the recording person's real tap than to that
    person's own: it carries the recordings, and the two persons' real taps differ by >= 0.15 (measured 0.18-0.25:
    behind the fingertip the heavier arm changes the real tap less than it did on the handle itself, 0.28-0.31)."""
    other = {(c.velocity_m_s, c.grip_N): c for c in scores.refined if c.person == S.SECOND_PERSON_NAME}
    vs_rec = {(c.velocity_m_s, c.grip_N): c for c in scores.refined_recording_reference
              if c.person == S.SECOND_PERSON_NAME}
    assert len(other) == 6 and set(other) == set(vs_rec)
    for k in other:
        assert other[k].v_in_m_s == vs_rec[k].v_in_m_s            # the same tap, two references
        assert other[k].nrmse > vs_rec[k].nrmse + 0.03, k
    assert all(r["nrmse"] >= 0.15 for r in scores.person_floor), scores.person_floor
    assert S.summarise(list(vs_rec.values()))["worst_nrmse"] <= 0.38


def test_unseen_conditions_are_between_the_library_points(libs, scores):
    refined = libs[1]
    speeds = sorted({c.velocity_m_s for c in scores.refined})
    assert speeds == sorted(S.unseen_speeds(refined))
    v = refined.velocities_m_s
    for s in speeds:
        k = int(np.searchsorted(v, s))
        assert abs(s - 0.5 * (v[k - 1] + v[k])) < 1e-4
    assert {c.grip_N for c in scores.refined} == {1.5, 2.5}
    assert {c.person for c in scores.refined} == {S.DEFAULT_PERSON_NAME, S.SECOND_PERSON_NAME}
    with pytest.raises(ValueError, match="near the library's own velocity"):
        S.generalisation_conditions(refined, [float(v[4]) + 1e-4])
    with pytest.raises(ValueError, match="grip 2 N is one of the library's grip levels"):
        S.generalisation_conditions(refined, [S.unseen_speeds(refined)[0]], [2.0])


def test_saturation_is_flagged_counted_and_excluded(scores):
    """Section 4.4.3: a cell whose command reached the amplifier limit is saturated; the summary leaves it out.
    At the sim's 4 A the fast, firm-grip cells saturate (0.3 m/s x 3 N among them); the raised limit takes
    every one of them below its clamp, with currents above the old limit."""
    grid = scores.saturation_grid
    for c in grid:
        assert c.saturated == (c.peak_command_A >= c.limit_A * (1 - 1e-9)) and c.limit_A == 4.0
    sat = [c for c in grid if c.saturated]
    assert any(c.velocity_m_s == 0.3 and c.grip_N == 3.0 for c in sat)
    assert all(c.velocity_m_s >= 0.14 for c in sat)
    m = S.summarise(grid)
    assert m["n_saturated"] == len(sat) and m["n_scored"] == len(grid) - len(sat)
    assert m["worst_nrmse"] == max(c.nrmse for c in grid if not c.saturated)
    raised = {(c.velocity_m_s, c.grip_N): c for c in scores.saturation_grid_raised}
    assert S.summarise(scores.saturation_grid_raised)["n_saturated"] < len(sat)
    # the wall's own (steady-state) current stays under the device's peak in every tap: one clamp on the sum
    # stands for Figure 4.9's two levels
    assert all(0.0 < c.wall_peak_A < 1.0 for c in scores.saturation_grid_raised)
    for c in sat:
        r = raised[(c.velocity_m_s, c.grip_N)]
        assert r.limit_A == scores.transient_limit_A and r.peak_command_A > 4.0
        assert r.nrmse < c.nrmse + 0.02                   # no worse than clipped
    assert S.hfam_claims(scores)[2]["measured"] == len(sat)


def test_thermal_numbers_follow_the_winding_model(scores):
    """Each tap's winding temperature rise (the sim's thermal state) equals R R_th / tau x its heat (the
    first-order model over a tap much shorter than tau), and the sustained tap rate follows from I_cont."""
    info = SimDevice().info
    k = info.winding_resistance_ohm * info.thermal_resistance_K_W / info.thermal_time_constant_s
    for c in scores.saturation_grid_raised + scores.saturation_grid:
        assert c.temp_rise_K == pytest.approx(k * c.heat_A2s, rel=0.02), c
    th = scores.thermal
    assert th["max_temp_rise_K"] < th["limit_K"]
    assert th["taps_per_min"] == pytest.approx(60 * info.current_continuous_A ** 2 / th["max_heat_A2s"])
    assert scores.thermal["max_heat_A2s"] > scores.thermal_default["max_heat_A2s"]


def test_raised_limit_stays_inside_the_thermal_model():
    """max_transient_limit_A is the current a 100 ms transient may hold from cold: the sim's winding reaches
    (0.99)^2 of its limit holding 0.99 of it for 100 ms; beyond it the option is refused."""
    top = S.max_transient_limit_A(SimDevice().info)
    dev = S.raised_limit_device_factory(0.99 * top)()
    assert dev.info.current_amplifier_A == pytest.approx(0.99 * top) and dev.info.current_continuous_A == 1.26
    dev.set_user(TapTrajectory(0.05, n_taps=1), grip_N=2.0)
    with dev:
        for _ in range(1000):
            dev.command(0.99 * top)
            dev.read()
        rise = dev.true_state()["winding_temp_rise_K"]
    assert rise == pytest.approx(0.99 ** 2 * dev.info.winding_max_temp_rise_K, rel=1e-3)
    with pytest.raises(ValueError, match="between the device's peak current 4 A"):
        S.raised_limit_device_factory(1.01 * top)
    with pytest.raises(ValueError, match="between the device's peak current 4 A"):
        S.raised_limit_device_factory(3.0)


def test_score_settings_refuse_bad_values():
    for kw, msg in (({"wall_N_m": -1.0}, "wall_N_m"), ({"reference_person": "other"}, "reference_person"),
                    ({"linkage": "rigid"}, "linkage"),
                    ({"band_hz": (100.0, 20.0)}, "band_hz"), ({"max_lag_s": 0.05}, "max_lag_s"),
                    ({"pre_s": 0.0001}, "pre_s")):
        with pytest.raises(ValueError, match=msg):
            S.ScoreSettings(**kw)


def test_score_hfam_command(pipe, tmp_path, capsys):
    """``python -m stimuli score-hfam`` on an existing pipeline, small grids: prints the tables, writes the CSV
    and the claims, refuses to overwrite them and names bad input."""
    out = tmp_path / "scores"
    argv = ["score-hfam", "--out", str(out), "--pipeline", str(pipe), "--speeds-m-s", "0.05,0.3",
            "--grips-N", "3", "--unseen-grips-N", "1.5"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "Open-loop library" in text and "Claims:" in text and "SAT (excluded)" in text
    rows = (out / "scores.csv").read_text().splitlines()
    assert rows[0].startswith("set,person,velocity_m_s,grip_N")
    assert sum(r.startswith("open_loop,") for r in rows) == 2
    claims = json.loads((out / "claims.json").read_text())
    assert [list(c) for c in claims] == [CLAIM_KEYS] * 3
    assert main(argv) == 2
    assert "already holds earlier scores" in capsys.readouterr().err
    assert main(argv[:3] + ["--force", "--pipeline", str(tmp_path / "none")]) == 2
    assert "none/library.npz: not found" in capsys.readouterr().err
    assert main(["score-hfam", "--out", str(tmp_path / "o2"), "--pipeline", str(pipe), "--unseen-speeds-m-s",
                 str(float(HfamLibrary.load(pipe / "library.npz").velocities_m_s[3]))]) == 2
    assert "not an unseen condition" in capsys.readouterr().err
    assert main(["score-hfam", "--out", str(tmp_path / "o3"), "--pipeline", str(pipe), "--transient-limit-A", "2"]) == 2
    assert "transient limit 2.0 A must be between" in capsys.readouterr().err
    assert not (tmp_path / "o2").exists() and not (tmp_path / "o3").exists()


def test_score_hfam_linkage_option(pipe, joystick_pipe, tmp_path, capsys):
    """``--linkage``: a pipeline folder records the device it ran on (``pipeline_settings.json``), is scored on
    that device (the report and every CSV row name it) and refuses the other device; the default folder is the
    one-dof (linear) one."""
    assert S.pipeline_linkage(pipe) == "linear" and S.pipeline_linkage(joystick_pipe) == "hysteretic"
    out = tmp_path / "joy"
    argv = ["score-hfam", "--out", str(out), "--pipeline", str(joystick_pipe), "--speeds-m-s", "0.14",
            "--grips-N", "2", "--unseen-grips-N", "1.5"]
    assert main(argv + ["--linkage", "hysteretic"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("Device: the sim joystick of Table 3.1 with its hysteretic linkage")
    rows = (out / "scores.csv").read_text().splitlines()
    assert rows[0].endswith(",linkage") and all(r.endswith(",hysteretic") for r in rows[1:])
    assert main(argv[:1] + ["--out", str(tmp_path / "h"), *argv[3:], "--linkage", "linear"]) == 2
    assert "--linkage linear: the pipeline folder" in capsys.readouterr().err
    assert main(["score-hfam", "--out", str(tmp_path / "h2"), "--pipeline", str(pipe), "--linkage", "hysteretic"]) == 2
    assert "was run on the linear device" in capsys.readouterr().err
    assert not (tmp_path / "h").exists() and not (tmp_path / "h2").exists()
    (tmp_path / "odd").mkdir()
    with pytest.raises(FileNotFoundError, match="odd/library.npz: not found"):
        S.pipeline_linkage(tmp_path / "odd")
    (tmp_path / "odd" / "library.npz").write_bytes(b"")
    (tmp_path / "odd" / S.DEVICE_FILE).write_text(json.dumps(S.device_params("hysteretic").replace(
        mechanics={"m_h_kg": 0.02}).to_dict()))
    with pytest.raises(ValueError, match="neither of the scoring's devices"):
        S.pipeline_linkage(tmp_path / "odd")


@pytest.mark.parametrize("flag, value, says", [
    ("--speeds-m-s", "0.002", "slower than the slowest tap the scoring plays, 0.02 m/s"),  # was a RuntimeError
    ("--speeds-m-s", "1e-9", "slower than the slowest tap"),           # was a numpy MemoryError (a 10^7 s tap)
    ("--speeds-m-s", "100", "not a tap speed of a hand"),              # was accepted
    ("--unseen-speeds-m-s", "0.01", "slower than the slowest tap"),
    ("--unseen-grips-N", "1000", "outside the grip range of sim-joystick, 0-10 N"),  # was accepted
    ("--grips-N", "2,30", "outside the grip range"),
])
def test_score_hfam_refuses_speeds_and_grips_outside_the_devices_range(flag, value, says, tmp_path, capsys):
    """Every speed and grip list is checked at the command line before any work: one ``error:`` line naming the
    flag and the value, exit 2, no traceback, nothing written."""
    assert main(["score-hfam", "--out", str(tmp_path / "o"), flag, value]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {flag} ") and says in err, err
    assert value.split(",")[-1].replace("1e-9", "1e-09") in lines[0]
    assert "Traceback" not in err and not (tmp_path / "o").exists()


def test_a_real_tap_that_never_reaches_the_sample_is_a_value_error_naming_speed_and_grip():
    """Below the scoring's slowest speed the sim's motor-off tap stops before the sample (0.01 m/s at 2 N):
    refused as bad input (ValueError, printed as one ``error:`` line), not a RuntimeError; 0.02 m/s (the floor)
    reaches it at 1 N."""
    st = S.ScoreSettings()
    factory = S.default_device_factory(st.seed)
    with pytest.raises(ValueError, match=r"tap at 0\.01 m/s, 2 N grip never reached the sample"):
        S.real_reference(0.01, 2.0, None, st, factory, 1031)
    window = S.real_reference(S.MIN_SPEED_M_S, 1.0, None, st, factory, 1031)
    assert np.all(np.isfinite(window)) and np.max(np.abs(window)) > 1.0


def test_a_demo_entry_is_scored_on_the_device_its_manifest_names(tmp_path):
    """A demo cache entry has no device_params.json but its manifest.json names the device: ``sim`` and a
    ``sim:<file>`` of the linear device are scored on theirs, ``sim:lti`` is refused (it was called hysteretic)."""
    entry = tmp_path / "demo-entry"
    entry.mkdir()
    (entry / "library.npz").write_bytes(b"")
    manifest = entry / "manifest.json"
    for device, want in (("sim", "hysteretic"), ("sim:joystick", "hysteretic"), ("sim:onedof", "linear"),
                         (S.pipeline_device(tmp_path, "linear"), "linear")):
        manifest.write_text(json.dumps({"settings": {"device": device}}))
        assert S.pipeline_linkage(entry) == want
    manifest.write_text(json.dumps({"settings": {"device": "sim:lti"}}))
    with pytest.raises(ValueError, match="this pipeline ran on sim:lti"):
        S.pipeline_linkage(entry)
