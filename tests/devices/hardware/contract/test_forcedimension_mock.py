"""Contract: the Force Dimension adapter against forcedimension-core in the package's own mock mode.

``__fdsdkpy_unittest__=True`` makes forcedimension-core's library handle a ``unittest.mock.Mock`` (its test
mode): every ``dhd`` function still runs its Python side and calls the ``dhd*`` symbol it binds, which the
Mock records. :class:`devices.firmware.dhd_emulator.DhdEmulator` answers those calls as a device would; this
test checks the order and arguments of the SDK calls the adapter makes (open, arm the watchdog, enable
forces before the first force; per tick force then state; zero force, disable, close last)."""

import unittest.mock

import pytest

from devices.firmware.dhd_emulator import DhdEmulator
from devices.hardware.forcedimension.driver import WATCHDOG_UNITS, ForceDimensionDevice


@pytest.fixture
def emu():
    e = DhdEmulator(plan=None)
    yield e
    e.stop()


def test_the_bindings_run_in_their_own_mock_mode(emu):
    import forcedimension_core.runtime as runtime
    assert isinstance(runtime._libdhd, unittest.mock.Mock) and emu.lib is runtime._libdhd
    assert emu.dhd.getSDKVersion is not None


def test_sdk_calls_come_in_the_order_a_device_needs(emu):
    dev = ForceDimensionDevice(0, bindings=(emu.dhd, emu.expert))
    with dev:
        for k in range(5):
            dev.read()
            dev.command_force(0.1 * k, -0.2, 0.3)
    names = emu.calls()
    first_force = names.index("dhdSetForce")
    assert names[:first_force] == ["dhdGetDeviceCount", "dhdOpenID", "dhdGetSystemName", "dhdEnableExpertMode",
                                   "dhdSetWatchdog", "dhdEnableForce"]
    tick = ["dhdSetForce", "dhdGetPosition", "dhdGetLinearVelocity", "dhdGetButtonMask"]
    body = names[first_force:-3]
    assert body == tick * (len(body) // 4) and len(body) >= 4 * 6   # open's zero, the first read, 5 commands
    assert names[-3:] == ["dhdSetForce", "dhdEnableForce", "dhdClose"]
    lib = emu.lib
    assert lib.dhdOpenID.call_args_list == [unittest.mock.call(0)]
    assert lib.dhdSetWatchdog.call_args_list == [unittest.mock.call(WATCHDOG_UNITS, 0)]
    assert WATCHDOG_UNITS * 125e-6 == pytest.approx(0.020)                 # the contract's 20 ms
    assert lib.dhdEnableForce.call_args_list == [unittest.mock.call(True, 0), unittest.mock.call(False, 0)]
    forces = [c.args[:3] for c in lib.dhdSetForce.call_args_list]
    assert forces[-1] == (0.0, 0.0, 0.0)                                    # zero before close
    assert (0.4, -0.2, 0.3) in [tuple(round(v, 12) for v in f) for f in forces]
    assert all(c.args[3] == 0 for c in lib.dhdSetForce.call_args_list)     # always this device's ID


def test_the_state_comes_back_in_the_device_frame(emu):
    dev = ForceDimensionDevice(0, bindings=(emu.dhd, emu.expert))
    with dev:
        emu.endpoint.pos[:] = [0.01, -0.02, 0.03]
        emu.endpoint.vel[:] = [0.1, 0.2, 0.3]
        dev.command_force(0.0, 0.0, 0.0)
        st = dev.read()
        p, v = emu.endpoint.pos, emu.endpoint.vel   # after the tick the force call advanced
        assert (st.x_m, st.y_m, st.position_m) == pytest.approx(tuple(p))
        assert (st.vx_m_s, st.vy_m_s, st.vz_m_s) == pytest.approx(tuple(v))


def test_a_saturated_motor_is_reported_as_clipping(emu):
    dev = ForceDimensionDevice(0, bindings=(emu.dhd, emu.expert))
    with dev:
        dev.command_force(0.0, 0.0, 11.5)      # within the device's 12 N: no clipping
        assert not dev.read().status & 8
        emu.lib.dhdSetForce.side_effect = lambda *a: 2   # the SDK answers MOTOR_SATURATED
        dev.command_force(0.0, 0.0, 1.0)
        assert dev.read().status & 8 and dev.stats["clipped"] == 1
