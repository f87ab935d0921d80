"""The Haply Inverse3's serial protocol (USB CDC): pure codec, bytes in and out, no I/O.

Sources. The command codes are public in the vendor's C++ header ``Inverse3.h`` (Haply Robotics'
Hardware API, 2022: ``HC_DEVICE_WAKEUP = 0x0A``, ``HC_JOINT_TORQUES = 0x1A``, ``HC_JOINT_STATES = 0x1B``,
``HC_JOINT_ANGLES = 0x1C``, ``HC_END_EFFECTOR_FORCE = 0x2A``, ``HC_END_EFFECTOR_STATE = 0x2B``,
``HC_END_EFFECTOR_POSITION = 0x2C``, ``HC_TEMPERATURE_STATUS = 0xAA``, ``HC_CURRENT_STATUS = 0xAB``,
``HC_POWER_STATUS = 0xAC``, ``HC0_DEVICE_INFO_EXT = 0x0D`` with ``0xD1`` device id / ``0xD2`` firmware
version, ``HC0_CONFIG = 0x0E``) with its request/response structs (``EndEffectorForceRequest``:
``float force[3]``; ``EndEffectorStateResponse``: ``float position[3], velocity[3]``;
``DeviceInfoResponse``: ``uint16 device_id, uint8 model, uint8 hardware, uint8 firmware, UUID``). The
reply framing (which header byte answers which command, and how many bytes follow it) was read off the
vendor's compiled package ``HaplyHardwareAPI`` 0.1.13 (PyPI) by driving it against a pseudo-terminal: every
request is one command byte and its little-endian payload; every reply is one header byte and a fixed
number of payload bytes:

=======================  ======================  ==========================================
request                  reply header            reply payload (little endian)
=======================  ======================  ==========================================
0x0A wake-up             0x0B                    u16 device id, u8 model, u8 hardware version,
                                                 u8 firmware version, 16-byte UUID (21 bytes)
0x2A force f32[3] (N)    0x2B                    position f32[3] (m), velocity f32[3] (m/s)
0x2C position f32[3] (m) 0x2B                    as above
0x1A torques f32[3] (Nm) 0x1B                    joint angles f32[3], joint velocities f32[3]
0x1C angles f32[3]       0x1B                    as above
0xAA temperature         0xAA                    f32 (deg C)
0xAB motor currents      0xAB                    f32[3] (A)
0xAC power               0xAC                    u8 (1: powered)
0x0D 0xD1 device id      0x0D 0xD1               u8 16, 16-byte UUID
0x0D 0xD2 firmware       0x0D 0xD2               u8 16, 16-byte UUID
=======================  ======================  ==========================================

A reply with an unexpected header makes the vendor library drain its input; this codec's
:class:`ReplyParser` instead skips bytes until a known header with a whole payload is there, and counts
what it skipped (a host then waits for the next reply; see :mod:`devices.hardware.haply.driver`).
Positions and velocities are the end effector's, in the device's base frame (the Inverse3 reports
Cartesian state itself: no kinematics on the host), metres; forces in newtons.
"""

from __future__ import annotations

import math
import struct
import uuid
from dataclasses import dataclass

WAKEUP = 0x0A
WAKEUP_REPLY = 0x0B
JOINT_TORQUES = 0x1A
JOINT_STATES = 0x1B
JOINT_ANGLES = 0x1C
EE_FORCE = 0x2A
EE_STATE = 0x2B
EE_POSITION = 0x2C
DEVICE_INFO_EXT = 0x0D
INFO_EXT_DEVICE_ID = 0xD1
INFO_EXT_FIRMWARE = 0xD2
CONFIG = 0x0E
TEMPERATURE = 0xAA
CURRENTS = 0xAB
POWER = 0xAC

VEC3 = struct.Struct("<3f")
STATE6 = struct.Struct("<6f")
WAKEUP_STRUCT = struct.Struct("<HBBB16s")
F32 = struct.Struct("<f")

#: bytes after the header byte of each reply (the header byte itself not counted)
REPLY_SIZES = {WAKEUP_REPLY: WAKEUP_STRUCT.size, EE_STATE: STATE6.size, JOINT_STATES: STATE6.size,
               TEMPERATURE: F32.size, CURRENTS: VEC3.size, POWER: 1}
#: two-byte replies (0x0D, sub-code): bytes after the two header bytes
EXT_REPLY_SIZE = 17


class ProtocolError(ValueError):
    """A payload that does not decode (wrong size, a NaN where a number must be)."""


@dataclass(frozen=True)
class WakeupInfo:
    """The wake-up reply."""

    device_id: int
    model: int
    hardware_version: int
    firmware_version: int
    uuid: uuid.UUID


def _finite3(x, y, z, what: str) -> bytes:
    for v in (x, y, z):
        if not math.isfinite(v):
            raise ProtocolError(f"{what}: {v!r} is not a finite number")
    return VEC3.pack(x, y, z)


def encode_wakeup() -> bytes:
    """The wake-up request: the single byte 0x0A."""
    return bytes((WAKEUP,))


def encode_force(fx: float, fy: float, fz: float) -> bytes:
    """End-effector force request: 0x2A, then 3 little-endian float32 (N). A non-finite value is refused
    (ProtocolError): the driver zeroes it before it gets here, so NaN never reaches the wire."""
    return bytes((EE_FORCE,)) + _finite3(fx, fy, fz, "force")


