"""Wire protocol between the host and a haptic device's microcontroller (docs/protocol.md).

A frame is::

    0xA5 0x5A | len u8 | type u8 | seq u8 | payload (len bytes) | crc16 u16 LE

``crc16`` is CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no
final xor) over ``len, type, seq, payload``. All multi-byte fields are little
endian; floats are IEEE-754 float32 (what an AVR's ``float`` is).

The same byte stream runs over a serial/CDC port and, chunked into 64-byte
reports, over USB HID (:mod:`devices.hardware.hid_device`). :class:`FrameParser` takes
arbitrary chunks of bytes and yields whole frames; it resynchronises after
garbage or truncated frames and counts every byte it had to throw away.

This module is pure (no I/O) so the host drivers, the emulator and the tests
share one implementation; the C firmware in ``devices/firmware/`` mirrors it.
"""

from __future__ import annotations

import binascii
import math
import struct
from dataclasses import dataclass

from ..base import DeviceInfo

SYNC = b"\xa5\x5a"
HEADER_SIZE = 5  # sync(2) len type seq
CRC_SIZE = 2
OVERHEAD = HEADER_SIZE + CRC_SIZE
MAX_PAYLOAD = 255

PROTOCOL_VERSION = (1, 1)  # (major, minor); a major mismatch is refused at the hello
# 1.1: WALL may append the passivity observer's limit and leak (WALL_OBSERVER_STRUCT); STATE status bit 64 UNSTABLE

# -- message types: host -> device -----------------------------------------
HELLO = 0x01
CURRENT = 0x02
SET_MODE = 0x03
SET_WATCHDOG = 0x04
CLEAR_FAULTS = 0x05
PING = 0x06
SET_CALIBRATION = 0x07
WALL = 0x10
LIMITS = 0x11
TRANSIENT_PARAM = 0x12
TABLE_BEGIN = 0x13
TABLE_DATA = 0x14
TABLE_COMMIT = 0x15
REARM_DATA = 0x16
REARM_COMMIT = 0x17
RENDER_START = 0x18
RENDER_STOP = 0x19
KEEPALIVE = 0x1A
# -- device -> host ---------------------------------------------------------
INFO = 0x81
STATE = 0x82
EVENT = 0x83
ACK = 0x84
NAK = 0x85
PONG = 0x86

TYPE_NAMES = {v: k for k, v in dict(globals()).items() if k.isupper() and isinstance(v, int) and 0 < v < 0x100
              and k not in ("HEADER_SIZE", "CRC_SIZE", "OVERHEAD", "MAX_PAYLOAD")}

MODE_STREAMING = 0
MODE_ON_DEVICE = 1

# capability bits in INFO
CAP_STREAMING = 1
CAP_ON_DEVICE = 2
CAP_PARAM_TRANSIENT = 4
CAP_TABLE_TRANSIENT = 8
CAP_REARM_TRANSIENT = 16
# the link is native USB (CDC/HID), not a UART: its rate does not limit a telemetry frame every tick
CAP_NATIVE_USB = 32
CAPABILITY_NAMES = {CAP_STREAMING: "streaming", CAP_ON_DEVICE: "on_device", CAP_PARAM_TRANSIENT: "param_transient",
                    CAP_TABLE_TRANSIENT: "table_transient", CAP_REARM_TRANSIENT: "rearm_transient",
                    CAP_NATIVE_USB: "native_usb"}

# transient kinds for TRANSIENT_PARAM / EVENT
TRANSIENT_NONE = 0
TRANSIENT_PULSE = 1
TRANSIENT_SINUSOID = 2
TRANSIENT_TABLE = 3
TRANSIENT_REARM = 4
TRANSIENT_KIND_NAMES = {TRANSIENT_NONE: "none", TRANSIENT_PULSE: "pulse", TRANSIENT_SINUSOID: "sinusoid",
                        TRANSIENT_TABLE: "table", TRANSIENT_REARM: "rearm"}

# NAK error codes
NAK_UNKNOWN_TYPE = 1
NAK_BAD_PAYLOAD = 2
NAK_BAD_STATE = 3
NAK_TOO_LARGE = 4
NAK_VERSION = 5
NAK_NAMES = {NAK_UNKNOWN_TYPE: "unknown message type", NAK_BAD_PAYLOAD: "malformed payload",
             NAK_BAD_STATE: "not allowed in the current mode", NAK_TOO_LARGE: "does not fit in device memory",
             NAK_VERSION: "protocol version not supported"}

