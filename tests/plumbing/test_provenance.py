"""plumbing.provenance: the versions recorded with every result."""

import importlib.metadata
import subprocess
from pathlib import Path

from plumbing import provenance

ROOT = Path(__file__).resolve().parents[2]


def test_versions_are_the_installed_ones_and_the_checkout_commit():
    v = provenance.software_versions()
    for dist in provenance.RESULT_PACKAGES:
        assert v[dist] == importlib.metadata.version(dist)
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode == 0:   # a checkout: the commit is recorded
        assert v["git_commit"] == head.stdout.strip() and isinstance(v["git_dirty"], bool)
        assert provenance.version_line().startswith(f"hfam-haptics {v['hfam-haptics']} (git {v['git_commit'][:8]}")


def test_outside_a_checkout_the_commit_is_none(tmp_path):
    assert provenance.git_commit(tmp_path) == (None, None)


def test_fast_version_lookup_agrees_with_importlib_metadata_and_prefetch_gives_the_same():
    """The dist-info folder scan is a shortcut for importlib.metadata.version: same answers, also for
    spellings that differ from the folder's (``hfam-haptics`` vs ``hfam_haptics``) and for no install."""
    for dist in (*provenance.RESULT_PACKAGES, "hfam-haptics", "HFAM.Haptics", "pytest", "pip"):
        assert provenance._dist_version(dist) == importlib.metadata.version(dist), dist
    assert provenance._dist_version("no-such-distribution-xyz") is None
    before = provenance.software_versions()
    provenance._versions_once.cache_clear()
    provenance.prefetch()
    assert provenance.software_versions() == before
