"""Tests that need a system part ask here: it fails (or, with HFAM_MISSING_DEPS=skip, skips) naming the fix."""

import os

import pytest

from plumbing import sysdeps


def need(component: str) -> None:
    """Fail the test unless ``component`` (a key of ``plumbing.sysdeps.COMPONENTS``) is available.

    A missing part is a failure, never a silent skip; ``HFAM_MISSING_DEPS=skip`` (opt-in) skips with the reason.
    """
    try:
        sysdeps.require(component)
    except sysdeps.MissingDependency as exc:
        if os.environ.get("HFAM_MISSING_DEPS") == "skip":
            pytest.skip(f"HFAM_MISSING_DEPS=skip: {exc}")
        pytest.fail(str(exc), pytrace=False)


def chromium() -> str:
    """The Chromium program for playwright's ``executable_path`` (provisioned wrapper or Debian's)."""
    need("chromium")
    return sysdeps.chromium()