EVENT_FLAG_CLIPPED = 1
EVENT_FLAG_WATCHDOG = 2

TABLE_CHUNK_SAMPLES = 60  # at most this many float32 samples per TABLE_DATA/REARM_DATA frame (4 + 240 bytes)
# What hosts send per data frame, one frame at a time (the next once the last one's ACK is back): a
# 24-sample frame is 107 bytes and fits whole in a 128-byte receive buffer (the reference firmware's,
# devices/firmware/hfam_fw.c) however busy the device is; see docs/protocol.md "Receive buffer".
DATA_CHUNK_SAMPLES = 24

# -- payload layouts --------------------------------------------------------
# STATE: t_us u32, encoder i32, accel_raw i16, grip_raw u16, status u8, cmd_seq u8, current_mA i16
STATE_STRUCT = struct.Struct("<IihHBBh")
CURRENT_STRUCT = struct.Struct("<f")
# EVENT: t_us u32, v_in f32, grip f32, max_pen f32, peak_accel f32, flags u8, kind u8, index u16
EVENT_STRUCT = struct.Struct("<IffffBBH")
ACK_STRUCT = struct.Struct("<BB")
NAK_STRUCT = struct.Struct("<BBB")
WALL_STRUCT = struct.Struct("<ffff")
# WALL with the passivity observer (protocol 1.1): ... instability_limit_J f32 (0: off), instability_leak f32 (per tick)
WALL_OBSERVER_STRUCT = struct.Struct("<ffffff")
LIMITS_STRUCT = struct.Struct("<fff")
MODE_STRUCT = struct.Struct("<BH")
WATCHDOG_STRUCT = struct.Struct("<H")
HELLO_STRUCT = struct.Struct("<BB")
# SET_CALIBRATION: encoder_zero i32, encoder_sign i8, accel scale f32, accel offset f32, grip scale f32, grip offset f32
CALIBRATION_STRUCT = struct.Struct("<ibffff")
# TRANSIENT_PARAM: kind u8, then 4 float params (meaning per kind, docs/protocol.md)
TRANSIENT_PARAM_STRUCT = struct.Struct("<Bffff")
# TABLE_BEGIN: n_v u16, n_g u16, n_s u32, fs f32, gain f32, max_extrapolation f32, then n_v + n_g f32 levels
TABLE_BEGIN_STRUCT = struct.Struct("<HHIfff")
DATA_OFFSET_STRUCT = struct.Struct("<I")
# INFO: fixed part then two length-prefixed ASCII strings (name, serial)
INFO_STRUCT = struct.Struct("<5BI9fhfh6f2HIH")


#: payload sizes of the device -> host frames at this host's protocol version: (exact size, or None for a
#: variable one, minimum size). A frame of another size, or of a type a device never sends, is malformed:
#: the host drops and counts it like a frame with a bad CRC (one malformed frame is a loss)
DEVICE_FRAME_SIZES = {INFO: (None, INFO_STRUCT.size + 2), STATE: (STATE_STRUCT.size, STATE_STRUCT.size),
                      EVENT: (EVENT_STRUCT.size, EVENT_STRUCT.size), ACK: (ACK_STRUCT.size, ACK_STRUCT.size),
                      NAK: (None, NAK_STRUCT.size), PONG: (None, 0)}

#: the physical range of each INFO value (inclusive; unit in the name). A device reporting a value outside
#: is refused at the handshake (a servo rate of 1e9 Hz would hang the renderer's set-up). The bounds
#: are generous: the simulated testbed (devices/sim/default_params.toml: 10 kHz, 2000 lines, rho 15,
#: h 0.15 m, k_t 0.0235 N m/A, 1.26-4 A), the AVR board (4 kHz) and any desktop haptic interface lie
#: well inside them.
INFO_RANGES = {
    "servo_rate_hz": (100.0, 100_000.0),
    "encoder_lines": (1, 1 << 24),
    "gear_ratio": (0.01, 1000.0),
    "handle_length_m": (1e-3, 2.0),
    "torque_constant_Nm_A": (1e-5, 10.0),
    "current_continuous_A": (1e-3, 100.0),
    "current_peak_A": (1e-3, 100.0),
    "current_amplifier_A": (1e-3, 100.0),
    "accel_range_m_s2": (1.0, 1e5),
    "grip_range_N": (-1e4, 1e4),
    "winding_resistance_ohm": (1e-3, 1e4),
    "thermal_resistance_K_W": (1e-3, 1e4),
    "thermal_time_constant_s": (1e-2, 1e6),
    "winding_max_temp_rise_K": (1.0, 1000.0),
    "watchdog_ms": (1, 60_000),
    "max_table_samples": (0, 1 << 26),
}


