"""Homing controller (renderer.homing) on the real sim device."""

from devices.sim import SimDevice, TapTrajectory
from renderer.homing import HomingConfig, HomingController


class CurrentSpy:
    """Wraps a device to record every commanded current (the homing talks to the Device API only)."""

    def __init__(self, dev):
        self.dev, self.info, self.currents = dev, dev.info, []

    def read(self):
        return self.dev.read()

    def command(self, i):
        self.currents.append(i)
        self.dev.command(i)


def test_homing_reaches_home_within_the_continuous_limit():
    dev = SimDevice(seed=1).open()
    dev.set_sample("placeholder")
    dev.set_user(0.03, grip_N=2.0)      # the hand rests 30 mm up, 20 mm above home
    dev.set_user(None, grip_N=0.5)      # a light grip follows the handle (hold where it is)
    spy = CurrentSpy(dev)
    ctl = HomingController(spy, HomingConfig(home_height_m=0.01))
    res = ctl.run(3.0, until_settled=True, min_duration_s=0.2)
    assert res.settled and abs(res.final_position_m - 0.01) < 0.002
    assert res.contacts == 0
    assert max(abs(i) for i in spy.currents) <= dev.info.current_continuous_A + 1e-12
    assert spy.currents[-1] == 0.0                # output zeroed at the end
    assert abs(dev.read().position_m - 0.01) < 0.002


def test_homing_counts_a_tap_that_overpowers_it():
    dev = SimDevice(seed=1).open()
    dev.set_sample("wood")
    traj = TapTrajectory([0.15], 1, approach_height_m=0.01, press_depth_m=0.03)
    dev.set_user(traj, grip_N=8.0)                # a firm, deep push through the homing force
    res = HomingController(dev, HomingConfig(home_height_m=0.01)).run(1.5)
    assert res.contacts == 1
    dev.set_user(TapTrajectory([0.15], 1, approach_height_m=0.01, press_depth_m=0.005), grip_N=1.0)
    assert HomingController(dev, HomingConfig(home_height_m=0.01)).run(1.5).contacts == 0  # held back