def encode_position(x: float, y: float, z: float) -> bytes:
    """End-effector position request (the device's own position controller): 0x2C + 3 float32 (m)."""
    return bytes((EE_POSITION,)) + _finite3(x, y, z, "position")


def encode_query(code: int) -> bytes:
    """A status query with no payload: temperature 0xAA, motor currents 0xAB, power 0xAC."""
    if code not in (TEMPERATURE, CURRENTS, POWER):
        raise ValueError(f"not a status query: 0x{code:02X}")
    return bytes((code,))


def encode_info_ext(sub: int) -> bytes:
    """Device id (0xD1) or firmware version (0xD2) query: 0x0D then the sub-code."""
    if sub not in (INFO_EXT_DEVICE_ID, INFO_EXT_FIRMWARE):
        raise ValueError(f"not an info query: 0x{sub:02X}")
    return bytes((DEVICE_INFO_EXT, sub))


def encode_wakeup_reply(info: WakeupInfo) -> bytes:
    """What a device answers to the wake-up (0x0B + 21 bytes)."""
    return bytes((WAKEUP_REPLY,)) + WAKEUP_STRUCT.pack(info.device_id, info.model, info.hardware_version,
                                                        info.firmware_version, info.uuid.bytes)


def decode_wakeup_reply(payload: bytes) -> WakeupInfo:
    """The 21 bytes after 0x0B."""
    if len(payload) != WAKEUP_STRUCT.size:
        raise ProtocolError(f"wake-up reply: {len(payload)} bytes, expected {WAKEUP_STRUCT.size}")
    dev_id, model, hw, fw, raw = WAKEUP_STRUCT.unpack(payload)
    return WakeupInfo(dev_id, model, hw, fw, uuid.UUID(bytes=raw))


def encode_state(position, velocity, header: int = EE_STATE) -> bytes:
    """A state reply: ``header`` (0x2B Cartesian, 0x1B joints) + 6 float32."""
    return bytes((header,)) + STATE6.pack(*position, *velocity)


def decode_state(payload: bytes) -> tuple[tuple, tuple]:
    """``(position, velocity)`` from the 24 bytes after 0x2B (or 0x1B); ProtocolError if not 24 bytes."""
    if len(payload) != STATE6.size:
        raise ProtocolError(f"state reply: {len(payload)} bytes, expected {STATE6.size}")
    v = STATE6.unpack(payload)
    return v[:3], v[3:]


def encode_info_ext_reply(sub: int, value: uuid.UUID) -> bytes:
    """The answer to 0x0D ``sub``: 0x0D, sub, 16 (the UUID's length), the UUID's 16 bytes."""
    return bytes((DEVICE_INFO_EXT, sub, 16)) + value.bytes


class ReplyParser:
    """Splits the device's byte stream into replies ``(header, payload)``; resynchronises on garbage.

    ``feed(data)`` returns the complete replies found; bytes that start no known reply are skipped one
    at a time and counted in ``garbage_bytes``.
    """

    def __init__(self) -> None:
        self.buf = bytearray()
        self.garbage_bytes = 0

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        """Append ``data``; return the whole replies now available, in order."""
        buf = self.buf
        buf += data
        out = []
        while buf:
            head = buf[0]
            if head == DEVICE_INFO_EXT:
                if len(buf) < 2:
                    break
                if buf[1] not in (INFO_EXT_DEVICE_ID, INFO_EXT_FIRMWARE):
                    del buf[0]
                    self.garbage_bytes += 1
                    continue
                if len(buf) < 2 + EXT_REPLY_SIZE:
                    break
                out.append((DEVICE_INFO_EXT, bytes(buf[1:2 + EXT_REPLY_SIZE])))
                del buf[:2 + EXT_REPLY_SIZE]
                continue
            n = REPLY_SIZES.get(head)
            if n is None:
                del buf[0]
                self.garbage_bytes += 1
                continue
            if len(buf) < 1 + n:
                break
            out.append((head, bytes(buf[1:1 + n])))
            del buf[:1 + n]
        return out

    def pending(self) -> int:
        """Bytes held back waiting for the rest of a reply."""
        return len(self.buf)

    def reset(self) -> None:
        """Forget a partial reply (its rest may never come)."""
        self.garbage_bytes += len(self.buf)
        self.buf.clear()


class RequestParser:
    """The device side: splits the host's byte stream into requests ``(code, payload)`` (for the emulator)."""

    SIZES = {WAKEUP: 0, EE_FORCE: 12, EE_POSITION: 12, JOINT_TORQUES: 12, JOINT_ANGLES: 12,
             TEMPERATURE: 0, CURRENTS: 0, POWER: 0, DEVICE_INFO_EXT: 1}

    def __init__(self) -> None:
        self.buf = bytearray()
        self.garbage_bytes = 0

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        """Append ``data``; return the whole requests now available."""
        buf = self.buf
        buf += data
        out = []
        while buf:
            n = self.SIZES.get(buf[0])
            if n is None:
                del buf[0]
                self.garbage_bytes += 1
                continue
            if len(buf) < 1 + n:
                break
            out.append((buf[0], bytes(buf[1:1 + n])))
            del buf[:1 + n]
        return out
