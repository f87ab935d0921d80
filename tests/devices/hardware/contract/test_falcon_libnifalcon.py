"""Contract: libnifalcon's own source (BSD, vendored in ./libnifalcon) agrees with our Falcon codec, kinematics
and emulated loader.

The test compiles libnifalcon's ``FalconKinematicStamper.cpp``, ``FalconFirmwareNovintSDK.cpp`` and
``FalconFirmware.cpp`` with a small harness (./falcon_harness: a GMTL shim and a command loop, written for
the test) and compares, on random values, its inverse kinematics, Jacobian, force-to-motor conversion,
encoder angle, forward kinematics, the packets its firmware class writes and the packets it reads with
ours; then its firmware loader uploads an image to our emulated Falcon's loader. What libnifalcon's libusb
code does on the FTDI (FalconCommLibUSB.cpp, not compiled: it needs libusb) is checked as vectors cited
from it against the control requests our driver makes on the emulated FT232R.
"""

import random
import subprocess
from pathlib import Path

import pytest

from devices.firmware.falcon_emulator import (FalconModel, VirtualFalconBackend, falcon_usb_device,
                                              stand_in_firmware)
from devices.hardware.falcon import kinematics as K
from devices.hardware.falcon import protocol as P
from devices.hardware.falcon.link import FalconLink
from plumbing import sysdeps

from ....needs import need

HERE = Path(__file__).resolve().parent
LIB = HERE / "libnifalcon"
HARNESS = HERE / "falcon_harness"


@pytest.fixture(scope="module")
def harness(tmp_path_factory):
    """The compiled harness as a long-running process: ``ask(line) -> answer line``."""
    need("cc")
    cxx = sysdeps.tool("c++") or "c++"
    exe = tmp_path_factory.mktemp("falcon") / "falcon_harness"
    sources = [HARNESS / "falcon_harness.cpp", LIB / "src/kinematic/FalconKinematicStamper.cpp",
               LIB / "src/firmware/FalconFirmwareNovintSDK.cpp", LIB / "src/core/FalconFirmware.cpp"]
    r = subprocess.run([cxx, "-std=c++14", "-O1", f"-I{HARNESS}", f"-I{LIB / 'include'}", "-o", str(exe),
                        *map(str, sources)], capture_output=True, text=True, timeout=180, env=sysdeps.tool_env())
    assert r.returncode == 0, r.stderr[-3000:]
    proc = subprocess.Popen([str(exe)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)

    def ask(line: str) -> str:
        proc.stdin.write(line + "\n")
        proc.stdin.flush()
        return proc.stdout.readline().strip()

    ask.proc = proc
    yield ask
    proc.stdin.close()
    proc.wait(10)


def _points(n, seed):
    """Random positions inside the Falcon's workspace (a 6 cm cube around its centre)."""
    rng = random.Random(seed)
    out = []
    while len(out) < n:
        p = (rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), rng.uniform(0.08, 0.14))
        try:
            K.ik(p)
        except K.OutOfWorkspace:
            continue
        out.append(p)
    return out


def test_inverse_kinematics_and_jacobian_agree(harness):
    for p in _points(200, 1):
        theirs = [float(v) for v in harness("ik %.17g %.17g %.17g" % p).split()]
        ours = [v for group in K.ik(p) for v in group]
        assert ours == pytest.approx(theirs, abs=2e-6)   # libnifalcon keeps the angles as float32
        jt = [float(v) for v in harness("jac %.17g %.17g %.17g" % p).split()]
        jo = [v for row in K.jacobian(K.ik(p)) for v in row]
        assert jo == pytest.approx(jt, rel=1e-4, abs=1e-6)


def test_force_to_motor_commands_agree(harness):
    rng = random.Random(2)
    diffs = []
    for p in _points(300, 3):
        f = (rng.uniform(-9, 9), rng.uniform(-9, 9), rng.uniform(-9, 9))
        theirs = [int(v) for v in harness("forces %.17g %.17g %.17g %.17g %.17g %.17g" % (*p, *f)).split()]
        ours = K.motor_commands(p, f)
        diffs += [abs(a - b) for a, b in zip(ours, theirs)]
        assert max(abs(a - b) for a, b in zip(ours, theirs)) <= 2  # float32 angles: a count either side
        assert max(abs(v) for v in theirs) > 0
    assert sum(d == 0 for d in diffs) > 0.8 * len(diffs)


