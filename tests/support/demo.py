"""The demo's HFAM pipeline with its default settings, built once per test run for every xdist worker.

The sim demo (``renderer.demo``) first identifies the simulated device, records taps and builds an HFAM library
(``stimuli.hfam.pipeline``, ~15 s of CPU), then taps. Its cache (``renderer.demo.cache``) keeps the pipeline's
products by their settings. :func:`default_pipeline_cache` is a cache folder holding the entry of the default
settings (``PipelineSettings()``), built once per run (:mod:`tests.support.shared`); every demo run with the
default pipeline given this folder as its cache loads the entry instead of building it again.
"""

from __future__ import annotations

from pathlib import Path

from tests.support.shared import shared_folder


def default_pipeline_cache(tmp_path_factory) -> Path:
    """A demo cache folder holding the default pipeline's entry; readers must not change it."""
    from renderer.demo.cache import build_or_load
    from stimuli.hfam.pipeline import PipelineSettings, Progress

    def build(folder: Path) -> None:
        build_or_load(PipelineSettings(), folder, progress=Progress(3, quiet=True))

    return shared_folder(tmp_path_factory, "default_pipeline_cache", build)


def default_pipeline_entry(tmp_path_factory) -> Path:
    """The default pipeline's products (``identify/``, ``recordings.csv``, ``library.npz``, ...): the folder
    ``stimuli.hfam.pipeline.build_pipeline(folder, PipelineSettings())`` fills."""
    from renderer.demo.cache import cache_key
    from stimuli.hfam.pipeline import PipelineSettings

    return default_pipeline_cache(tmp_path_factory) / f"demo-{cache_key(PipelineSettings())}"
