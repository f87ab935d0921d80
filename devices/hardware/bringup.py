"""Calibrating a real board from the command line (``python -m devices calibrate``).

The steps are the driver's calibration API (:class:`devices.hardware.serial_device.SerialDevice`): with the
handle held still at a known height, the encoder zero (eq. 3.3); with the handle at rest and the grip not
held, the accelerometer and grip-sensor offsets; then the values are stored per device id in the JSON
calibration file the driver loads on open (``calibration=`` option or ``$HFAM_CALIBRATION``). The motor is
commanded zero throughout.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from plumbing.fileio import read_json_file


def existing_entry(path, device_id: str) -> bool:
    """Whether the calibration file ``path`` already holds an entry for ``device_id``."""
    p = Path(path)
    if not p.is_file():
        return False
    data = read_json_file(p, "calibration file")
    return isinstance(data, dict) and isinstance(data.get("devices"), dict) and device_id in data["devices"]


def mean_reading(dev, n: int) -> dict:
    """Mean and standard deviation of position (m), acceleration (m/s^2) and grip (N) over ``n`` reads at zero
    current (the calibration as it stands)."""
    rows = []
    for _ in range(n):
        s = dev.read()
        rows.append((s.position_m, s.accel_m_s2, s.grip_N))
        dev.command(0.0)
    a = np.asarray(rows, dtype=float)
    return {f"{k}_mean": float(m) for k, m in zip(("position_m", "accel_m_s2", "grip_N"), a.mean(axis=0))} | \
        {f"{k}_sd": float(m) for k, m in zip(("position_m", "accel_m_s2", "grip_N"), a.std(axis=0))}


def calibrate(dev, out, known_position_m: float = 0.0, samples: int = 200, accel: bool = True,
              grip: bool = True) -> dict:
    """Calibrate an opened serial device and store the result in ``out``.

    Parameters
    ----------
    dev : devices.hardware.serial_device.SerialDevice
        Opened; its handle held still at ``known_position_m`` (m above the wall height 0), the grip not held.
    out : path
        The calibration JSON file (other devices' entries are kept).
    known_position_m : float
        Where the handle is held (m, + up).
    samples : int
        Reads averaged per step (at the device's rate: 200 at 1 kHz = 0.2 s).
    accel, grip : bool
        Zero the accelerometer / grip-sensor offsets too.

    Returns
    -------
    dict
        ``device_id``, ``before`` and ``after`` (:func:`mean_reading`), ``calibration`` (the stored values),
        ``file``.
    """
    before = mean_reading(dev, samples)
    dev.calibrate_encoder_zero(known_position_m=known_position_m, n=samples)
    if accel or grip:
        dev.calibrate_sensor_offsets(n=samples, accel=accel, grip=grip)
    after = mean_reading(dev, samples)
    path = dev.save_calibration(out)
    entry = json.loads(Path(path).read_text(encoding="utf-8"))["devices"][dev.wire_info.device_id]
    return {"device_id": dev.wire_info.device_id, "before": before, "after": after, "calibration": entry,
            "file": str(path)}
