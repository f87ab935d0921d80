"""Contract: the vendor's own Python package (HaplyHardwareAPI, a compiled wheel) talks to our Inverse3 emulator.

The vendor library runs in a subprocess against the emulator's pseudo-terminal, preloaded with
``modem_lines_shim.so`` (a pty has no DTR line; the shim answers the library's TIOCMGET/TIOCMSET as a CDC
ACM port would and logs them). It must wake the device and read the identity our emulator sends, send
force requests whose bytes decode to the forces it was given, and accept the emulator's state replies:
the positions and velocities it returns are the ones the emulator sent.
"""

import json
import os
import random
import subprocess
import sys
import uuid

import pytest

from devices.firmware.endpoint import TapPlan
from devices.firmware.inverse3_emulator import start_inverse3_emulator
from devices.hardware.haply import protocol as H

VENDOR = """
import json, sys
import HaplyHardwareAPI as H
port, forces = sys.argv[1], json.loads(sys.argv[2])
stream = H.SerialStream(port)  # kept referenced: the binding does not keep it alive (a temporary is freed and the
inv = H.Inverse3(stream, 2.0)   # next write jumps through its freed vtable: SIGSEGV)
out = {"wakeup": {k: str(v) for k, v in inv.device_wakeup_dict().items()}}
out["device_id"] = str(inv.get_device_id())
out["firmware"] = str(inv.get_firmware_version())
out["states"] = [inv.end_effector_force(f) for f in forces]
out["temperature"] = inv.get_temperature()
out["currents"] = list(inv.get_motor_currents())
out["power"] = inv.get_power_status()
out["cpp_version"] = H.get_cpp_version()
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def vendor_run(modem_shim, tmp_path_factory):

    rng = random.Random(49)
    forces = [[rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-3, 3)] for _ in range(200)]
    log = tmp_path_factory.mktemp("modem") / "modem.log"
    with start_inverse3_emulator(plan=TapPlan(), seed=3) as emu:
        env = dict(os.environ, LD_PRELOAD=str(modem_shim), HFAM_MODEM_LOG=str(log))
        r = subprocess.run([sys.executable, "-c", VENDOR, emu.port, json.dumps(forces)], capture_output=True,
                           text=True, timeout=120, env=env)
        assert r.returncode == 0, r.stdout + r.stderr
        return {"out": json.loads(r.stdout.strip().splitlines()[-1]), "stderr": r.stderr, "forces": forces,
                "emu": emu.emulator, "modem_log": log.read_text() if log.exists() else ""}


def test_the_vendor_library_wakes_our_emulator_and_reads_its_identity(vendor_run):
    out, emu = vendor_run["out"], vendor_run["emu"]
    w = out["wakeup"]
    assert int(w["device_id"]) == emu.info.device_id
    assert int(w["device_model_number"]) == emu.info.model
    assert int(w["hardware_version"]) == emu.info.hardware_version
    assert int(w["firmware_version"]) == emu.info.firmware_version
    assert uuid.UUID(w["device_id_ext"]) == emu.info.uuid
    assert uuid.UUID(out["device_id"]) == emu.info.uuid
    assert uuid.UUID(out["firmware"]) == emu.firmware_uuid
    assert out["power"] is True and out["temperature"] == pytest.approx(31.5)
    assert "timeout" not in vendor_run["stderr"]  # every reply had the header and length the library waits for


def test_the_vendor_library_sends_the_force_bytes_our_emulator_decodes(vendor_run):
    emu, forces = vendor_run["emu"], vendor_run["forces"]
    got = list(emu.forces_received)
    assert len(got) == len(forces) == 200
    for sent, received in zip(forces, got):
        # float32 on the wire: the same bytes our encoder makes for the same request
        assert H.encode_force(*received) == H.encode_force(*sent)
    assert emu.parser.garbage_bytes == 0 and emu.stats["bad_requests"] == 0


def test_the_vendor_library_accepts_our_state_replies(vendor_run):
    out, emu = vendor_run["out"], vendor_run["emu"]
    sent = list(emu.states_sent)
    assert len(out["states"]) == len(sent) == 200
    for (pos, vel), (epos, evel) in zip(out["states"], sent):
        assert pos == pytest.approx(epos, abs=1e-6) and vel == pytest.approx(evel, abs=1e-5)
    # the emulated hand moved the handle: the library reported motion along z (the taps), not a constant
    zs = [p[2] for p, _ in out["states"]]
    assert max(zs) - min(zs) > 1e-4
    # the motor currents it read are the ones the emulator sent: 0.1 A per N of the last force it was given
    # (zero if the emulator's watchdog had switched the motors off by then: a loaded machine can delay the request)
    currents, tripped = emu.currents_sent[-1]
    assert out["currents"] == pytest.approx(currents, abs=1e-6)
    if not tripped:
        assert currents == pytest.approx([0.1 * f for f in emu.forces_received[-1]], abs=1e-6)
        assert max(abs(c) for c in currents) > 0.01


def test_the_vendor_library_asserts_dtr_on_its_port(vendor_run):
    """What the shim saw: the library reads the modem lines and sets DTR (0x002), as on a CDC ACM port."""
    lines = vendor_run["modem_log"].splitlines()
    assert any(line.startswith("TIOCMSET") and int(line.split()[1], 16) & 0x002 for line in lines), lines
