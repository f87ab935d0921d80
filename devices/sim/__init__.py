"""Simulated haptic device: nonlinear joystick model (thesis sec. 3.5.4), its one-dof variant with a linear linkage
(sec. 4.4.3; ``sim:onedof``) or Phantom-like LTI (sec. 3.4.4).

See ``docs/sim.md`` and ``docs/architecture.md`` ("Sim device")::

    from devices.sim import SimDevice, TapTrajectory
    dev = SimDevice()                       # Table 3.1 defaults
    dev.set_sample("wood_on_foam")
    dev.set_user(TapTrajectory(0.1, n_taps=3), grip_N=2.0)
    dev.motor_enabled = False
    while not dev.trajectory_done:
        state = dev.read()
        dev.command(0.0)
"""

from .device import SimDevice
from .sim3 import Sim3Device, tap_frame
from .hand import HoldTrajectory, ReactiveHand, ScriptedTrajectory, TapTrajectory
from .person import DEFAULT_PERSON, PRESCRIBED, Person
from .params import SimParams, default_params, load_sim_params, params_from_dict
from .presets import CHAPTER_4_DEVICE, PRESETS, preset_params
from .samples import SAMPLES, SampleParams, get_sample

__all__ = ["SimDevice", "Sim3Device", "tap_frame", "SimParams", "TapTrajectory", "ScriptedTrajectory", "HoldTrajectory",
           "ReactiveHand", "Person", "DEFAULT_PERSON", "PRESCRIBED", "SAMPLES", "SampleParams", "get_sample",
           "load_sim_params", "default_params", "params_from_dict", "PRESETS", "preset_params", "CHAPTER_4_DEVICE"]
