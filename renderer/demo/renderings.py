"""The demo's renderings (:class:`Rendering`, :data:`RENDERINGS`): what the user taps, in table order.

A module of its own, light (no numpy): the demo's parser lists their names in ``--help``.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Rendering:
    """One surface the user taps.

    Attributes
    ----------
    name : str
        Row name in the table and ``summary.csv``.
    label : str
        Human-readable description.
    stiffness_N_m : float
        Proportional wall stiffness (0 for the real sample).
    transient : str
        ``none``, ``pulse``, ``sinusoid``, ``hfam`` or ``hfam_fixed_grip`` (the
        library's transient for ``fixed_grip_N`` whatever the grip: no grip
        compensation, the Figure 4.13 discussion).
    sample : str
        Sim sample under the stylus (``placeholder`` for virtual walls).
    """

    name: str
    label: str
    stiffness_N_m: float
    transient: str = "none"
    sample: str = "placeholder"

    @property
    def is_real(self) -> bool:
        """True for a real sample under the stylus (motor off), not a virtual rendering."""
        return self.sample != "placeholder"


REAL = Rendering("real_wood_on_foam", "real wood on foam (motor off)", 0.0, "none", "wood_on_foam")
REAL_WOOD = Rendering("real_wood", "real wood (motor off)", 0.0, "none", "wood")
REAL_FOAM = Rendering("real_foam", "real foam (motor off)", 0.0, "none", "foam")

#: the six event-based renderings of Figure 4.19 (each transient over the firm and over the soft wall), in the
#: order of section 4.5.5's comparison with their underlying proportional walls
EVENT_BASED = ("pulse_firm", "pulse_soft", "sinusoid_firm", "sinusoid_soft", "hfam_firm", "hfam_soft")

#: the twelve samples of Figure 4.19 (nine virtual, three real; Table 4.1) plus the no-grip-compensation
#: HFAM of the Figure 4.13 discussion, in table order
RENDERINGS: tuple[Rendering, ...] = (
    Rendering("soft", "soft proportional wall, 340 N/m", 340.0),
    Rendering("firm", "firm proportional wall, 680 N/m", 680.0),
    Rendering("very_firm", "very firm proportional wall, 1020 N/m", 1020.0),
    Rendering("pulse_firm", "pulse (4.55 N s/m, 20 ms) over firm", 680.0, "pulse"),
    Rendering("pulse_soft", "pulse (4.55 N s/m, 20 ms) over soft", 340.0, "pulse"),
    Rendering("sinusoid_firm", "decaying sinusoid (15.9 N s/m, 55 Hz, 55 ms) over firm", 680.0, "sinusoid"),
    Rendering("sinusoid_soft", "decaying sinusoid (15.9 N s/m, 55 Hz, 55 ms) over soft", 340.0, "sinusoid"),
    Rendering("hfam_firm", "HFAM over firm", 680.0, "hfam"),
    Rendering("hfam_soft", "HFAM over soft", 340.0, "hfam"),
    Rendering("hfam_fixed_grip_firm", "HFAM over firm, medium-grip transient at every grip (no grip compensation)",
              680.0, "hfam_fixed_grip"),
    REAL_WOOD,
    REAL,
    REAL_FOAM,
)

