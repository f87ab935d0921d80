"""The HFAM build pipeline of thesis Figure 4.7, in one place.

``build``     selection of recorded taps, smoothing, model inversion, high-pass, taper, verification
              (:func:`build_library`, section 4.4.1; details in docs/hfam_library.md)
``pipeline``  device -> models + recorded taps -> library: the simulated recording and the shipped
              library (``python -m stimuli sim-library``), the demo's identify/record/build steps
"""

from .build import (MAX_SMOOTH_HZ, BuildReport, BuildSettings, Selection, band_sos, build_library, check_model,
                    file_digest, format_verification, forward_simulate, highpass_target, invert, make_proper,
                    nrmse_corr, select_taps, source_entry)

__all__ = ["MAX_SMOOTH_HZ", "BuildReport", "BuildSettings", "Selection", "band_sos", "build_library", "check_model",
           "file_digest", "format_verification", "forward_simulate", "highpass_target", "invert", "make_proper",
           "nrmse_corr", "select_taps", "source_entry"]
