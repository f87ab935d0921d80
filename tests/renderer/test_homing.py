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
    # a firm, deep push through the homing force: the prescribed (velocity-source) hand; the default simulated
    # person (issue 16) is compliant enough that homing holds it back
    dev.set_user(traj, grip_N=8.0, hand="prescribed")
    res = HomingController(dev, HomingConfig(home_height_m=0.01)).run(1.5)
    assert res.contacts == 1
    dev.set_user(TapTrajectory([0.15], 1, approach_height_m=0.01, press_depth_m=0.005), grip_N=1.0,
                 hand="prescribed")
    assert HomingController(dev, HomingConfig(home_height_m=0.01)).run(1.5).contacts == 0  # held back


class _Faulty:
    """A device whose readings turn implausible (NaN position) or disconnected after ``after`` reads."""

    def __init__(self, dev, after, kind):
        self.dev, self.info, self.after, self.kind, self.n, self.currents = dev, dev.info, after, kind, 0, []

    def read(self):
        s = self.dev.read()
        self.n += 1
        if self.n > self.after:
            if self.kind == "nan":
                s.position_m = float("nan")
            else:
                s.status |= 32
        return s

    def command(self, i):
        self.currents.append(i)
        self.dev.command(i)


def test_homing_runs_through_the_safety_path():
    """renderer.safety: NaN samples are held then stop homing, a disconnect stops it, heat is tracked."""
    from renderer.safety import safety_bounds

    for kind, reason in (("nan", "sensor"), ("disconnect", "disconnected")):
        dev = SimDevice(seed=1).open()
        dev.set_user(0.03, grip_N=2.0)
        spy = _Faulty(dev, 500, kind)
        ctl = HomingController(spy, HomingConfig(home_height_m=0.01))
        res = ctl.run(2.0)
        assert res.stop_reason == reason and spy.currents[-1] == 0.0
        assert all(i == i for i in spy.currents)  # no NaN ever commanded
        limit = safety_bounds(dev.info, dev.info.servo_rate_hz).max_bad_samples
        assert res.ticks == (500 + limit if kind == "nan" else 501), res
        assert res.bad_samples == (limit if kind == "nan" else 0)
    # the winding heats while homing pushes, from the temperature it was handed
    dev = SimDevice(seed=1).open()
    dev.set_user(0.03, grip_N=8.0)  # a firm hand 20 mm above home: homing pushes against it
    ctl = HomingController(dev, HomingConfig(home_height_m=0.01))
    ctl.temp_rise_K = 5.0
    res = ctl.run(1.0)
    assert res.temp_rise_K == ctl.temp_rise_K and res.temp_rise_K != 5.0
    assert ctl.max_current_A <= dev.info.current_continuous_A
