"""Frame encode/decode, CRC-16 and the streaming parser's resynchronisation (devices/hardware/wire_protocol.py)."""

import random
import struct

import pytest

from devices.hardware import wire_protocol as P
from devices.base import DeviceInfo


def test_crc16_is_ccitt_false_and_matches_the_firmware_bitwise_algorithm():
    assert P.crc16(b"123456789") == 0x29B1  # CRC-16/CCITT-FALSE check value
    rng = random.Random(1)
    for n in (0, 1, 7, 64, 255):
        data = bytes(rng.randrange(256) for _ in range(n))
        assert P.crc16(data) == P.crc16_bitwise(data)


def test_frame_round_trip_carries_every_byte_value():
    payloads = [bytes(range(0, 128)), bytes(range(128, 256)), bytes([0xA5, 0x5A] * 100), b"", bytes(255)]
    stream = b"".join(P.encode_frame(P.TABLE_DATA, k, p) for k, p in enumerate(payloads))
    parser = P.FrameParser()
    frames = parser.feed(stream)
    assert [f.payload for f in frames] == payloads
    assert [f.seq for f in frames] == list(range(len(payloads)))
    assert all(f.type == P.TABLE_DATA for f in frames)
    assert parser.crc_errors == 0 and parser.garbage_bytes == 0
    seen = set(b"".join(payloads))
    assert seen == set(range(256))


def test_frame_layout_is_sync_len_type_seq_payload_crc_le():
    frame = P.encode_frame(P.CURRENT, 7, struct.pack("<f", 0.5))
    assert frame[:2] == b"\xa5\x5a" and frame[2] == 4 and frame[3] == P.CURRENT and frame[4] == 7
    assert int.from_bytes(frame[-2:], "little") == P.crc16(frame[2:-2])
    assert len(frame) == P.OVERHEAD + 4


def test_oversize_payload_is_refused():
    with pytest.raises(ValueError, match="exceeds"):
        P.encode_frame(P.STATE, 0, bytes(256))


def test_parser_handles_byte_by_byte_and_random_chunking():
    rng = random.Random(2)
    frames = [P.encode_frame(P.STATE, k & 0xFF, bytes(rng.randrange(256) for _ in range(rng.randrange(40))))
              for k in range(300)]
    stream = b"".join(frames)
    parser = P.FrameParser()
    got = []
    pos = 0
    while pos < len(stream):
        n = rng.choice((1, 2, 3, 17, 64, 500))
        got += parser.feed(stream[pos:pos + n])
        pos += n
    assert len(got) == 300 and parser.crc_errors == 0 and parser.pending_bytes == 0


def test_resync_after_garbage_truncated_and_corrupted_frames():
    good = [P.encode_frame(P.STATE, k, bytes([k]) * 16) for k in range(6)]
    truncated = good[1][:9]
    corrupted = bytearray(good[3])
    corrupted[8] ^= 0x10
    garbage = bytes([0x00, 0xA5, 0xFF, 0xA5, 0x5A, 0x03]) + bytes(range(40))  # includes a false sync
    stream = garbage + good[0] + truncated + good[2] + bytes(corrupted) + b"\xa5" + good[4] + good[5]
    parser = P.FrameParser()
    got = parser.feed(stream)
    assert [f.seq for f in got] == [0, 2, 4, 5]
    assert parser.crc_errors >= 2  # the corrupted frame, the truncated one swallowing the next header
    assert parser.garbage_bytes > 0
    # the parser keeps working after all that
    assert [f.seq for f in parser.feed(P.encode_frame(P.ACK, 9, b"\x01\x02"))] == [9]


def test_parser_keeps_a_trailing_half_sync():
    frame = P.encode_frame(P.PONG, 3, b"hi")
    parser = P.FrameParser()
    assert parser.feed(b"junk" + frame[:1]) == []
    assert [f.payload for f in parser.feed(frame[1:])] == [b"hi"]


def test_state_event_and_table_payload_round_trips():
    payload = P.encode_state(2**32 - 1, -123456, -32768, 65535, 0b1101, 200, -4000)
    s = P.decode_state(payload)
    assert (s.t_us, s.encoder, s.accel_raw, s.grip_raw, s.status, s.cmd_seq, s.current_mA) == \
        (2**32 - 1, -123456, -32768, 65535, 13, 200, -4000)
    ev = {"t_us": 99, "incoming_velocity_m_s": 0.125, "grip_N": 2.5, "max_penetration_m": 0.001,
          "peak_accel_m_s2": 30.0, "clipped": True, "kind": P.TRANSIENT_SINUSOID, "index": 4}
    back = P.decode_event(P.encode_event(ev))
    assert back["clipped"] and back["transient"] == "sinusoid" and back["incoming_velocity_m_s"] == 0.125
    assert back["max_penetration_m"] == pytest.approx(0.001, rel=1e-6)
    v, g, n, fs, gain, mx = P.decode_table_begin(P.encode_table_begin([0.05, 0.1], [1.0, 2.0, 3.0], 1000, 1e4,
                                                                      0.9, 2.0))
    assert v == pytest.approx([0.05, 0.1]) and g == [1.0, 2.0, 3.0] and n == 1000 and gain == pytest.approx(0.9)
    off, samples = P.decode_data_chunk(P.encode_data_chunk(120, [0.5] * 60))
    assert off == 120 and samples == (0.5,) * 60
    with pytest.raises(P.ProtocolError, match="STATE payload must be"):
        P.decode_state(payload[:-1])


