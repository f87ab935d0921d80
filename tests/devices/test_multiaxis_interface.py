"""The multi-axis device interface (devices/base.py): the 1-DOF device is its one-axis case."""

import math

import pytest

from devices.base import Device, DeviceInfo, DeviceState
from devices.sim import SimDevice


class ThreeAxis(Device):
    """A minimal 3-axis driver: records what reaches its motors."""

    def __init__(self):
        super().__init__()
        self.info = DeviceInfo(name="three", encoder_lines=1000, gear_ratio=10.0, handle_length_m=0.1,
                               torque_constant_Nm_A=0.02, current_continuous_A=1.0, current_peak_A=2.0,
                               current_amplifier_A=3.0, servo_rate_hz=1000.0, axes=3,
                               workspace_min_m=(-0.05, -0.05, -0.05), workspace_max_m=(0.05, 0.05, 0.05),
                               max_force_N=3.0, max_peak_force_N=8.0, max_stiffness_N_m=2000.0, linear=False,
                               buttons=4)
        self.sent = []
        self.state = DeviceState()

    def _open(self):
        pass

    def _close(self):
        pass

    def read(self):
        return self.state

    def _send_force(self, fx, fy, fz):
        self.sent.append((fx, fy, fz))


def test_a_one_axis_device_renders_the_z_component_as_its_current():
    dev = SimDevice()
    kf = dev.info.force_per_amp_N_A
    dev.command_force(5.0, -7.0, 1.5)   # x and y cannot be pushed on one axis
    assert dev.last_command_A == pytest.approx(1.5 / kf, rel=1e-12)
    assert dev.last_force_N == (5.0, -7.0, 1.5)
    dev.command_force(0.0, float("nan"), 1.0)
    assert dev.last_command_A == 0.0 and dev.rejected_commands == 1


def test_one_axis_specs_are_derived_from_the_1dof_fields():
    info = SimDevice().info
    spec = info.specs()
    assert spec.axes == 1 and spec.linear
    assert spec.max_force_N == pytest.approx(info.current_continuous_A * info.force_per_amp_N_A)
    assert spec.max_peak_force_N == pytest.approx(info.current_peak_A * info.force_per_amp_N_A)
    # one encoder count commands the continuous force: 3.8e5 N/m on the default sim (docs/renderer.md)
    assert spec.max_stiffness_N_m == pytest.approx(3.77e5, rel=0.01)
    assert spec.workspace_min_m[:2] == (0.0, 0.0) and spec.contains((0.0, 0.0, 0.01))
    assert not spec.contains((0.001, 0.0, 0.0))


def test_three_axis_force_is_clamped_in_magnitude_with_its_direction_kept_and_zeroed_on_exit():
    dev = ThreeAxis()
    with dev:
        dev.command_force(30.0, 40.0, 0.0)          # 50 N -> the 8 N peak
        fx, fy, fz = dev.sent[-1]
        assert math.hypot(fx, fy, fz) == pytest.approx(8.0, rel=1e-12)
        assert fx / fy == pytest.approx(0.75, rel=1e-12) and fz == 0.0
        dev.command_force(1.0, math.inf, 0.0)
        assert dev.sent[-1] == (0.0, 0.0, 0.0) and dev.rejected_commands == 1
        dev.command_force(1.0, 2.0, 3.0)
        assert dev.sent[-1] == (1.0, 2.0, 3.0)
        with pytest.raises(Exception, match="takes forces"):
            dev.command(0.5)
    assert dev.sent[-1] == (0.0, 0.0, 0.0)            # zeroed on close
    assert dev.sent[0] == (0.0, 0.0, 0.0)             # and on open
    spec = dev.info.specs()
    assert (spec.axes, spec.linear, spec.buttons, spec.max_stiffness_N_m) == (3, False, 4, 2000.0)


def test_device_info_rejects_bad_multiaxis_fields():
    base = dict(name="x", encoder_lines=1000, gear_ratio=1.0, handle_length_m=0.1, torque_constant_Nm_A=0.1,
                current_continuous_A=1.0, current_peak_A=1.0, current_amplifier_A=1.0, servo_rate_hz=1000.0)
    with pytest.raises(ValueError, match="axes"):
        DeviceInfo(**base, axes=2)
    with pytest.raises(ValueError, match="workspace"):
        DeviceInfo(**base, axes=3, workspace_min_m=(0, 0, 0), workspace_max_m=(-1, 0, 0))
    with pytest.raises(ValueError, match="max_force_N"):
        DeviceInfo(**base, max_force_N=-1.0)


def test_state_carries_position_and_velocity_three_vectors_and_buttons():
    st = DeviceState(position_m=0.01, x_m=0.02, y_m=-0.03, vx_m_s=0.1, buttons=0b101)
    assert st.position3() == (0.02, -0.03, 0.01) and st.z_m == 0.01
    assert st.velocity3()[0] == 0.1 and math.isnan(st.velocity3()[1])
    cp = st.copy()
    st.buttons = 0
    assert cp.buttons == 0b101 and cp.x_m == 0.02
