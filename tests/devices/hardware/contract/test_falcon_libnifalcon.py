"""Contract: what libnifalcon computes agrees with our Falcon codec, kinematics and emulated loader.

libnifalcon (BSD; the open driver of the Novint Falcon) is not in this repository. Its answers on seeded
random inputs are recorded in ``vectors/falcon_libnifalcon.json`` (``vectors/README.md``: the libnifalcon
commit, how the file was made, the licence of the code that computed it; ``falcon_vectors.py`` regenerates
it from a harness linked with libnifalcon). This test checks ours against them with libnifalcon's precision
as the tolerance: inverse kinematics, Jacobian, force-to-motor conversion, encoder angle, forward kinematics,
the packets its firmware class writes and how it reads the device's; and it replays its firmware loader's
byte exchange against our emulated Falcon: the blocks libnifalcon writes, sent through our driver, come back
as the echoes libnifalcon accepted, and an echo it rejects stops our upload at the same block. What
libnifalcon's libusb code does on the FTDI (FalconCommLibUSB.cpp, which needs libusb) is checked as values
cited from it against the control requests our driver makes on the emulated FT232R.
"""

import json
from pathlib import Path

import pytest

from devices.firmware.falcon_emulator import FalconModel, VirtualFalconBackend, falcon_usb_device
from devices.hardware.falcon import kinematics as K
from devices.hardware.falcon import protocol as P
from devices.hardware.falcon.link import FalconError, FalconLink

VECTORS = Path(__file__).resolve().parent / "vectors" / "falcon_libnifalcon.json"
#: FalconFirmware.h: FALCON_FIRMWARE_NO_COMM_SET = 3000, then ... FALCON_FIRMWARE_CHECKSUM_MISMATCH (the 5th)
CHECKSUM_MISMATCH = 3004


@pytest.fixture(scope="module")
def lib():
    """libnifalcon's recorded answers (see module doc)."""
    data = json.loads(VECTORS.read_text())
    assert len(data["source"]["commit"]) == 40 and data["source"]["licence"] == "BSD-3-Clause"
    return data


def test_inverse_kinematics_and_jacobian_agree(lib):
    assert len(lib["ik"]) == 200
    for v in lib["ik"]:
        p = tuple(v["p"])
        ours = [x for group in K.ik(p) for x in group]
        assert ours == pytest.approx(v["theta"], abs=2e-6)   # libnifalcon keeps the angles as float32
        jo = [x for row in K.jacobian(K.ik(p)) for x in row]
        assert jo == pytest.approx(v["jacobian"], rel=1e-4, abs=1e-6)


def test_force_to_motor_commands_agree(lib):
    diffs = []
    assert len(lib["forces"]) == 350
    # the last 50 ask kN: libnifalcon scales the torques down together so the largest is its cap (30 N m),
    # x10000, truncated (so one count under, at times)
    cap = int(K.MAX_TORQUE * K.TORQUE_TO_COMMAND)
    assert all(cap - 1 <= max(abs(c) for c in v["commands"]) <= cap for v in lib["forces"][300:])
    for v in lib["forces"]:
        theirs = v["commands"]
        ours = K.motor_commands(tuple(v["p"]), tuple(v["force"]))
        diffs += [abs(a - b) for a, b in zip(ours, theirs)]
        assert max(abs(a - b) for a, b in zip(ours, theirs)) <= 2  # float32 angles: a count either side
        assert max(abs(x) for x in theirs) > 0
    assert sum(d == 0 for d in diffs) > 0.8 * len(diffs)


def test_encoder_angles_and_forward_kinematics_agree(lib):
    assert len(lib["theta"]) == 100 and len(lib["fk"]) == 60
    for v in lib["theta"]:
        assert K.theta_from_encoder(v["count"]) == pytest.approx(v["degrees"], abs=1e-9)
    # libnifalcon's FK stops at 0.01 rad of leg-angle error; ours converges fully: both must land within the
    # motion that error allows (< 0.5 mm here), and ours must reproduce the encoders exactly
    for v in lib["fk"]:
        p, enc = tuple(v["p"]), v["encoders"]
        assert [K.encoder_from_theta(t) for t in K.ik(p)[0]] == enc   # the same input libnifalcon was given
        ours = K.fk([K.theta_from_encoder(e) * K.DEG_TO_RAD for e in enc])
        assert [K.encoder_from_theta(t) for t in K.ik(ours)[0]] == enc
        theirs = v["answers"][-1]   # libnifalcon starts from its last answer: the third call has settled
        assert ours == pytest.approx(theirs, abs=5e-4)
        assert ours == pytest.approx(p, abs=2e-4)  # one encoder count is ~0.06 mm at the arm


def test_packets_agree_both_ways(lib):
    assert len(lib["pack"]) == len(lib["unpack"]) == 300
    for v in lib["pack"]:
        assert P.encode_command(v["commands"], v["leds"], v["homing"]).hex() == v["packet"]
        assert P.decode_command(bytes.fromhex(v["packet"])) == (tuple(v["commands"]), v["leds"], v["homing"])
    for v in lib["unpack"]:
        packet = bytes.fromhex(v["packet"])
        assert v["ok"]
        # libnifalcon's reading of the packet is our decoding, and our encoder writes the same packet
        enc, homed, buttons = P.decode_status(packet)
        assert list(enc) == v["encoders"] and homed == v["homing_status"] and buttons == v["grip"]
        assert P.encode_status(enc, homed, buttons) == packet


