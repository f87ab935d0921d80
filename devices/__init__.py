"""Haptic devices: the interface, the simulated device, hardware drivers, identification, models."""

from .base import Device, DeviceError, DeviceInfo, DeviceState, Status
from .registry import DEVICE_KINDS, check_device_spec, make_device, open_device

__all__ = ["Device", "DeviceError", "DeviceInfo", "DeviceState", "Status", "DEVICE_KINDS", "check_device_spec", "make_device", "open_device",
           "load_model"]


def load_model(path):
    """Load a device model JSON file (see docs/models.md); lazy so ``import devices`` stays light."""
    from .model import load_model as _load  # deferred: keeps `import devices` light

    return _load(path)
