"""Haptic devices: the interface, the simulated device, hardware drivers, identification, models."""

import importlib

from .base import Device, DeviceError, DeviceInfo, DeviceState, Status
from .registry import DEVICE_KINDS, check_device_spec, make_device, open_device

__all__ = ["Device", "DeviceError", "DeviceInfo", "DeviceState", "Status", "DEVICE_KINDS", "check_device_spec", "make_device", "open_device",
           "load_model"]


def __getattr__(name):
    """``load_model`` (devices.model: a model JSON file, docs/models.md), loaded on first use (PEP 562): every
    ``python -m devices`` parser imports this package."""
    if name != "load_model":
        raise AttributeError(f"module 'devices' has no attribute {name!r}")
    value = importlib.import_module(".model", __name__).load_model
    globals()[name] = value
    return value
