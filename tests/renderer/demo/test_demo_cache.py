"""The demo's pipeline cache: reuse, --rebuild, damaged entries, interrupted builds (small real pipelines)."""

import json

import pytest

from renderer.demo.cache import build_or_load, cache_key
from stimuli.hfam.pipeline import PipelineSettings

SMALL = dict(identify_grips_N=(0.0, 10.0), identify_trials=1, sweep_duration_s=0.5,
             record_velocities_m_s=(0.04, 0.08, 0.12), library_velocities=3)


def test_rebuild_damage_and_reuse(tmp_path):
    s = PipelineSettings(**SMALL)
    first = build_or_load(s, tmp_path)
    assert not first.from_cache
    assert first.directory.name == f"demo-{cache_key(s)}"
    assert sorted(p.name for p in first.directory.iterdir()) == [
        "identify", "library.npz", "library_verification.txt", "manifest.json", "recordings.csv"]
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