def check_frame_size(frame_type: int, size: int, newer_minor: bool = False) -> str:
    """Why a device -> host frame of ``frame_type`` with a ``size``-byte payload is malformed ("" if it is not).

    Parameters
    ----------
    frame_type : int
        The frame's message type.
    size : int
        Its payload length in bytes.
    newer_minor : bool
        The device speaks a newer minor version than this host: it may append fields to a fixed-size payload,
        which the host ignores (docs/protocol.md, Versioning).

    Returns
    -------
    str
        Empty for a well-formed frame, else what is wrong (for the link counters' message).
    """
    sizes = DEVICE_FRAME_SIZES.get(frame_type)
    if sizes is None:
        return f"type {TYPE_NAMES.get(frame_type, f'0x{frame_type:02x}')} is not sent by a device"
    exact, minimum = sizes
    if size < minimum or (exact is not None and size != exact and not newer_minor):
        want = f"{exact}" if exact is not None else f"at least {minimum}"
        return f"{TYPE_NAMES[frame_type]} payload of {size} bytes, expected {want}"
    return ""


class ProtocolError(ValueError):
    """A frame or payload that cannot be decoded (names the message type and what is wrong)."""


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (poly 0x1021, init 0xFFFF); ``binascii.crc_hqx`` is the same CRC in C."""
    return binascii.crc_hqx(data, crc)


def crc16_bitwise(data: bytes, crc: int = 0xFFFF) -> int:
    """Bit-by-bit reference of :func:`crc16`, the algorithm the C firmware uses (for cross-checking)."""
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def encode_frame(msg_type: int, seq: int, payload: bytes = b"") -> bytes:
    """Build one frame (see module doc). Raises ValueError for an oversize payload or bad type/seq."""
    n = len(payload)
    if n > MAX_PAYLOAD:
        raise ValueError(f"payload of {n} bytes exceeds the {MAX_PAYLOAD}-byte frame limit (type 0x{msg_type:02x})")
    body = bytes((n, msg_type & 0xFF, seq & 0xFF)) + payload
    return SYNC + body + crc16(body).to_bytes(2, "little")


@dataclass(frozen=True)
class Frame:
    """One decoded, CRC-checked frame: message ``type``, sequence number ``seq`` (0-255) and ``payload`` bytes."""
    type: int
    seq: int
    payload: bytes

    @property
    def type_name(self) -> str:
        """The message type's name (``"STATE"``), or its hex code if unknown."""
        return TYPE_NAMES.get(self.type, f"0x{self.type:02x}")


