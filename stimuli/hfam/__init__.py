"""The HFAM build pipeline of thesis Figure 4.7, in one place.

``settings``  the builder's settings (:class:`BuildSettings`)
``selection`` step 1: selection of recorded taps (:func:`select_taps`)
``inversion`` model inversion (eq. 4.6), filters and the forward model (:func:`invert`, :func:`forward_simulate`)
``build``     the whole build: select, smooth, invert per grip, high-pass, taper, verify (:func:`build_library`,
              section 4.4.1; details in docs/hfam_library.md)
``pipeline``  device -> models + recorded taps -> library: the simulated recording and the shipped
              library (``python -m stimuli sim-library``), the demo's identify/record/build steps
"""

from .build import BuildReport, build_library, file_digest, format_verification, source_entry
from .inversion import band_sos, check_model, forward_simulate, highpass_target, invert, make_proper, nrmse_corr
from .selection import Selection, select_taps
from .settings import MAX_SMOOTH_HZ, BuildSettings

__all__ = ["MAX_SMOOTH_HZ", "BuildReport", "BuildSettings", "Selection", "band_sos", "build_library", "check_model",
           "file_digest", "format_verification", "forward_simulate", "highpass_target", "invert", "make_proper",
           "nrmse_corr", "select_taps", "source_entry"]
