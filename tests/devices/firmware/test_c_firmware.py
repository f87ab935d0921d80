"""The reference C firmware: its protocol code agrees with devices/hardware/wire_protocol.py, and it builds with avr-gcc."""

import random
import subprocess
from pathlib import Path

import pytest

from plumbing import sysdeps
from devices.hardware import wire_protocol as P

from tests.support.needs import need

FIRMWARE = Path(__file__).resolve().parents[3] / "devices" / "firmware"


def _make(target, build):
    need("avr-toolchain" if target == "all" else "cc")
    # .deps/bin first on PATH: the provisioned avr-gcc when `make test` provisioned it
    return subprocess.run(["make", "-C", str(FIRMWARE), f"BUILD={build}", target], capture_output=True, text=True,
                          timeout=120, env=sysdeps.tool_env())


@pytest.fixture(scope="module")
def harness(tmp_path_factory):
    """``make fw-harness`` (hfam_fw.c built for the host, ~0.5 s of CPU) once for the module: (make's result, its
    build folder). The tests only run the binary, each with its own input."""
    build = tmp_path_factory.mktemp("fw_harness")
    return _make("fw-harness", build), build


def test_c_parser_and_crc_agree_with_python(tmp_path):
    r = _make("host-check", tmp_path)
    assert r.returncode == 0, r.stderr
    rng = random.Random(5)
    parts = []
    for k in range(200):
        payload = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 60)))
        frame = bytearray(P.encode_frame(rng.choice([P.STATE, P.CURRENT, P.ACK, P.EVENT]), k & 0xFF, payload))
        if rng.random() < 0.1:
            frame[rng.randrange(2, len(frame))] ^= 0x04  # corrupt
        if rng.random() < 0.1:
            parts.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30))) + b"\xa5")  # garbage
        parts.append(bytes(frame))
    stream = b"".join(parts)
    out = subprocess.run([str(tmp_path / "host_check")], input=stream, capture_output=True, timeout=30).stdout.decode()
    lines = out.strip().splitlines()
    c_frames = [tuple(line.split()) if len(line.split()) == 3 else (*line.split(), "") for line in lines[:-1]]
    py = P.FrameParser()
    py_frames = [(f"{f.type:02x}", f"{f.seq:02x}", f.payload.hex()) for f in py.feed(stream)]
    assert len(py_frames) > 150
    assert c_frames == py_frames
    assert lines[-1] == f"crc_errors {py.crc_errors}"


