"""The device under test and its mechanical configurations: set directly on the sim, by the operator (prompts
and checks) on hardware (thesis sec. 3.5.1: the chain is broken mechanically at each stage)."""

from __future__ import annotations

import numpy as np

from ...base import Device
from ...sim.mechconfig import get_config
from ..record import hold_user
from .common import StageError
from .experiment import Experiment, Trace, run_on_device, run_on_sim_device


class Bench:
    """Runs experiments on a device in the configuration a stage needs.

    Parameters
    ----------
    dev : Device
        Open device. A simulated device with ``set_mechanical_config`` is configured directly; on any
        other device the operator is asked (``prompt``) to change the mechanics and the change is checked.
    prompt : callable or None
        ``prompt(text) -> str`` (default ``input``) for operator instructions on hardware.
    log : callable
    config_override : dict or None
        Tests only: ``{requested: actual}`` configuration, to play an operator's mistake on the sim.
    hand : object or None
        Simulated device: the person holding it (``set_user``'s ``hand``; None: the sim's default).
    """

    def __init__(self, dev: Device, prompt=None, log=print, config_override: dict | None = None, hand=None):
        self.dev = dev
        self.prompt = prompt or input
        self.log = log
        self.override = dict(config_override or {})
        self.hand = hand
        self.simulated = bool(getattr(dev, "simulated", False)) and hasattr(dev, "set_mechanical_config")
        self.config = None
        self.ticks = 0
        self.saturation_A = float(dev.info.current_amplifier_A)  # the amplifier stage measures it

    @property
    def info(self):
        """The device's :class:`DeviceInfo`."""
        return self.dev.info

    def configure(self, key: str) -> None:
        """Put the device into mechanical configuration ``key`` (sim: directly; hardware: prompt + check)."""
        cfg = get_config(key)
        if self.simulated:
            self.dev.set_mechanical_config(get_config(self.override.get(key, key)))
        elif self.config != key:
            self.dev.command(0.0)
            answer = self.prompt(f"\n>>> Set the device to: {cfg.describe()}.\n    Press Enter when done "
                                 f"(or type 'skip' to abort this stage): ")
            if str(answer).strip().lower() == "skip":
                raise StageError(f"operator skipped configuration {cfg.name!r}")
            self._check_motion(cfg)
        self.config = key

    def _check_motion(self, cfg) -> None:
        """Hardware: a small current pulse must move the motor (free chain) or not (motor locked)."""
        n = int(0.05 * self.info.servo_rate_hz)
        ff = np.zeros(3 * n)
        ff[:n] = 0.1
        ff[n:2 * n] = -0.1
        tr = run_on_device(self.dev, Experiment("config check", ff))
        moved = float(np.ptp(tr.x_m)) > 3 * self.info.position_resolution_m
        if cfg.motor_locked and moved:
            raise StageError(f"configuration {cfg.name!r}: the motor moved {np.ptp(tr.x_m) * 1e3:.3f} mm under "
                             "a 0.1 A pulse; it should be locked")
        if not cfg.motor_locked and not moved:
            raise StageError(f"configuration {cfg.name!r}: the motor did not move under a 0.1 A pulse; is it "
                             "still locked?")

    def run(self, exp: Experiment, measure_current: bool = False, allow_saturation: bool = False) -> Trace:
        """Play ``exp`` with the user holding at ``exp.grip_N`` (0: hands off) and return the trace.

        Raises
        ------
        StageError
            If the test would saturate the amplifier (open loop: the feedforward's peak is at or above the
            amplifier limit; closed loop: the command reached it), unless ``allow_saturation`` (the
            amplifier stage's own saturation test): a saturated test does not show the mechanics.
        """
        dev = self.dev
        limit = self.saturation_A
        peak = float(np.max(np.abs(exp.ff_A))) if exp.n else 0.0
        if not allow_saturation and peak >= limit:
            raise StageError(f"test {exp.name!r} saturates the amplifier: its current peaks at {peak:.3g} A, the "
                             f"amplifier limit is {limit:.3g} A; use a smaller amplitude")
        if self.simulated:
            if self.hand is None:
                dev.set_user(None, grip_N=exp.grip_N)
            else:
                dev.set_user(None, grip_N=exp.grip_N, hand=self.hand)
        elif exp.grip_N > 0:
            hold_user(dev, exp.grip_N, log=self.log)
        meas = None
        if measure_current:
            if self.simulated:
                meas = lambda: dev.true_state()["amplifier_current_A"]  # noqa: E731  the sim's sense resistor
            else:
                meas = None
        self.ticks += exp.n
        tr = run_on_sim_device(dev, exp, measure_current) if self.simulated else None
        if tr is None:
            tr = run_on_device(dev, exp, meas)
        if not allow_saturation and exp.ref_m is not None and float(np.max(np.abs(tr.i_A))) >= limit:
            raise StageError(f"test {exp.name!r} saturated the amplifier (the controller asked for "
                             f"{float(np.max(np.abs(tr.i_A))):.3g} A, limit {limit:.3g} A); the result is not used")
        return tr
