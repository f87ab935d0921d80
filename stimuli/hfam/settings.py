"""Settings of the HFAM library builder (:class:`BuildSettings`, section 4.4.1; docs/hfam_library.md)."""

from __future__ import annotations

from dataclasses import dataclass

from plumbing.validation import require_int, require_number, require_positive


MAX_SMOOTH_HZ = 1000.0  # bandwidth of human vibrotactile perception (section 4.4.1)


@dataclass(frozen=True)
class BuildSettings:
    """Settings of the library builder (all in SI units).

    Attributes
    ----------
    n_velocities : int
        Number of velocities to pick (nicely spaced) from the usable taps.
    taps : tuple of int or None
        Explicit tap ids to use instead of the automatic selection.
    duration_s : float
        Transient length after impact (thesis: 100 ms).
    max_pre_impact_ratio : float
        Drop a tap whose peak |acceleration| before impact exceeds this
        fraction of its peak after impact ("high incoming acceleration").
    min_neighbour_corr : float
        Drop a tap whose median peak correlation with its (up to four) nearest
        neighbours in velocity is below this ("atypical").
    pre_pad_s, post_pad_s : float
        Zero padding before/after the recording during processing.
    smooth_hz : float
        Cut-off of the zero-phase Butterworth smoothing low-pass (<= 1000 Hz).
    smooth_order : int
        Its order (run twice by sosfiltfilt).
    added_zero_hz, added_zero_zeta : float
        Frequency and damping of the zeros added to make a strictly proper
        model proper (section 4.2.2: 800 Hz, 0.5).
    highpass_hz : float
        Cut-off of the second-order high-pass on the current (section 4.4.1: ~10 Hz).
    taper_s : float
        Length of the half-cosine taper at the end of each transient.
    onset_delay_s : float
        Constant delay accepted between impact and the realised acceleration,
        so the non-causal start of the current (zero-phase smoothing spreads
        the abrupt onset before t = 0, right-half-plane zeros need
        pre-actuation) is played rather than cut off; the thesis accepts the
        same few-sample delay from windowed smoothing (section 4.2.2). 0 cuts
        everything before impact.
    zero_phase_added_zeros : bool
        Apply the low-pass that the added zeros become in the inverse as its
        magnitude only (zero phase, offline) instead of causally (thesis, real
        time): no phase lag inside the band.
    highpass_phase : str
        Phase of the high-pass the inverse starts from: ``causal`` (Tustin
        Butterworth), ``zero`` (its magnitude only, offline like the
        smoothing) or ``best`` (default): both, keeping per velocity and grip
        the one whose windowed current (after ``window_iterations``) makes the
        desired acceleration more closely through the model over
        ``verify_band_hz``. Section 4.4.1 asks for a second-order high-pass
        near 10 Hz so the transient does not try to make accelerations below
        ~8 Hz; a causal Butterworth also turns the phase of a tap's 20-60 Hz
        content by 43-13 deg, which alone cost NRMSE ~0.26 against the sim's
        recordings over 20-1000 Hz (docs/demo.md, "Why HFAM missed the real tap").
    window_iterations : int
        Corrective passes on the windowed current (``build._current``): its
        model response's error to the desired acceleration (the recording
        high-passed without phase turn), band-limited to ``verify_band_hz``,
        inverted causally and added inside the window. 0: the cut inverse.
    gain : float
        Optional gain on all currents (section 4.4.1).
    verify_band_hz : (float, float)
        Band of the verification comparison (20-1000 Hz).
    peak_current_A : float or None
        Device peak current limit; None skips the check.
    scale_to_limit : bool
        Scale a transient above ``peak_current_A`` down to it (and say so)
        instead of stopping.
    max_extrapolation : float
        Stored in the library: cap of v_in/v_max above the velocity range.
    """

    n_velocities: int = 8
    taps: tuple[int, ...] | None = None
    duration_s: float = 0.1
    max_pre_impact_ratio: float = 0.2
    min_neighbour_corr: float = 0.5
    pre_pad_s: float = 0.1
    post_pad_s: float = 0.2
    smooth_hz: float = 500.0
    smooth_order: int = 4
    added_zero_hz: float = 800.0
    added_zero_zeta: float = 0.5
    highpass_hz: float = 10.0
    taper_s: float = 0.02
    onset_delay_s: float = 0.002
    zero_phase_added_zeros: bool = True
    highpass_phase: str = "best"
    window_iterations: int = 4
    gain: float = 1.0
    verify_band_hz: tuple[float, float] = (20.0, 1000.0)
    peak_current_A: float | None = None
    scale_to_limit: bool = False
    max_extrapolation: float = 1.5

    def __post_init__(self) -> None:
        require_positive(self, "duration_s", "pre_pad_s", "post_pad_s", "smooth_hz", "added_zero_hz",
                         "added_zero_zeta", "highpass_hz", "max_pre_impact_ratio", prefix="BuildSettings.")
        require_int("n_velocities", self.n_velocities, minimum=2, prefix="BuildSettings.")
        if self.smooth_hz > MAX_SMOOTH_HZ:
            raise ValueError(f"BuildSettings.smooth_hz={self.smooth_hz} exceeds {MAX_SMOOTH_HZ} Hz "
                             "(the bandwidth of human perception, section 4.4.1)")
        require_int("smooth_order", self.smooth_order, minimum=1, maximum=8, prefix="BuildSettings.")
        if self.highpass_phase not in ("causal", "zero", "best"):
            raise ValueError(f"BuildSettings.highpass_phase must be 'causal', 'zero' or 'best', got {self.highpass_phase!r}")
        require_int("window_iterations", self.window_iterations, minimum=0, maximum=50, prefix="BuildSettings.")
        if not (0 <= self.onset_delay_s <= 0.01):
            raise ValueError(f"BuildSettings.onset_delay_s must be in [0, 0.01] s, got {self.onset_delay_s!r}")
        if not (0 <= self.taper_s < self.duration_s):
            raise ValueError(f"BuildSettings.taper_s must be in [0, duration_s), got {self.taper_s!r}")
        require_number("gain", self.gain, minimum=0.0, strict=True, prefix="BuildSettings.")
        if not (-1 <= self.min_neighbour_corr <= 1):
            raise ValueError(f"BuildSettings.min_neighbour_corr must be in [-1, 1], got {self.min_neighbour_corr!r}")
        lo, hi = self.verify_band_hz
        if not 0 < lo < hi:
            raise ValueError(f"BuildSettings.verify_band_hz must be (lo, hi) with 0 < lo < hi, got {self.verify_band_hz!r}")
        require_number("peak_current_A", self.peak_current_A, minimum=0.0, strict=True, optional=True,
                       prefix="BuildSettings.")
        if self.max_extrapolation < 1:
            raise ValueError(f"BuildSettings.max_extrapolation must be >= 1, got {self.max_extrapolation!r}")
