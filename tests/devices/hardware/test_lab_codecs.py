"""The 3-DOF devices' codecs and kinematics: vectors from the cited sources, round trips, resynchronisation,
and a cross-check with pyftdi's own baud-rate arithmetic."""

import math
import random

import pytest
from pyftdi.ftdi import Ftdi

from devices.firmware.falcon_emulator import FalconModel, VirtualFalconBackend, falcon_usb_device, stand_in_firmware
from devices.hardware.falcon import kinematics as K
from devices.hardware.falcon import protocol as FP
from devices.hardware.haply import protocol as H
from devices.hardware.woodenhaptics import protocol as W


def test_inverse3_requests_are_the_command_byte_and_little_endian_floats():
    # Inverse3.h: HC_END_EFFECTOR_FORCE = 0x2A with EndEffectorForceRequest {float force[3]}
    assert H.encode_force(1.0, 2.0, 3.0) == bytes.fromhex("2a" "0000803f" "00000040" "00004040")
    assert H.encode_wakeup() == b"\x0a"
    with pytest.raises(H.ProtocolError):
        H.encode_force(math.nan, 0.0, 0.0)   # NaN never reaches the wire


def test_inverse3_reply_parser_skips_garbage_and_waits_for_whole_replies():
    p = H.ReplyParser()
    state = H.encode_state((0.1, 0.2, 0.3), (1.0, 2.0, 3.0))
    wake = H.encode_wakeup_reply(H.WakeupInfo(7, 1, 2, 3, __import__("uuid").UUID(int=5)))
    stream = b"\x00\x11" + state[:10]
    assert p.feed(stream) == [] and p.garbage_bytes == 2
    got = p.feed(state[10:] + b"\x7f" + wake)
    assert [h for h, _ in got] == [H.EE_STATE, H.WAKEUP_REPLY] and p.garbage_bytes == 3
    pos, vel = H.decode_state(got[0][1])
    assert pos == pytest.approx((0.1, 0.2, 0.3)) and vel == pytest.approx((1, 2, 3))
    assert H.decode_wakeup_reply(got[1][1]).device_id == 7


def test_falcon_packet_parser_resynchronises_on_garbage():
    pkts = [FP.encode_status((k, -k, 2 * k), 7, k % 16) for k in range(1, 6)]
    stream = pkts[0] + b"\x13\x3c" + pkts[1] + pkts[2][:7]
    p = FP.PacketParser()
    out = p.feed(stream)
    assert out == pkts[:2] and p.garbage_bytes == 2
    assert p.feed(pkts[2][7:] + pkts[3]) == pkts[2:4]


def test_falcon_nibbles_carry_int16_twos_complement():
    for v in (0, 1, -1, 4096, -4096, 32767, -32768):
        assert FP.decode_command(FP.encode_command((v, 0, 0)))[0][0] == v
    with pytest.raises(ValueError):
        FP.encode_command((40000, 0, 0))


@pytest.mark.parametrize("baud", [9600, 142857, 1_500_000, 115200, 1_000_000])
def test_falcon_emulator_baud_arithmetic_agrees_with_pyftdi(baud):
    """The emulated FT232R's divisor decoding (AN232B-05) against pyftdi's encoder for the same chip."""
    model = FalconModel(stand_in_firmware(), plan=None)
    be = VirtualFalconBackend(model)
    try:
        ftdi = Ftdi()
        ftdi.open_from_device(falcon_usb_device(be))   # enumerates as an FT232R (bcdDevice 0x0600)
        actual = ftdi.set_baudrate(baud)
        request, value, index = be.control_log[-1]
        assert request == 3   # SIO_SET_BAUDRATE
        assert FP.ftdi_baud_from_divisor(value, index) == pytest.approx(actual, rel=2e-3)
        assert FP.baud_matches(FP.ftdi_baud_from_divisor(value, index), baud)
    finally:
        be.stop()


