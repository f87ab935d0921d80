"""The demo's pipeline cache: reuse, --rebuild, damaged entries, interrupted builds (small real pipelines)."""

import json
import math

import pytest

from plumbing.outdir import MARKER
from renderer.demo import fidelity, sim_demo
from renderer.demo.cache import (HFAM_CLAIMS_FILE, PIPELINE_FIGURES, build_or_load, cache_key, entry_hfam_claims,
                                 figure_folder, hfam_score_settings, restore_figures)
from renderer.demo.config import DemoConfig
from stimuli.hfam import scoring
from stimuli.hfam.pipeline import PipelineSettings

SMALL = dict(identify_grips_N=(0.0, 10.0), identify_trials=1, sweep_duration_s=0.5,
             record_velocities_m_s=(0.04, 0.08, 0.12), library_velocities=3)


def test_rebuild_damage_and_reuse(tmp_path):
    s = PipelineSettings(**SMALL)
    first = build_or_load(s, tmp_path)
    assert not first.from_cache
    assert first.directory.name == f"demo-{cache_key(s)}"
    assert sorted(p.name for p in first.directory.iterdir()) == [
        MARKER, "identify", "library.npz", "library_refinement.txt", "library_verification.txt", "manifest.json",
        "pipeline_settings.json", "recordings.csv"]
    # the refinement by playback (on by default) reports its error before and after every pass: first towards
    # the smoothed recordings, then (second stage, before and after each pass) towards the recordings
    lines = (first.directory / "library_refinement.txt").read_text().splitlines()
    n = s.refine_iterations + 1 + s.refine_recording_iterations + 1
    assert [ln.split(":")[0] for ln in lines] == [f"refinement iteration {i}" for i in range(n)]
    assert sum(ln.endswith("target: recording)") for ln in lines) == s.refine_recording_iterations + 1
    assert list(first.library.grips_N) == [0.0, 10.0] and len(first.library.velocities_m_s) == 3
    created = json.loads((first.directory / "manifest.json").read_text())["created_unix"]

    again = build_or_load(s, tmp_path)
    assert again.from_cache

    rebuilt = build_or_load(s, tmp_path, rebuild=True)
    assert not rebuilt.from_cache
    assert json.loads((rebuilt.directory / "manifest.json").read_text())["created_unix"] > created

    # a damaged entry is rebuilt, not trusted
    (rebuilt.directory / "library.npz").write_bytes(b"not a library")
    healed = build_or_load(s, tmp_path)
    assert not healed.from_cache and healed.library.currents_A.shape[0] == 3
    # no temporary folders left behind
    assert [p.name for p in tmp_path.iterdir()] == [healed.directory.name]


