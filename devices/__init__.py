"""Haptic devices: the interface, the simulated device, hardware drivers, identification, models."""

from plumbing.lazy import lazy_exports

from .base import Device, DeviceError, DeviceInfo, DeviceState, Status
from .registry import DEVICE_KINDS, check_device_spec, make_device, open_device

__all__ = ["Device", "DeviceError", "DeviceInfo", "DeviceState", "Status", "DEVICE_KINDS", "check_device_spec", "make_device", "open_device",
           "load_model"]

# ``load_model`` (devices.model: a model JSON file, docs/models.md) loads on first use: every ``python -m devices``
# parser imports this package
__getattr__, __dir__ = lazy_exports(__name__, {"load_model": "model"})
