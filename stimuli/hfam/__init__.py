"""The HFAM build pipeline of thesis Figure 4.7, in one place.

``settings``  the builder's settings (:class:`BuildSettings`)
``selection`` step 1: selection of recorded taps (:func:`select_taps`)
``inversion`` model inversion (eq. 4.6), filters and the forward model (:func:`invert`, :func:`forward_simulate`)
``build``     the whole build: select, smooth, invert per grip, high-pass, taper, verify (:func:`build_library`,
              section 4.4.1; details in docs/hfam_library.md)
``pipeline``  device -> models + recorded taps -> library: the simulated recording and the shipped
              library (``python -m stimuli sim-library``), the demo's identify/record/build steps
``scoring``   the open-loop and refined libraries against the real tap on the sim, unseen conditions,
              saturation and the thermal option (:func:`score_pipeline`, :func:`hfam_claims`;
              ``python -m stimuli score-hfam``)
"""

from plumbing.lazy import lazy_exports

_EXPORTS = {"BuildReport": "build", "build_library": "build", "file_digest": "build",
            "format_verification": "build", "source_entry": "build", "band_sos": "inversion",
            "check_model": "inversion", "forward_simulate": "inversion", "highpass_target": "inversion",
            "invert": "inversion", "make_proper": "inversion", "nrmse_corr": "inversion",
            "Selection": "selection", "select_taps": "selection", "MAX_SMOOTH_HZ": "settings",
            "BuildSettings": "settings", "hfam_claims": "scoring", "score_pipeline": "scoring",
            "pipeline_libraries": "scoring"}

__all__ = ["MAX_SMOOTH_HZ", "BuildReport", "BuildSettings", "Selection", "band_sos", "build_library", "check_model",
           "file_digest", "format_verification", "forward_simulate", "highpass_target", "invert", "make_proper",
           "hfam_claims", "nrmse_corr", "pipeline_libraries", "score_pipeline", "select_taps", "source_entry"]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
