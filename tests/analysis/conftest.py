"""Shared synthetic study folders for the analysis tests (written once per run, for every xdist worker:
:mod:`tests.support.shared`; readers never change them)."""

from __future__ import annotations

import warnings

import pytest

from analysis.synthetic import write_synthetic_study

from tests.support.shared import shared_folder, shared_value


@pytest.fixture(scope="session")
def study_dir(tmp_path_factory):
    """20 subjects, one missing a sample, one unfinished, with traces (Figure 4.20)."""
    return shared_folder(tmp_path_factory, "analysis_study", lambda root: write_synthetic_study(
        root, 20, seed=7, missing={"S005": ["foam", "pulse_soft"]}, unfinished=["S006"], traces=3))


@pytest.fixture(scope="session")
def complete_dir(tmp_path_factory):
    """12 complete subjects, no traces."""
    return shared_folder(tmp_path_factory, "analysis_complete", lambda root: write_synthetic_study(root, 12, seed=3))


@pytest.fixture(scope="session")
def analysed(study_dir, tmp_path_factory):
    """:func:`analysis.pipeline.analyse` of ``study_dir``, computed once per run (each worker gets its own copy)."""
    from analysis.pipeline import analyse

    def compute(_folder):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return analyse(study_dir)

    return shared_value(tmp_path_factory, "analysis_analysed", compute)


@pytest.fixture(scope="session")
def analysed_report(analysed, tmp_path_factory):
    """``write_report(analysed, <folder>/report)`` with every figure, written once per run: the report that the
    figure, model and report tests read (each module wrote its own, ~2.5 s of CPU each). Returns write_report's
    dict (``tables``, ``figures``, ``notes``, ``md``, ``html``)."""
    from analysis.report import write_report

    def write(folder):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return write_report(analysed, folder / "report")

    return shared_value(tmp_path_factory, "analysed_report", write)
