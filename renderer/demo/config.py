"""The sim demo's settings (:class:`DemoConfig`) and results (:class:`DemoResult`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from plumbing.validation import require_int, require_number
from stimuli.hfam.settings import PipelineSettings

from .renderings import RENDERINGS

if TYPE_CHECKING:  # annotations only: the cached pipeline loads the identification (scipy.signal)
    from .cache import Pipeline


@dataclass(frozen=True)
class DemoConfig:
    """What the sim demo taps.

    Attributes
    ----------
    velocities_m_s : tuple of float
        Tap speeds of the simulated user (m/s): 0.05-0.15 m/s cover section 4.5.4's operating point (the
        fidelity claims, :mod:`renderer.demo.fidelity`), 0.2-0.3 m/s the library's upper range.
    grips_N : tuple of float
        Grips of the simulated user (N): light, medium, firm.
    taps : int
        Taps per rendering x velocity x grip (the sim is deterministic up
        to sensor noise, so 1 is enough; metrics are averaged over taps).
    medium_grip_N : float
        Grip whose transient the no-grip-compensation rendering always plays.
    figure_velocity_m_s : float
        Velocity of the contact figure (thesis: 0.11 m/s).
    grid_velocities_m_s : tuple of float
        Three velocities of the Figure 4.13 grid.
    pipeline : PipelineSettings
    renderings : tuple of Rendering
    """

    velocities_m_s: tuple = (0.05, 0.08, 0.11, 0.15, 0.2, 0.3)
    grips_N: tuple = (1.0, 2.0, 3.0)
    taps: int = 1
    medium_grip_N: float = 2.0
    figure_velocity_m_s: float = 0.11
    grid_velocities_m_s: tuple = (0.05, 0.08, 0.11)
    pipeline: PipelineSettings = field(default_factory=PipelineSettings)
    renderings: tuple = RENDERINGS

    def __post_init__(self) -> None:
        for key in ("velocities_m_s", "grips_N"):
            vals = getattr(self, key)
            if not vals:
                raise ValueError(f"demo {key} must be positive numbers, got {vals!r}")
            for k, x in enumerate(vals):
                require_number(f"{key}[{k}]", x, minimum=0.0, strict=True, prefix="demo ")
        require_int("taps", self.taps, minimum=1, prefix="demo ")
        if self.figure_velocity_m_s not in self.velocities_m_s:
            raise ValueError(f"figure velocity {self.figure_velocity_m_s} must be one of the demo velocities")
        if any(v not in self.velocities_m_s for v in self.grid_velocities_m_s):
            raise ValueError(f"grid velocities {self.grid_velocities_m_s} must be demo velocities")


@dataclass
class DemoResult:
    """Everything the sim demo computed.

    Attributes
    ----------
    rows : list of dict
        ``summary.csv`` rows (``SUMMARY_COLUMNS``) plus ``in_library_range``.
    traces : dict (rendering, velocity, grip) -> list of TapTrace
    references : dict velocity -> real-sample window at the recording grip
    pipeline : Pipeline
    figures : dict name -> Path
    timings_s : dict
    reactive : dict
        :func:`reactive_hand_cuts` (empty if not applicable).
    claims : list of Claim
        The thesis claims measured on the taps (:func:`renderer.demo.fidelity.measure_claims`; ``fidelity.csv``).
    """

    rows: list
    traces: dict
    references: dict
    pipeline: Pipeline
    figures: dict
    timings_s: dict
    fs_hz: float = 10_000.0
    reactive: dict = field(default_factory=dict)
    claims: list = field(default_factory=list)

    def row(self, rendering: str, velocity_m_s: float, grip_N: float) -> dict:
        """The summary row of one rendering at one velocity (m/s) and grip (N); KeyError if there is none."""
        for r in self.rows:
            if r["rendering"] == rendering and r["velocity_m_s"] == velocity_m_s and r["grip_N"] == grip_N:
                return r
        raise KeyError((rendering, velocity_m_s, grip_N))