class FrameParser:
    """Incremental frame decoder with resynchronisation.

    ``feed(chunk)`` returns the list of complete, CRC-valid frames found so
    far. Bytes before a sync pattern are discarded (``garbage_bytes``); a
    frame whose CRC does not match is dropped (``crc_errors``) and the search
    restarts one byte after its sync, so a sync pattern inside a corrupted
    frame's payload cannot swallow the valid frame that follows.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.frames_ok = 0
        self.crc_errors = 0
        self.garbage_bytes = 0

    def reset(self) -> None:
        """Drop every byte not yet parsed (after a reconnect)."""
        self._buf.clear()

    @property
    def pending_bytes(self) -> int:
        """Bytes received but not yet part of a complete frame."""
        return len(self._buf)

    def pending_is_well_formed(self) -> bool:
        """Whether the pending partial frame starts with a header a device sends (a device -> host type whose
        length byte is a payload size of that type, :data:`DEVICE_FRAME_SIZES`): a frame still arriving from
        a slow device (a simulator descheduled mid-frame), not a false sync to give up on."""
        buf = self._buf
        if len(buf) < HEADER_SIZE or bytes(buf[:2]) != SYNC:
            return False
        sizes = DEVICE_FRAME_SIZES.get(buf[3])
        if sizes is None:
            return False
        exact, minimum = sizes
        return buf[2] == exact if exact is not None else minimum <= buf[2] <= MAX_PAYLOAD

    def skip_partial(self) -> list[Frame]:
        """Give up on a pending partial frame (its length byte may be garbage) and re-parse after its sync.

        Called by a driver when a reply is overdue: a false sync with a large
        length would otherwise hold back the valid frames behind it.
        """
        if len(self._buf) < 2:
            return []
        self.garbage_bytes += 1
        del self._buf[:1]
        return self.feed(b"")

    def feed(self, chunk: bytes) -> list[Frame]:
        """Add received bytes; return the complete, CRC-valid frames found, in order.

        Parameters
        ----------
        chunk : bytes
            Bytes as read from the link (any split).

        Returns
        -------
        list of Frame
            Garbage before a sync and frames with a bad CRC are skipped (counted in ``garbage_bytes`` and
            ``crc_errors``); an incomplete frame stays pending for the next call.
        """
        buf = self._buf
        buf += chunk
        out: list[Frame] = []
        pos = 0
        n = len(buf)
        while True:
            start = buf.find(SYNC, pos)
            if start < 0:
                # keep a trailing 0xA5: it may be the first half of the next sync
                keep = 1 if n and buf[n - 1] == 0xA5 else 0
                self.garbage_bytes += n - pos - keep
                pos = n - keep
                break
            self.garbage_bytes += start - pos
            if start + HEADER_SIZE > n:
                pos = start
                break
            if buf[start + 3] not in TYPE_NAMES:  # a false sync inside garbage: skip it at once
                self.garbage_bytes += 1
                pos = start + 1
                continue
            length = buf[start + 2]
            end = start + HEADER_SIZE + length + CRC_SIZE
            if end > n:
                pos = start
                break
            body = bytes(buf[start + 2:end - CRC_SIZE])
            if crc16(body) == buf[end - 2] | (buf[end - 1] << 8):
                out.append(Frame(body[1], body[2], body[3:]))
                self.frames_ok += 1
                pos = end
            else:
                self.crc_errors += 1
                self.garbage_bytes += 1
                pos = start + 1
        del buf[:pos]
        return out


# -- payload codecs ------------------------------------------------------------
def _unpack(st: struct.Struct, payload: bytes, what: str) -> tuple:
    if len(payload) != st.size:
        raise ProtocolError(f"{what} payload must be {st.size} bytes, got {len(payload)}")
    return st.unpack(payload)


def decode_wall(payload: bytes) -> tuple:
    """WALL payload -> (height_m, stiffness_N_m, damping_N_s_m, rearm_margin_m, instability_limit_J,
    instability_leak): 16 bytes (protocol 1.0, observer off: limit and leak 0) or 24 (1.1); ProtocolError otherwise."""
    if len(payload) == WALL_STRUCT.size:
        return (*WALL_STRUCT.unpack(payload), 0.0, 0.0)
    return _unpack(WALL_OBSERVER_STRUCT, payload, "WALL")


def encode_current(current_A: float) -> bytes:
    """CURRENT payload: the motor current command in A (float32)."""
    return CURRENT_STRUCT.pack(current_A)


def decode_current(payload: bytes) -> float:
    """The current (A) of a CURRENT payload; ProtocolError if the payload has the wrong size."""
    (value,) = _unpack(CURRENT_STRUCT, payload, "CURRENT")
    return value


@dataclass
class RawState:
    """A decoded STATE payload: raw sensor values as the microcontroller reads them."""

    t_us: int
    encoder: int
    accel_raw: int
    grip_raw: int
    status: int
    cmd_seq: int
    current_mA: int


def encode_state(t_us: int, encoder: int, accel_raw: int, grip_raw: int, status: int, cmd_seq: int,
                 current_mA: int) -> bytes:
    """STATE payload: the raw sensor values of one firmware tick.

    Parameters
    ----------
    t_us : int
        Device clock (us, wraps at 2^32).
    encoder : int
        Encoder count.
    accel_raw, grip_raw : int
        Raw ADC counts of the accelerometer and the grip sensor.
    status : int
        Status bits (``Status``).
    cmd_seq : int
        Sequence number of the last command applied.
    current_mA : int
        The current applied (mA).
    """
    return STATE_STRUCT.pack(t_us & 0xFFFFFFFF, encoder, accel_raw, grip_raw, status & 0xFF, cmd_seq & 0xFF,
                             current_mA)


def decode_state(payload: bytes) -> RawState:
    """A :class:`RawState` from a STATE payload; ProtocolError if the payload has the wrong size."""
    return RawState(*_unpack(STATE_STRUCT, payload, "STATE"))


def encode_event(event: dict) -> bytes:
    """EVENT payload from an event dict (keys as :func:`decode_event` returns them).

    A contact event: time (us), incoming velocity (m/s), grip (N), maximum penetration (m), peak
    acceleration (m/s^2), clipped and watchdog flags, transient kind and event index.
    """
    flags = (EVENT_FLAG_CLIPPED if event.get("clipped") else 0) | (EVENT_FLAG_WATCHDOG if event.get("watchdog") else 0)
    return EVENT_STRUCT.pack(int(event["t_us"]) & 0xFFFFFFFF, event["incoming_velocity_m_s"], event["grip_N"],
                             event["max_penetration_m"], event["peak_accel_m_s2"], flags, event.get("kind", 0),
                             event.get("index", 0) & 0xFFFF)


def decode_event(payload: bytes) -> dict:
    """An EVENT payload as a dict.

    Returns
    -------
    dict
        ``t_us``, ``incoming_velocity_m_s``, ``grip_N``, ``max_penetration_m``, ``peak_accel_m_s2``,
        ``clipped``, ``watchdog``, ``kind``, ``transient`` (the kind's name) and ``index``.
    """
    t_us, v_in, grip, pen, peak, flags, kind, index = _unpack(EVENT_STRUCT, payload, "EVENT")
    return {"t_us": t_us, "incoming_velocity_m_s": v_in, "grip_N": grip, "max_penetration_m": pen,
            "peak_accel_m_s2": peak, "clipped": bool(flags & EVENT_FLAG_CLIPPED),
            "watchdog": bool(flags & EVENT_FLAG_WATCHDOG), "kind": kind,
            "transient": TRANSIENT_KIND_NAMES.get(kind, str(kind)), "index": index}


@dataclass(frozen=True)
class WireInfo:
    """Everything the INFO reply carries: the :class:`DeviceInfo` plus firmware and ADC facts."""

    info: DeviceInfo
    protocol_version: tuple[int, int]
    firmware_version: tuple[int, int, int]
    serial_number: str
    accel_scale_m_s2_per_count: float
    accel_offset_counts: int
    grip_scale_N_per_count: float
    grip_offset_counts: int
    watchdog_ms: int
    capability_bits: int
    max_table_samples: int
    modes: int = 1  # bit 0 streaming, bit 1 on-device (redundant with capabilities, kept for old hosts)

    @property
    def device_id(self) -> str:
        """Key for per-device calibration: ``name/serial``."""
        return f"{self.info.name}/{self.serial_number}"


def capability_names(bits: int) -> tuple[str, ...]:
    """Names of the capability bits set in ``bits`` (``("streaming", "on_device", ...)``)."""
    return tuple(name for bit, name in sorted(CAPABILITY_NAMES.items()) if bits & bit)


def _short_str(text: str, limit: int, what: str) -> bytes:
    raw = text.encode("ascii", "replace")
    if len(raw) > limit:
        raise ValueError(f"INFO {what} {text!r} longer than {limit} ASCII characters")
    return bytes((len(raw),)) + raw


#: INFO flags: bit 0 simulated; bit 1 lockstep (the device's clock is simulated and advances only with the
#: host's frames: bits 8-15 give the servo ticks per host period, docs/protocol.md "Lockstep"); bit 2 emulated
#: (an emulator of the board on the link, not hardware: the firmware never sets it)
INFO_FLAG_SIMULATED = 1
INFO_FLAG_LOCKSTEP = 2
INFO_FLAG_EMULATED = 4


def info_flags(info: DeviceInfo) -> int:
    """INFO's flags field for ``info``: simulated (bit 0), lockstep (bit 1) with its ticks per period (bits 8-15),
    emulated (bit 2)."""
    flags = (INFO_FLAG_SIMULATED if info.simulated else 0) | (INFO_FLAG_EMULATED if info.emulated else 0)
    if info.lockstep_ticks:
        flags |= INFO_FLAG_LOCKSTEP | (info.lockstep_ticks << 8)
    return flags


def encode_info(w: WireInfo) -> bytes:
    """INFO payload: protocol and firmware versions, device constants and calibration of ``w``."""
    i = w.info
    fixed = INFO_STRUCT.pack(
        w.protocol_version[0], w.protocol_version[1], *w.firmware_version,
        i.encoder_lines, i.gear_ratio, i.handle_length_m, i.torque_constant_Nm_A,
        i.current_continuous_A, i.current_peak_A, i.current_amplifier_A, i.servo_rate_hz,
        i.accel_range_m_s2, w.accel_scale_m_s2_per_count, w.accel_offset_counts,
        w.grip_scale_N_per_count, w.grip_offset_counts, i.grip_range_N[0], i.grip_range_N[1],
        i.winding_resistance_ohm, i.thermal_resistance_K_W, i.thermal_time_constant_s, i.winding_max_temp_rise_K,
        w.watchdog_ms, w.capability_bits, w.max_table_samples, info_flags(i),
    )
    return fixed + _short_str(i.name, 32, "name") + _short_str(w.serial_number, 16, "serial number")


def decode_info(payload: bytes) -> WireInfo:
    """Decode an INFO payload; raises ProtocolError naming the field that is wrong."""
    n = INFO_STRUCT.size
    if len(payload) < n + 2:
        raise ProtocolError(f"INFO payload too short: {len(payload)} bytes, need at least {n + 2}")
    (pmaj, pmin, fmaj, fmin, fpat, lines, rho, h, kt, cont, peak, amp, rate, arange, ascale, aoff, gscale, goff,
     gmin, gmax, rw, rth, tau, trise, wd_ms, caps, max_table, flags) = INFO_STRUCT.unpack_from(payload)
    pos = n
    strings = []
    for what in ("name", "serial number"):
        if pos >= len(payload):
            raise ProtocolError(f"INFO payload truncated before the {what}")
        k = payload[pos]
        if pos + 1 + k > len(payload):
            raise ProtocolError(f"INFO {what} length {k} runs past the payload end")
        strings.append(payload[pos + 1:pos + 1 + k].decode("ascii", "replace"))
        pos += 1 + k
    for key, value in {"accel scale": ascale, "grip scale": gscale}.items():
        if not (math.isfinite(value) and value > 0):
            raise ProtocolError(f"INFO {key} must be positive and finite, got {value!r}")
    _check_info_ranges({"servo_rate_hz": rate, "encoder_lines": lines, "gear_ratio": rho, "handle_length_m": h,
                        "torque_constant_Nm_A": kt, "current_continuous_A": cont, "current_peak_A": peak,
                        "current_amplifier_A": amp, "accel_range_m_s2": arange, "grip_range_N": (gmin, gmax),
                        "winding_resistance_ohm": rw, "thermal_resistance_K_W": rth, "thermal_time_constant_s": tau,
                        "winding_max_temp_rise_K": trise, "watchdog_ms": wd_ms, "max_table_samples": max_table})
    if flags & INFO_FLAG_LOCKSTEP and not flags >> 8:
        raise ProtocolError("INFO flags say lockstep but give 0 servo ticks per host period (bits 8-15)")
    # float32 on the wire: round to its ~7 significant digits so 0.15 stays 0.15
    rho, h, kt, cont, peak, amp, rate, arange, gmin, gmax, rw, rth, tau, trise = (
        float(f"{x:.7g}") for x in (rho, h, kt, cont, peak, amp, rate, arange, gmin, gmax, rw, rth, tau, trise))
    try:
        info = DeviceInfo(
            name=strings[0], encoder_lines=lines, gear_ratio=rho, handle_length_m=h, torque_constant_Nm_A=kt,
            current_continuous_A=cont, current_peak_A=peak, current_amplifier_A=amp, servo_rate_hz=rate,
            winding_resistance_ohm=rw, thermal_resistance_K_W=rth, thermal_time_constant_s=tau,
            winding_max_temp_rise_K=trise, accel_range_m_s2=arange, grip_range_N=(gmin, gmax),
            capabilities=capability_names(caps), simulated=bool(flags & INFO_FLAG_SIMULATED),
            lockstep_ticks=(flags >> 8) if flags & INFO_FLAG_LOCKSTEP else 0,
            emulated=bool(flags & INFO_FLAG_EMULATED),
        )
    except ValueError as exc:
        raise ProtocolError(f"INFO describes an impossible device: {exc}") from None
    return WireInfo(info, (pmaj, pmin), (fmaj, fmin, fpat), strings[1], ascale, aoff, gscale, goff, wd_ms, caps,
                    max_table)


def _check_info_ranges(values: dict) -> None:
    """ProtocolError naming the first INFO value outside :data:`INFO_RANGES` (or not finite)."""
    for key, value in values.items():
        low, high = INFO_RANGES[key]
        for v in (value if isinstance(value, tuple) else (value,)):
            if not (math.isfinite(v) and low <= v <= high):
                raise ProtocolError(f"INFO {key} = {v:g} is outside the physical range {low:g}..{high:g}; "
                                    "the device's INFO is wrong (firmware constants or a damaged reply)")
    gmin, gmax = values["grip_range_N"]
    if not gmin < gmax:
        raise ProtocolError(f"INFO grip_range_N ({gmin:g}, {gmax:g}) is empty: the minimum must be below the maximum")


def encode_table_begin(velocities_m_s, grips_N, n_samples: int, fs_hz: float, gain: float = 1.0,
                       max_extrapolation: float = 1.0) -> bytes:
    """TABLE_BEGIN payload announcing an HFAM table (section 4.4.2).

    Parameters
    ----------
    velocities_m_s, grips_N : sequence of float
        The table's velocity (m/s) and grip (N) levels.
    n_samples : int
        Samples per transient.
    fs_hz : float
        Sample rate of the table (Hz).
    gain : float
        Output gain.
    max_extrapolation : float
        Largest scaling beyond the highest velocity level.

    Raises
    ------
    ValueError
        Too many levels for one frame.
    """
    v = [float(x) for x in velocities_m_s]
    g = [float(x) for x in grips_N]
    body = (TABLE_BEGIN_STRUCT.pack(len(v), len(g), n_samples, fs_hz, gain, max_extrapolation)
            + struct.pack(f"<{len(v) + len(g)}f", *v, *g))
    if len(body) > MAX_PAYLOAD:
        raise ValueError(f"transient table has too many levels ({len(v)} velocities, {len(g)} grips) for one frame")
    return body


def decode_table_begin(payload: bytes) -> tuple[list[float], list[float], int, float, float, float]:
    """Return ``(velocities_m_s, grips_N, n_samples, fs_hz, gain, max_extrapolation)``."""
    if len(payload) < TABLE_BEGIN_STRUCT.size:
        raise ProtocolError("TABLE_BEGIN payload too short")
    n_v, n_g, n_s, fs, gain, max_extra = TABLE_BEGIN_STRUCT.unpack_from(payload)
    rest = payload[TABLE_BEGIN_STRUCT.size:]
    if len(rest) != 4 * (n_v + n_g) or n_v < 1 or n_g < 1:
        raise ProtocolError(f"TABLE_BEGIN declares {n_v} velocities and {n_g} grips but carries {len(rest)} bytes")
    levels = struct.unpack(f"<{n_v + n_g}f", rest)
    return list(levels[:n_v]), list(levels[n_v:]), n_s, fs, gain, max_extra


def encode_data_chunk(offset: int, samples) -> bytes:
    """TABLE_DATA / REARM_DATA payload: ``offset`` (samples) and up to ``TABLE_CHUNK_SAMPLES`` float32 samples (A)."""
    samples = list(samples)
    if len(samples) > TABLE_CHUNK_SAMPLES:
        raise ValueError(f"at most {TABLE_CHUNK_SAMPLES} samples per data frame")
    return DATA_OFFSET_STRUCT.pack(offset) + struct.pack(f"<{len(samples)}f", *samples)


def decode_data_chunk(payload: bytes) -> tuple[int, tuple[float, ...]]:
    """``(offset, samples)`` of a TABLE_DATA / REARM_DATA payload; ProtocolError if malformed."""
    if len(payload) < 4 or (len(payload) - 4) % 4:
        raise ProtocolError(f"data chunk payload of {len(payload)} bytes is not offset + float32 samples")
    (offset,) = DATA_OFFSET_STRUCT.unpack_from(payload)
    n = (len(payload) - 4) // 4
    return offset, struct.unpack_from(f"<{n}f", payload, 4)


def describe_nak(payload: bytes) -> str:
    """A NAK payload as one line for people: which request was refused, why, and the device's text."""
    if len(payload) < NAK_STRUCT.size:
        return "NAK (malformed)"
    t, s, code = NAK_STRUCT.unpack_from(payload)
    text = payload[NAK_STRUCT.size:].decode("ascii", "replace")
    name = TYPE_NAMES.get(t, f"0x{t:02x}")
    return f"device refused {name} (seq {s}): {NAK_NAMES.get(code, f'error {code}')}" + (f": {text}" if text else "")