def test_failed_build_leaves_no_entry(tmp_path):
    s = PipelineSettings(**SMALL, sample="marble")  # identification runs, then recording fails on the sample
    with pytest.raises(ValueError, match="marble"):
        build_or_load(s, tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_settings_are_validated():
    with pytest.raises(ValueError, match="identify_grips_N"):
        PipelineSettings(identify_grips_N=(2.0, 1.0))
    with pytest.raises(ValueError, match="record_velocities_m_s"):
        PipelineSettings(record_velocities_m_s=(0.1,))
    with pytest.raises(ValueError, match="sim device"):
        PipelineSettings(device="serial:/dev/ttyACM0")


def test_pipeline_figures_are_kept_and_copied_byte_for_byte(tmp_path):
    # the library and Bode figures depend only on the entry: drawn once, then copied from the cache
    pipe = build_or_load(PipelineSettings(**SMALL), tmp_path / "cache")
    assert restore_figures(pipe, tmp_path) is None          # nothing kept yet
    drawn_dir, copied_dir = tmp_path / "drawn", tmp_path / "copied"
    drawn_dir.mkdir()
    copied_dir.mkdir()
    drawn = sim_demo._pipeline_figures(pipe, DemoConfig(pipeline=PipelineSettings(**SMALL)), drawn_dir)
    assert set(drawn) == set(PIPELINE_FIGURES)
    folder = figure_folder(pipe)
    assert folder.parent == pipe.directory and folder.name.startswith("figures-")
    kept = sorted(p.name for p in folder.iterdir())
    assert kept == sorted([f"{s}{x}" for s in PIPELINE_FIGURES.values() for x in (".png", ".svg", ".plot.csv")]
                          + ["sha256.json"])
    copied = restore_figures(pipe, copied_dir)
    assert copied == {k: copied_dir / f"{s}.png" for k, s in PIPELINE_FIGURES.items()}
    for name in kept:
        if name != "sha256.json":
            assert (copied_dir / name).read_bytes() == (drawn_dir / name).read_bytes(), name
    assert not [p for p in copied_dir.iterdir() if p.name.startswith(".")]   # no temporary files left
    # a damaged kept figure is not copied (the demo draws it again)
    png = folder / "fig_library.png"
    png.write_bytes(png.read_bytes()[:-10])
    assert restore_figures(pipe, tmp_path / "copied") is None


def test_hfam_claims_of_a_library_above_every_unseen_speed_are_not_measured_and_a_corrupt_file_is_recomputed(tmp_path):
    """A library recorded at 0.2 and 0.3 m/s lies above all of the issue's unseen speeds (0.065, 0.095, 0.14 m/s):
    the refined-unseen claim is "not measured" (NaN, not holding, the speeds named), the others are scored. The
    claims kept in the entry are checked as claims: valid JSON with the wrong keys is recomputed and replaced
    (a new file renamed over it), not returned (it failed every later demo run until --rebuild)."""
    s = PipelineSettings(**{**SMALL, "record_velocities_m_s": (0.2, 0.3), "library_velocities": 2})
    pipe = build_or_load(s, tmp_path)
    v = pipe.library.velocities_m_s
    assert 0.14 < v[0] < v[-1] < 0.31
    rows = entry_hfam_claims(pipe, s)
    claims = {c.id: c for c in fidelity.claims_from_dicts(rows)}
    rf = claims["hfam_refined_unseen"]
    assert math.isnan(rf.measured) and not rf.holds
    assert rf.measured_text.startswith("not measured: no unseen speed to score")
    assert "0.065, 0.095, 0.14 m/s left out" in rf.measured_text and f"{v[0]:.4f}-{v[-1]:.4f} m/s" in rf.measured_text
    assert 0.1 < claims["hfam_open_loop"].measured < 1.5 and claims["hfam_saturation"].measured >= 0
    assert "not measured" in fidelity.format_fidelity(claims.values())

    path = pipe.directory / HFAM_CLAIMS_FILE
    assert [r["measured_text"] for r in json.loads(path.read_text())] == [r["measured_text"] for r in rows]
    path.write_text(json.dumps([{"id": "hfam_open_loop", "median": 0.1}, {"claim": "x"}]))
    inode = path.stat().st_ino
    again = entry_hfam_claims(pipe, s)
    assert [c.id for c in fidelity.claims_from_dicts(again)] == list(claims)
    assert [r["measured"] for r in again][0::2] == [rows[0]["measured"], rows[2]["measured"]]
    kept = json.loads(path.read_text())
    assert [r["id"] for r in kept] == list(claims) and path.stat().st_ino != inode
    assert [p.name for p in pipe.directory.iterdir() if p.name.startswith(".") and p.name != MARKER] == []


def test_hfam_claims_are_scored_on_the_demos_own_device_or_not_measured(tmp_path):
    """The demo's HFAM claims play on the device the demo ran on: the one-dof sim (the default), the joystick, or a
    ``sim:<params file>`` holding either (with the demo's tap stop time); on ``sim:lti`` or other parameters they
    are "not measured", never scored on another sim in its place."""
    assert hfam_score_settings(PipelineSettings()) == scoring.ScoreSettings()
    st = hfam_score_settings(PipelineSettings(tap_stop_time_s=0.06))
    assert (st.linkage, st.stop_time_s) == ("linear", 0.06)
    assert hfam_score_settings(PipelineSettings(device="sim")).linkage == "hysteretic"
    assert hfam_score_settings(PipelineSettings(device="sim:joystick")).linkage == "hysteretic"
    linear = tmp_path / "onedof.json"                              # sim:<file> with the one-dof device
    linear.write_text(json.dumps(scoring.device_params("linear").to_dict()))
    assert hfam_score_settings(PipelineSettings(device=f"sim:{linear}")).linkage == "linear"
    same = tmp_path / "table31.json"
    same.write_text(json.dumps(scoring.device_params("hysteretic").to_dict()))
    assert hfam_score_settings(PipelineSettings(device=f"sim:{same}")).linkage == "hysteretic"
    other = tmp_path / "light.json"
    other.write_text(json.dumps(scoring.device_params("hysteretic").replace(mechanics={"m_h_kg": 0.02}).to_dict()))
    for device in ("sim:lti", f"sim:{other}"):
        s = PipelineSettings(device=device)
        assert hfam_score_settings(s) is None
        rows = entry_hfam_claims(None, s)          # decided before the entry is read: nothing is scored
        claims = fidelity.claims_from_dicts(rows)
        assert [c.id for c in claims] == ["hfam_open_loop", "hfam_refined_unseen", "hfam_saturation"]
        for c in claims:
            assert math.isnan(c.measured) and not c.holds
            assert c.measured_text.startswith("not measured: ") and device in c.measured_text