def test_falcon_kinematics_round_trip_and_force_mapping():
    rng = random.Random(3)
    for _ in range(100):
        p = (rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), rng.uniform(0.08, 0.14))
        theta = K.ik(p)[0]
        assert K.fk(theta) == pytest.approx(p, abs=1e-9)
        f = (rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-3, 3))
        # what the motors exert for libnifalcon's commands is the force asked, within the int truncation
        assert K.force_from_commands(p, K.motor_commands(p, f)) == pytest.approx(f, abs=0.02)


def test_woodenhaptics_reports_as_the_firmware_structs_lay_them_out():
    # the firmware's input report: three int16 encoder counts and a uint16 counter, little-endian (LPC1768)
    assert W.encode_report((1, -2, 300), 5) == bytes.fromhex("0100" "feff" "2c01" "0500")
    assert W.decode_report(bytes.fromhex("ffff" "0080" "ff7f" "ffff")) == ((-1, -32768, 32767), 65535)
    # counter[] is an int: a count beyond a short wraps as the firmware's assignment does
    assert W.decode_report(W.encode_report((40000, 0, 0), 1))[0][0] == 40000 - 65536
    # its output report: three int16 motor commands (the firmware's mA) and a uint16 field
    assert W.encode_command((3000, -1500, 0), 9) == bytes.fromhex("b80b" "24fa" "0000" "0900")
    with pytest.raises(W.ProtocolError):
        W.decode_report(b"\x00" * 7)


def test_woodenhaptics_firmware_current_saturates_at_its_full_scale():
    # the firmware: a command n is n/1000 A; its PWM saturates (0.9) above 3 A, else 0.1 + 0.8 |i| / 3
    assert W.firmware_current_A(1500) == pytest.approx(1.5)
    assert W.firmware_current_A(9000) == W.FIRMWARE_FULL_SCALE_A == 3.0
    assert W.firmware_current_A(-9000) == -3.0
    # CWoodenDevice: the current clamped to +/-3 A, times 3000, truncated to an int16
    assert W.wire_ma((0.5, -5.0, 0.0)) == (1500, -9000, 0)


def test_woodenhaptics_kinematics_round_trip_and_statics():
    rng = random.Random(4)
    for _ in range(50):
        p = (rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05))
        q = W.inverse(p)
        assert W.forward(q) == pytest.approx(p, abs=1e-9)
        enc = W.encoders_from_angles(q)
        assert W.forward(W.joint_angles(enc)) == pytest.approx(p, abs=1e-4)   # a count is ~20 um
    # with gravity compensation off, an upward force needs current only on the motors that lift
    q = W.inverse((0.0, 0.0, 0.0))
    a = W.motor_currents(q, (0.0, 0.0, 1.0), gravity=False)
    assert a[0] == pytest.approx(0.0, abs=1e-12) and abs(a[1]) > 0.05
    # the gravity compensation alone holds the linkage: non-zero, and the same sign as lifting it
    g = W.motor_currents(q, (0.0, 0.0, 0.0))
    assert g[1] * a[1] > 0


def test_falcon_fk_newton_uses_the_exact_derivative_of_ik():
    """fk's Jacobian is the inverse of ik's finite-difference derivative (so Newton converges quadratically);
    libnifalcon's own jacobian(), which getForces uses and ours reproduces, is not, in its z column."""
    rng = random.Random(11)
    h = 1e-7
    for _ in range(20):
        p = (rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), rng.uniform(0.08, 0.14))
        angles = K.ik(p)
        num = [[0.0] * 3 for _ in range(3)]
        for c in range(3):
            q = list(p)
            q[c] += h
            t = K.ik(q)[0]
            for r in range(3):
                num[r][c] = (t[r] - angles[0][r]) / h
        for jac, close in ((K._leg_jacobian(angles), True), (K.jacobian(angles), False)):
            prod = [[sum(jac[r][k] * num[k][c] for k in range(3)) for c in range(3)] for r in range(3)]
            err = max(abs(prod[r][c] - (r == c)) for r in range(3) for c in range(3))
            assert (err < 1e-4) == close, (p, err)