def test_avr_firmware_builds(tmp_path):
    r = _make("all", tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert (tmp_path / "hfam_fw.hex").stat().st_size > 1000
    # text data bss: RAM (data + bss) must leave room for the stack on a 2 kB ATmega328P
    sizes = [line.split() for line in r.stdout.splitlines() if line.strip().endswith("hfam_fw.elf")][-1]
    text, data, bss = (int(x) for x in sizes[:3])
    assert text + data < 32 * 1024 - 512  # flash minus the Uno bootloader
    assert data + bss < 1700


def _frames(*specs):
    return b"".join(P.encode_frame(t, k, pl) for k, (t, pl) in enumerate(specs, 1))


def test_c_firmware_speaks_the_protocol_and_renders_like_the_python_firmware(harness):
    """hfam_fw.c itself, built for the host against register stand-ins, driven with protocol frames."""
    import math

    from devices.firmware.logic import FirmwareRenderer
    from devices.hardware.calibration import Calibration

    r, build = harness
    assert r.returncode == 0, r.stderr
    cal = Calibration(0, 1, 0.345, 512, 0.0098, 0)
    stream = _frames((P.HELLO, P.HELLO_STRUCT.pack(1, 0)), (P.SET_MODE, P.MODE_STRUCT.pack(1, 1)),
                     (P.CLEAR_FAULTS, b""), (P.SET_CALIBRATION, cal.to_payload()),
                     (P.WALL, P.WALL_STRUCT.pack(0.0, 500.0, 0.0, 0.001)),
                     (P.LIMITS, P.LIMITS_STRUCT.pack(0.8, 2.0, 2.0)),
                     (P.TRANSIENT_PARAM, P.TRANSIENT_PARAM_STRUCT.pack(P.TRANSIENT_PULSE, 5.0, 0.002, 0, 0)),
                     (P.TABLE_BEGIN, P.encode_table_begin([0.1], [1.0], 10, 4000.0)), (P.PING, b"abc"),
                     (0x1F, b""), (P.RENDER_START, b""))  # 0x1F: unknown type, a false sync to both parsers
    n_ticks = 400
    out = subprocess.run([str(build / "fw_harness"), str(n_ticks)], input=stream, capture_output=True,
                         timeout=30).stdout
    frames = P.FrameParser().feed(out)
    types = [f.type for f in frames]
    assert types[:10] == [P.INFO, P.ACK, P.ACK, P.ACK, P.ACK, P.ACK, P.ACK, P.NAK, P.PONG, P.ACK]
    assert [f.seq for f in frames] == [k & 0xFF for k in range(len(frames))]  # no gaps: nothing overflowed
    w = P.decode_info(frames[0].payload)
    assert w.info.name == "hapkit-paddle" and w.serial_number == "HK0001" and w.info.servo_rate_hz == 4000.0
    assert "on_device" in w.info.capabilities and "table_transient" not in w.info.capabilities
    assert "does not fit" in P.describe_nak(frames[7].payload)
    assert frames[8].payload == b"abc"
    states = [P.decode_state(f.payload) for f in frames if f.type == P.STATE]
    events = [P.decode_event(f.payload) for f in frames if f.type == P.EVENT]
    assert len(states) == n_ticks and len(events) >= 2
    # the same scripted tap through the Python firmware logic (the emulator's renderer)
    info = w.info
    fw = FirmwareRenderer(info.position_resolution_m, info.force_per_amp_N_A, 4000.0, 2.0, velocity_window=4,
                          thermal=(info.winding_resistance_ohm, info.thermal_resistance_K_W,
                                   info.thermal_time_constant_s, info.winding_max_temp_rise_K))
    fw.cal = cal
    fw.set_wall(0.0, 500.0, 0.0, 0.001)
    fw.set_limits(0.8, 2.0)
    fw.set_param_transient(P.TRANSIENT_PULSE, 5.0, 0.002, 0.0, 0.0)
    res = info.position_resolution_m
    step = -0.1 / 4000.0 / res
    pos = 0.002 / res
    py_mA = []
    import numpy as np

    f32 = np.float32
    step, pos, lo, hi = f32(step), f32(pos), f32(-0.0015 / res), f32(0.0025 / res)
    for k in range(n_ticks):
        if pos < lo:
            pos = hi
        pos = f32(pos + step)
        enc = int(math.floor(float(pos) + 0.5)) if pos >= 0 else -int(math.floor(-float(pos) + 0.5))
        py_mA.append(round(fw.tick((k + 1) * 250, enc, 600, 600) * 1000.0))
        assert states[k].encoder == enc
    c_mA = [s.current_mA for s in states]
    assert max(c_mA) > 200
    assert max(abs(a - b) for a, b in zip(c_mA, py_mA)) <= 1
    assert [e["incoming_velocity_m_s"] for e in events] == pytest.approx(
        [e["incoming_velocity_m_s"] for e in fw.events[:len(events)]], rel=1e-5)
    assert events[0]["max_penetration_m"] == pytest.approx(fw.events[0]["max_penetration_m"], rel=1e-5)


def _harness_tap_run(harness, wall, n_ticks):
    """The host-built firmware through the harness's scripted tap (0.1 m/s down from +2.5 mm to -1.5 mm, then an
    instant lift) with ``wall`` (a WALL payload); returns (STATE frames, EVENT frames, INFO)."""
    from devices.hardware.calibration import Calibration

    r, build = harness
    assert r.returncode == 0, r.stderr
    cal = Calibration(0, 1, 0.345, 512, 0.0098, 0)
    # no keepalives come from the harness: a 60 s watchdog, so only the observer stops the output
    stream = _frames((P.HELLO, P.HELLO_STRUCT.pack(1, 1)), (P.SET_MODE, P.MODE_STRUCT.pack(1, 1)),
                     (P.SET_WATCHDOG, P.WATCHDOG_STRUCT.pack(60000)),
                     (P.CLEAR_FAULTS, b""), (P.SET_CALIBRATION, cal.to_payload()), (P.WALL, wall),
                     (P.LIMITS, P.LIMITS_STRUCT.pack(0.8, 2.0, 2.0)),
                     (P.TRANSIENT_PARAM, P.TRANSIENT_PARAM_STRUCT.pack(P.TRANSIENT_PULSE, 5.0, 0.002, 0, 0)),
                     (P.RENDER_START, b""))
    out = subprocess.run([str(build / "fw_harness"), str(n_ticks)], input=stream, capture_output=True,
                         timeout=30).stdout
    frames = P.FrameParser().feed(out)
    assert [f.type for f in frames[:9]] == [P.INFO] + [P.ACK] * 8  # the 24-byte WALL (protocol 1.1) accepted
    info = P.decode_info(frames[0].payload)
    return ([P.decode_state(f.payload) for f in frames if f.type == P.STATE],
            [P.decode_event(f.payload) for f in frames if f.type == P.EVENT], info, cal)


def test_c_firmware_passivity_observer_trips_like_the_python_firmware(harness):
    """The wall's passivity observer in hfam_fw.c and in devices/firmware/logic.py, tick by tick. The harness's
    scripted tap lifts the handle out of the wall in one tick (4 mm at full wall force): each lift is ~40 A count
    of energy the wall generates (a jump no real paddle makes, so the observer has something to stop). With a
    limit of 6 mJ (~102 A count) both stop on the same tick, with zero current from then on and FAULT + UNSTABLE
    in every STATE; the 1.0 WALL (no observer) renders the same taps to the end."""
    import math
    import struct

    from devices import Status
    from devices.firmware.logic import FirmwareRenderer

    n_ticks = 1500
    leak = -math.expm1(-1.0 / 4000.0)  # 1 s window at 4 kHz, as renderer.passivity.passivity_constants
    wall = struct.pack("<ffffff", 0.0, 500.0, 0.0, 0.001, 0.006, leak)
    states, events, w, cal = _harness_tap_run(harness, wall, n_ticks)
    assert w.protocol_version == (1, 1)
    info = w.info
    fw = FirmwareRenderer(info.position_resolution_m, info.force_per_amp_N_A, 4000.0, 2.0, velocity_window=4,
                          thermal=(info.winding_resistance_ohm, info.thermal_resistance_K_W,
                                   info.thermal_time_constant_s, info.winding_max_temp_rise_K))
    fw.cal = cal
    fw.set_wall(*P.decode_wall(wall))
    fw.set_limits(0.8, 2.0)
    fw.set_param_transient(P.TRANSIENT_PULSE, 5.0, 0.002, 0.0, 0.0)
    py_mA, py_unstable, py_e = [], [], []
    for k, s in enumerate(states):
        py_mA.append(round(fw.tick((k + 1) * 250, s.encoder, 600, 600) * 1000.0))
        py_unstable.append(fw.unstable)
        py_e.append(fw.po_e)
    c_mA = [s.current_mA for s in states]
    c_unstable = [bool(s.status & Status.UNSTABLE) for s in states]
    assert len(states) == n_ticks
    trip = c_unstable.index(True)
    assert py_unstable.index(True) == trip  # the same tick
    assert all(c_unstable[trip:]) and all(s.status & Status.FAULT for s in states[trip:])
    assert not any(s.status & (Status.FAULT | Status.UNSTABLE) for s in states[:trip])
    # three lifts (160 ticks apart) of ~40 A count each against the 102 A count limit: the third one trips
    limit = fw.instability_limit_q16
    assert limit == pytest.approx(0.006 / (info.force_per_amp_N_A * info.position_resolution_m) * 65536, rel=1e-6)
    assert 300 < trip < 600, trip
    assert py_e[trip] > limit > py_e[trip - 1] > 0.5 * limit
    assert max(c_mA[:trip]) > 200 and c_mA[trip:] == [0] * (n_ticks - trip) and py_mA[trip:] == c_mA[trip:]
    assert max(abs(a - b) for a, b in zip(c_mA, py_mA)) <= 1
    assert len(events) == len(fw.events) >= 2  # the contact open at the trip was closed and reported
    # the same taps with the 1.0 WALL (16 bytes: observer off) render to the end
    states0, _, _, _ = _harness_tap_run(harness, wall[:16], n_ticks)
    assert not any(s.status & (Status.FAULT | Status.UNSTABLE | Status.WATCHDOG_TRIPPED) for s in states0)
    assert max(s.current_mA for s in states0[trip:]) > 200


def test_rearm_samples_convert_in_integers_exactly_as_the_float_rounding_did(harness):
    """REARM_DATA samples are converted to Q24 A from their IEEE-754 bits in integers (q24_of_bits; soft-float
    lroundf per sample before): the same value as the float conversion for every pattern checked (every 13th
    32-bit pattern, each with the significands around its rounding halves: ~1.2e9 finite floats)."""
    r, build = harness
    assert r.returncode == 0, r.stderr
    out = subprocess.run([str(build / "fw_harness"), "--q24-check", "13"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    checked, mismatches = (int(v) for v in out.stdout.split()[1::2])
    assert mismatches == 0 and checked > 5e8, out.stdout
