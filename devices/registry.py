"""Device strings: the one way every command selects a device.

``sim``                 simulated device, Table 3.1 parameters (nonlinear model)
``sim:lti``             simulated linear "Phantom-like" device
``sim:<params file>``   simulated device from a TOML/JSON parameter file
``serial:<port>``       hardware over a serial/CDC port (e.g. serial:/dev/ttyACM0)
``hid:<vid>:<pid>``     hardware over USB HID (hex ids, e.g. hid:16c0:0486)

Hardware strings take driver options after ``?`` (``&``-separated ``key=value``,
numbers converted), e.g. ``serial:/dev/pts/3?mode=on-device&timeout_s=0.05``.
"""

from __future__ import annotations

from .base import Device

DEVICE_KINDS = ("sim", "sim:lti", "sim:<params file>", "serial:<port>", "hid:<vid>:<pid>")


def make_device(spec: str, **options) -> Device:
    """Create (not open) the device named by ``spec``; see the module doc.

    Raises
    ------
    ValueError
        For an unknown or malformed device string, listing the valid forms.
    """
    kind, _, rest = spec.partition(":")
    if kind in ("serial", "hid") and "?" in rest:
        rest, query = rest.split("?", 1)
        options = {**_parse_options(spec, query), **options}
    if kind == "sim":
        from .sim import SimDevice

        return SimDevice.from_spec(rest or None, **options)
    if kind == "serial" and rest:
        from .serial_device import SerialDevice

        return SerialDevice(rest, **options)
    if kind == "hid" and rest.count(":") == 1:
        from .hid_device import HidDevice

        vid, pid = rest.split(":")
        try:
            return HidDevice(int(vid, 16), int(pid, 16), **options)
        except ValueError:
            pass
    raise ValueError(f"unknown device string {spec!r}; valid forms: {', '.join(DEVICE_KINDS)}")


def _parse_options(spec: str, query: str) -> dict:
    """``mode=on-device&timeout_s=0.05`` -> {"mode": "on-device", "timeout_s": 0.05}."""
    out: dict = {}
    for item in query.split("&"):
        if not item:
            continue
        key, eq, value = item.partition("=")
        if not eq or not key.isidentifier():
            raise ValueError(f"device string {spec!r}: option {item!r} is not key=value")
        for conv in (int, float):
            try:
                value = conv(value)
                break
            except ValueError:
                pass
        out[key] = value
    return out


def open_device(spec: str, **options) -> Device:
    """Create and open the device named by ``spec`` (use as a context manager)."""
    return make_device(spec, **options).open()
