"""Shared synthetic study folders for the analysis tests (written once per session)."""

from __future__ import annotations

import warnings

import pytest

from analysis.synthetic import write_synthetic_study


@pytest.fixture(scope="session")
def study_dir(tmp_path_factory):
    """20 subjects, one missing a sample, one unfinished, with traces (Figure 4.20)."""
    root = tmp_path_factory.mktemp("study")
    write_synthetic_study(root, 20, seed=7, missing={"S005": ["foam", "pulse_soft"]}, unfinished=["S006"],
                          traces=3)
    return root


@pytest.fixture(scope="session")
def complete_dir(tmp_path_factory):
    """12 complete subjects, no traces."""
    root = tmp_path_factory.mktemp("complete")
    write_synthetic_study(root, 12, seed=3)
    return root


@pytest.fixture(scope="session")
def analysed(study_dir):
    from analysis.pipeline import analyse
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return analyse(study_dir)