def _wire_info(**over):
    info = DeviceInfo(name="paddle", encoder_lines=500, gear_ratio=10.0, handle_length_m=0.07,
                      torque_constant_Nm_A=0.0187, current_continuous_A=0.8, current_peak_A=2.0,
                      current_amplifier_A=2.5, servo_rate_hz=5000.0, grip_range_N=(0.0, 12.0),
                      capabilities=("streaming", "on_device"))
    fields = dict(info=info, protocol_version=(1, 0), firmware_version=(1, 2, 3), serial_number="SN42",
                  accel_scale_m_s2_per_count=0.0175 * 9.81, accel_offset_counts=512, grip_scale_N_per_count=0.009,
                  grip_offset_counts=3, watchdog_ms=50, capability_bits=P.CAP_STREAMING | P.CAP_ON_DEVICE,
                  max_table_samples=200)
    fields.update(over)
    return P.WireInfo(**fields)


def test_info_round_trip_carries_every_deviceinfo_field():
    w = _wire_info()
    back = P.decode_info(P.encode_info(w))
    assert back.info == w.info
    assert back.firmware_version == (1, 2, 3) and back.serial_number == "SN42" and back.watchdog_ms == 50
    assert back.accel_offset_counts == 512 and back.grip_scale_N_per_count == pytest.approx(0.009)
    assert back.device_id == "paddle/SN42" and back.max_table_samples == 200


def test_info_says_whether_the_device_is_an_emulator():
    """INFO flags bit 2: an emulator of the board (a link, no hardware) says so; the firmware never sets it, and
    the bit is independent of ``simulated`` (which would take the hardware path away)."""
    from dataclasses import replace
    w = _wire_info()
    assert P.info_flags(w.info) == 0 and not P.decode_info(P.encode_info(w)).info.emulated
    emu = _wire_info(info=replace(w.info, emulated=True))
    assert P.info_flags(emu.info) == P.INFO_FLAG_EMULATED == 4
    back = P.decode_info(P.encode_info(emu)).info
    assert back.emulated and not back.simulated and back == emu.info


def test_info_decode_errors_name_the_problem():
    raw = P.encode_info(_wire_info())
    with pytest.raises(P.ProtocolError, match="too short"):
        P.decode_info(raw[:20])
    with pytest.raises(P.ProtocolError, match="name length"):
        P.decode_info(raw[:P.INFO_STRUCT.size] + b"\x30abc")
    bad = P.encode_info(_wire_info(accel_scale_m_s2_per_count=-1.0))
    with pytest.raises(P.ProtocolError, match="accel scale"):
        P.decode_info(bad)


def test_unknown_message_type_is_treated_as_a_false_sync():
    parser = P.FrameParser()
    got = parser.feed(P.encode_frame(0x42, 1, b"abc") + P.encode_frame(P.ACK, 2, b"\x01\x02"))
    assert [f.seq for f in got] == [2] and parser.garbage_bytes > 0


def test_a_state_frame_half_received_is_well_formed_and_a_false_sync_is_not():
    """The telemetry reader gives up on a pending partial frame at a timeout only if it is not a frame a device
    sends (a false sync): half a STATE from a simulator paused mid-frame is kept and completes."""
    frame = P.encode_frame(P.STATE, 7, P.encode_state(1234, 5, 6, 7, 0, 0, 0))
    parser = P.FrameParser()
    assert parser.feed(frame[:9]) == [] and parser.pending_is_well_formed()
    assert [f.seq for f in parser.feed(frame[9:])] == [7] and not parser.pending_is_well_formed()
    false_sync = P.FrameParser()
    assert false_sync.feed(P.SYNC + bytes([200, P.STATE, 0, 1, 2])) == []
    assert not false_sync.pending_is_well_formed()          # a STATE is never 200 bytes
    assert not P.FrameParser().pending_is_well_formed()
    host_type = P.FrameParser()
    assert host_type.feed(P.SYNC + bytes([4, P.CURRENT, 0, 1])) == []
    assert not host_type.pending_is_well_formed()           # a host -> device type, never from a device
