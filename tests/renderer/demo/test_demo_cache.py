"""The demo's pipeline cache: reuse, --rebuild, damaged entries, interrupted builds (small real pipelines)."""

import json

import pytest

from renderer.demo import sim_demo
from renderer.demo.cache import PIPELINE_FIGURES, build_or_load, cache_key, figure_folder, restore_figures
from renderer.demo.config import DemoConfig
from stimuli.hfam.pipeline import PipelineSettings

SMALL = dict(identify_grips_N=(0.0, 10.0), identify_trials=1, sweep_duration_s=0.5,
             record_velocities_m_s=(0.04, 0.08, 0.12), library_velocities=3)


def test_rebuild_damage_and_reuse(tmp_path):
    s = PipelineSettings(**SMALL)
    first = build_or_load(s, tmp_path)
    assert not first.from_cache
    assert first.directory.name == f"demo-{cache_key(s)}"
    assert sorted(p.name for p in first.directory.iterdir()) == [
        "identify", "library.npz", "library_refinement.txt", "library_verification.txt", "manifest.json",
        "recordings.csv"]
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
