"""Mechanical test configurations of the simulated joystick for successive isolation (thesis sec. 3.5.1).

Successive isolation breaks the dynamic chain motor - cables - drum - linkage -
handle - user at points progressively farther from the motor (Figure 3.13):
cables disconnected (the motor alone), drum locked (motor on the cables), linkage
disconnected (motor, cables and drum), handle locked (the linkage deflects between
drum and ground), and the handle free or held. :meth:`SimDevice.set_mechanical_config`
applies a :class:`MechanicalConfig` by substituting parameters of the kernel's
parameter array (a disconnected element exerts no force, a locked mass is given
an inertia so large it does not move), so the physics kernel itself is unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

# an inertia this large (kg) does not move measurably under the device's forces (< 1e-11 m/s^2 at 10 N)
LOCKED_MASS_KG = 1e12


@dataclass(frozen=True)
class MechanicalConfig:
    """One mechanical configuration of the device (which couplings are on, which masses are locked).

    Attributes
    ----------
    cables : bool
        Cables connect motor and drum (False: the motor spins alone, sec. 3.5.2 "Motor and Encoder").
    linkage : bool
        The linkage connects drum and handle (False: the drum spins without the handle, "Drum").
    motor_locked, drum_locked, handle_locked : bool
        That mass is clamped to ground where it is ("Current Amplifier": motor locked;
        "Cables": drum locked; "Linkage": handle locked).
    name : str
        Label for prompts and reports.
    """

    cables: bool = True
    linkage: bool = True
    motor_locked: bool = False
    drum_locked: bool = False
    handle_locked: bool = False
    name: str = "assembled"

    def describe(self) -> str:
        """One line for an operator: what to connect, disconnect and lock."""
        parts = ["cables " + ("connected" if self.cables else "DISCONNECTED"),
                 "linkage " + ("connected" if self.linkage else "DISCONNECTED")]
        for what, on in (("motor", self.motor_locked), ("drum", self.drum_locked), ("handle", self.handle_locked)):
            if on:
                parts.append(f"{what} LOCKED")
        return f"{self.name}: " + ", ".join(parts)


ASSEMBLED = MechanicalConfig()
CONFIGS = {
    "motor_locked": MechanicalConfig(cables=False, linkage=False, motor_locked=True, name="motor locked"),
    "motor_only": MechanicalConfig(cables=False, linkage=False, name="cables disconnected"),
    "drum_locked": MechanicalConfig(cables=True, linkage=False, drum_locked=True, name="drum locked"),
    "linkage_off": MechanicalConfig(cables=True, linkage=False, name="linkage disconnected"),
    "handle_locked": MechanicalConfig(cables=True, linkage=True, handle_locked=True, name="handle locked"),
    "assembled": ASSEMBLED,
}


def get_config(name_or_config) -> MechanicalConfig:
    """A :class:`MechanicalConfig` from itself or its key in ``CONFIGS``; ValueError naming the valid keys."""
    if isinstance(name_or_config, MechanicalConfig):
        return name_or_config
    try:
        return CONFIGS[name_or_config]
    except (KeyError, TypeError):
        raise ValueError(f"unknown mechanical configuration {name_or_config!r} (valid: {', '.join(CONFIGS)})") \
            from None
