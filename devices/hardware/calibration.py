"""Raw-to-SI calibration a host uploads to a device (SET_CALIBRATION) and stores per device.

Used by the real drivers (:mod:`devices.hardware.serial_device`) and by the
firmware mirror (:mod:`devices.firmware.logic`), which imports it from here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from . import wire_protocol as P


@dataclass
class Calibration:
    """Raw-to-SI conversion the host uploads (SET_CALIBRATION) and stores per device.

    ``position_m = encoder_sign * (encoder - encoder_zero_counts) * position_resolution_m`` (eq. 3.3),
    ``accel_m_s2 = (accel_raw - accel_offset_counts) * accel_scale_m_s2_per_count``,
    ``grip_N = (grip_raw - grip_offset_counts) * grip_scale_N_per_count``.
    """

    encoder_zero_counts: int = 0
    encoder_sign: int = 1
    accel_scale_m_s2_per_count: float = 1.0
    accel_offset_counts: float = 0.0
    grip_scale_N_per_count: float = 1.0
    grip_offset_counts: float = 0.0

    def to_payload(self) -> bytes:
        """SET_CALIBRATION payload: encoder zero and sign, accelerometer and grip scale and offset."""
        return P.CALIBRATION_STRUCT.pack(int(self.encoder_zero_counts), int(self.encoder_sign),
                                         self.accel_scale_m_s2_per_count, self.accel_offset_counts,
                                         self.grip_scale_N_per_count, self.grip_offset_counts)

    @classmethod
    def from_payload(cls, payload: bytes) -> "Calibration":
        """Calibration from a SET_CALIBRATION payload; ProtocolError for a bad sign or a non-positive scale."""
        zero, sign, a_s, a_o, g_s, g_o = P._unpack(P.CALIBRATION_STRUCT, payload, "SET_CALIBRATION")
        if sign not in (-1, 1):
            raise P.ProtocolError(f"SET_CALIBRATION encoder_sign must be +1 or -1, got {sign}")
        for key, value in (("accel scale", a_s), ("grip scale", g_s)):
            if not (math.isfinite(value) and value > 0):
                raise P.ProtocolError(f"SET_CALIBRATION {key} must be positive and finite, got {value}")
        return cls(zero, sign, a_s, a_o, g_s, g_o)