def _uploading(image, **faults):
    """Our driver and an emulated Falcon whose loader has taken the handshake, ready for firmware blocks."""
    model = FalconModel(image, plan=None, **faults)
    be = VirtualFalconBackend(model)
    link = FalconLink(falcon_usb_device(be))
    link.loader_mode()  # our driver's FTDI set-up and DTR pulse, then the loader's handshake by hand
    link.write(P.LOADER_CHECK)
    assert link.read(4, 0.5) == P.LOADER_CHECK_REPLY
    link.ftdi.set_dtr(False)
    link.ftdi.set_baudrate(int(round(P.UPLOAD_BAUD)))
    link.write(P.LOADER_SYNC)
    assert link.read(1, 0.5) == P.LOADER_SYNC
    return model, be, link


def test_libnifalcons_firmware_upload_replays_on_our_emulated_falcon(lib):
    """FalconFirmware::loadFirmware's blocks (62 bytes, each echo compared), through our driver to the emulator."""
    v = lib["loader"][0]
    image = bytes.fromhex(v["image"])
    assert v["ok"] and v["corrupt_echo_at"] is None and len(image) == 1000
    blocks = [bytes.fromhex(b) for b in v["blocks"]]
    assert [len(b) for b in blocks[:-1]] == [P.UPLOAD_BLOCK] * (len(blocks) - 1) and b"".join(blocks) == image
    model, be, link = _uploading(image)
    try:
        for block in blocks:
            link.write(block)                      # libnifalcon's block, through our driver to the emulator
            assert link.read(len(block), 1.0) == block   # the echo libnifalcon accepted
        link.normal_mode()
        assert model.state == "running" and bytes(model.image) == image
    finally:
        be.stop()
    # our own upload writes libnifalcon's blocks, in its order
    model = FalconModel(image, plan=None)
    be = VirtualFalconBackend(model)
    try:
        link = FalconLink(falcon_usb_device(be))
        sent = []
        write = link.write
        link.write = lambda data: (sent.append(bytes(data)), write(data))[1]
        link.upload_firmware(image)
        assert sent[-len(blocks):] == blocks and model.state == "running"
    finally:
        be.stop()


def test_a_wrong_echo_stops_the_upload_at_the_block_libnifalcon_stops_at(lib):
    v = lib["loader"][1]
    image, bad = bytes.fromhex(v["image"]), v["corrupt_echo_at"]
    assert not v["ok"] and v["error_code"] == CHECKSUM_MISMATCH
    assert len(v["blocks"]) == bad // P.UPLOAD_BLOCK + 1   # libnifalcon wrote up to the block with the bad echo
    model = FalconModel(image, plan=None, corrupt_echo_at=bad)
    be = VirtualFalconBackend(model)
    try:
        link = FalconLink(falcon_usb_device(be))
        with pytest.raises(FalconError, match=f"firmware upload failed at byte {len(v['blocks']) * P.UPLOAD_BLOCK} "):
            link.upload_firmware(image)
        # nothing after that block reached the loader, and the Falcon never started a firmware
        assert bytes(model.image) == bytes.fromhex("".join(v["blocks"])) and model.state == "uploading"
    finally:
        be.stop()


def test_our_ftdi_setup_is_libnifalcons():
    """The FTDI requests of our upload equal FalconCommLibUSB::setFirmwareMode / setNormalMode's, cited:
    latency 16 (0x40, 0x09, 16), baud 9600 (SIO_SET_BAUDRATE 0x4138), 8N1 (SIO_SET_DATA 8), no flow
    control, RTS low, DTR low then high; DTR low, baud divisor 0x15; then latency 1 and baud divisor 0x2."""
    image = bytes(range(256)) * 3
    model = FalconModel(image, plan=None)
    be = VirtualFalconBackend(model)
    try:
        link = FalconLink(falcon_usb_device(be))
        be.control_log.clear()
        link.upload_firmware(image)
        log = be.control_log
        baud = [(v, i) for r, v, i in log if r == 3]
        assert [P.ftdi_baud_from_divisor(v, i) for v, i in baud] == pytest.approx(
            [3e6 / 312.5, 3e6 / 21, 3e6 / 2], rel=1e-9)
        assert baud[0][0] == 0x4138 and baud[1][0] == 0x15 and baud[2][0] == 0x2
        latency = [v for r, v, _ in log if r == 9]
        assert latency == [16, 1]
        assert (4, 8, 1) in log or any(r == 4 and v & 0xFF == 8 for r, v, _ in log)   # 8 data bits, 1 stop, none
        dtr = [v & 1 for r, v, _ in log if r == 1 and v & 0x0100]
        assert dtr == [0, 1, 0]
        assert model.state == "running"
    finally:
        be.stop()
