"""HidDevice through its transport seam: 64-byte report packing, recorded reports, and a full session
against the emulator's firmware logic (no virtual HID device can exist on these machines)."""

import pytest

from devices import DeviceError, Status, make_device
from devices.hardware import wire_protocol as P
from devices.firmware.emulator import build_emulator
from devices.hardware.hid_device import HidDevice
from devices.hardware.transport import HID_REPORT_SIZE, HidTransport, pack_reports, unpack_report

# recorded with protocol 1.0: HELLO(1.0) seq 0 as an output report, and a STATE frame as an input report
RECORDED_HELLO_REPORT = bytes.fromhex("09a55a02010001000a10") + bytes(54)
RECORDED_STATE_REPORT = bytes.fromhex("17a55a10821140e2010006ffffffbdffc8000409dc05a53f") + bytes(40)


def test_report_packing_matches_the_recorded_bytes():
    reports = pack_reports(P.encode_frame(P.HELLO, 0, P.HELLO_STRUCT.pack(1, 0)))
    assert reports == [RECORDED_HELLO_REPORT]
    assert all(len(r) == HID_REPORT_SIZE for r in reports)


def test_recorded_state_report_decodes():
    frames = P.FrameParser().feed(unpack_report(RECORDED_STATE_REPORT))
    assert len(frames) == 1 and frames[0].type == P.STATE and frames[0].seq == 17
    s = P.decode_state(frames[0].payload)
    assert (s.t_us, s.encoder, s.accel_raw, s.grip_raw, s.status, s.cmd_seq, s.current_mA) == \
        (123456, -250, -67, 200, 4, 9, 1500)


def test_long_frames_span_reports_and_reassemble():
    frame = P.encode_frame(P.TABLE_DATA, 3, P.encode_data_chunk(0, [0.25] * 60))  # 251 bytes
    reports = pack_reports(frame)
    assert len(reports) == 4 and [r[0] for r in reports] == [63, 63, 63, 62]
    assert b"".join(unpack_report(r) for r in reports) == frame
    with pytest.raises(ValueError, match="must be 64 bytes"):
        unpack_report(bytes(65))
    with pytest.raises(ValueError, match="length byte 64"):
        unpack_report(bytes([64]) + bytes(63))


class EmulatedHidHandle:
    """hidapi-like handle whose far end is the emulator's firmware logic (bytes in, bytes out)."""

    def __init__(self, emu, fail_after_writes=None):
        self.emu = emu
        emu._write = self._from_device
        self.inbox = bytearray()
        self.written = []
        self.fail_after_writes = fail_after_writes

    def _from_device(self, data):
        self.inbox += data

    def write(self, data):
        data = bytes(data)
        if self.fail_after_writes is not None and len(self.written) >= self.fail_after_writes:
            raise OSError("No such device (unplugged)")
        assert len(data) == HID_REPORT_SIZE + 1 and data[0] == 0  # report id 0 + 64 bytes
        self.written.append(data)
        for frame in self.emu.parser.feed(unpack_report(data[1:])):
            self.emu.handle(frame)
        return len(data)

    def read(self, size, timeout_ms=0):
        assert size == HID_REPORT_SIZE
        if not self.inbox:
            return []
        chunk = bytes(self.inbox[:63])
        del self.inbox[:63]
        return list(pack_reports(chunk)[0])

    def close(self):
        pass


def test_hid_device_session_through_the_seam():
    emu = build_emulator()
    handle = EmulatedHidHandle(emu)
    with HidDevice(0x16C0, 0x0486, transport=handle) as dev:
        assert dev.name == "hid:16c0:0486"
        assert dev.info.servo_rate_hz == 1000.0 and dev.wire_info.serial_number == "EMU0001"
        for _ in range(200):
            s = dev.read()
            dev.command(0.25)
        assert s.extra["current_A"] == pytest.approx(0.25)
        assert emu.applied_A == pytest.approx(0.25)
        # every output report: 65 bytes, report id 0, a CURRENT frame fits in one report
        current_reports = [r for r in handle.written if r[5] == P.CURRENT]
        assert len(current_reports) >= 200 and all(r[1] == P.OVERHEAD + 4 for r in current_reports)
    assert emu.applied_A == 0.0  # close zeroed the output


def test_hid_unplug_gives_a_clear_error():
    emu = build_emulator()
    dev = HidDevice(0x16C0, 0x0486, transport=EmulatedHidHandle(emu, fail_after_writes=50)).open()
    for _ in range(100):
        s = dev.read()
        if s.status & Status.DISCONNECTED:
            break
        dev.command(0.1)
    assert s.status & Status.DISCONNECTED and dev.last_command_A == 0.0
    with pytest.raises(DeviceError, match=r"hid:16c0:0486: disconnected .*unplugged"):
        dev.read()
    dev.close()


def test_hid_device_string_and_missing_device():
    dev = make_device("hid:16c0:0486?mode=on-device")
    assert isinstance(dev, HidDevice) and dev.vid == 0x16C0 and dev.on_device_rendering
    with pytest.raises(ValueError, match=r"'hid:zz:0486'.*hex numbers"):
        make_device("hid:zz:0486")
    # real enumeration: hidapi finds no devices on these machines, so opening fails with a clear error
    with pytest.raises(DeviceError, match=r"cannot open hid:16c0:0486"):
        HidDevice(0x16C0, 0x0486).open()


def test_hid_transport_skips_malformed_reports():
    class Bad:
        def __init__(self):
            self.reports = [[70] + [0] * 63, list(pack_reports(P.encode_frame(P.PONG, 1, b"x"))[0])]

        def read(self, size, timeout_ms):
            return self.reports.pop(0) if self.reports else []

    t = HidTransport(Bad())
    data = t.read(0.01)
    assert t.bad_reports == 1 and P.FrameParser().feed(data)[0].payload == b"x"