def test_encoder_angles_and_forward_kinematics_agree(harness):
    rng = random.Random(4)
    for _ in range(100):
        n = rng.randrange(-3000, 3000)
        assert K.theta_from_encoder(n) == pytest.approx(float(harness(f"theta {n}")), abs=1e-9)
    # libnifalcon's FK stops at 0.01 rad of leg-angle error; ours converges fully: both must land within the
    # motion that error allows (< 0.5 mm here), and ours must reproduce the encoders exactly
    for p in _points(60, 5):
        enc = [K.encoder_from_theta(t) for t in K.ik(p)[0]]
        ours = K.fk([K.theta_from_encoder(e) * K.DEG_TO_RAD for e in enc])
        assert [K.encoder_from_theta(t) for t in K.ik(ours)[0]] == enc
        for _ in range(3):  # libnifalcon starts from its last answer: a few loops settle it
            theirs = [float(v) for v in harness("pos %d %d %d" % tuple(enc)).split()]
        assert ours == pytest.approx(theirs, abs=5e-4)
        assert ours == pytest.approx(p, abs=2e-4)  # one encoder count is ~0.06 mm at the arm


def test_packets_agree_both_ways(harness):
    rng = random.Random(6)
    for _ in range(300):
        cmds = [rng.randrange(-4096, 4097) for _ in range(3)]
        leds = rng.choice((0, P.LED_RED, P.LED_GREEN, P.LED_BLUE, P.LED_RED | P.LED_BLUE))
        homing = rng.random() < 0.5
        theirs = harness(f"pack {cmds[0]} {cmds[1]} {cmds[2]} {leds} {int(homing)}")
        assert P.encode_command(cmds, leds, homing).hex() == theirs
        assert P.decode_command(bytes.fromhex(theirs)) == (tuple(cmds), leds, homing)
        enc = [rng.randrange(-32768, 32768) for _ in range(3)]
        homed, buttons = rng.randrange(8), rng.randrange(16)
        packet = P.encode_status(enc, homed, buttons)
        e0, e1, e2, hs, grip, ok = (int(v) for v in harness(f"unpack {packet.hex()}").split())
        assert ok == 1 and [e0, e1, e2] == enc and hs == homed and grip == buttons
        assert P.decode_status(packet) == (tuple(enc), homed, buttons)


def test_libnifalcons_firmware_loader_uploads_to_our_emulated_falcon(harness):
    """FalconFirmware::loadFirmware (62-byte blocks, each echo compared) against our emulator's loader."""
    image = stand_in_firmware(1000, seed=9)
    model = FalconModel(image, plan=None)
    be = VirtualFalconBackend(model)
    try:
        link = FalconLink(falcon_usb_device(be))
        link.loader_mode()  # our driver's FTDI set-up and DTR pulse, then the loader's handshake by hand
        link.write(P.LOADER_CHECK)
        assert link.read(4, 0.5) == P.LOADER_CHECK_REPLY
        link.ftdi.set_dtr(False)
        link.ftdi.set_baudrate(int(round(P.UPLOAD_BAUD)))
        link.write(P.LOADER_SYNC)
        assert link.read(1, 0.5) == P.LOADER_SYNC
        proc = harness.proc
        proc.stdin.write(f"load {len(image)}\n{image.hex()}\n")
        proc.stdin.flush()
        blocks = []
        while True:
            line = proc.stdout.readline().strip()
            if line.startswith("LOAD"):
                break
            assert line.startswith("W ")
            block = bytes.fromhex(line[2:])
            blocks.append(len(block))
            link.write(block)                       # libnifalcon's block, through our driver to the emulator
            echo = link.read(len(block), 1.0)
            proc.stdin.write(f"R {echo.hex()}\n")
            proc.stdin.flush()
        assert line.split()[1] == "1", line         # libnifalcon accepted every echo
        assert blocks[:-1] == [P.UPLOAD_BLOCK] * (len(blocks) - 1) and sum(blocks) == len(image)
        link.normal_mode()
        assert model.state == "running" and bytes(model.image) == image
    finally:
        be.stop()


def test_our_ftdi_setup_is_libnifalcons(harness):
    """The FTDI requests of our upload equal FalconCommLibUSB::setFirmwareMode / setNormalMode's, cited:
    latency 16 (0x40, 0x09, 16), baud 9600 (SIO_SET_BAUDRATE 0x4138), 8N1 (SIO_SET_DATA 8), no flow
    control, RTS low, DTR low then high; DTR low, baud divisor 0x15; then latency 1 and baud divisor 0x2."""
    image = stand_in_firmware(700, seed=2)
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
