"""ctypes bindings of the OpenHaptics HD API (libHD), as pyOpenHaptics binds them, loaded on request.

The constants and types are OpenHaptics' (``hdDefines.h``; the same values pyOpenHaptics 1.0.1 lists).
:func:`load` finds the library: ``$HFAM_OPENHAPTICS_LIB`` (a path), else ``libHD.so`` on the loader's
path (the vendor installer puts it in /usr/lib), and checks the version it reports (3.0 or newer).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
from dataclasses import dataclass

LIB_ENV = "HFAM_OPENHAPTICS_LIB"
MIN_VERSION = (3, 0)

HHD = ctypes.c_uint
HDenum = ctypes.c_uint
HDerror = ctypes.c_uint
HDCallbackCode = ctypes.c_uint
HDSchedulerHandle = ctypes.c_ulong
HD_CALLBACK_DONE, HD_CALLBACK_CONTINUE = 0, 1
HD_SUCCESS = 0x000
HD_INVALID_HANDLE = 0xFFFFFFFF
HD_CURRENT_BUTTONS = 0x2000
HD_CURRENT_POSITION = 0x2050
HD_CURRENT_VELOCITY = 0x2051
HD_VERSION = 0x2500
HD_DEVICE_MODEL_TYPE = 0x2501
HD_DEVICE_VENDOR = 0x2503
HD_NOMINAL_MAX_STIFFNESS = 0x2602
HD_NOMINAL_MAX_FORCE = 0x2603
HD_NOMINAL_MAX_CONTINUOUS_FORCE = 0x2604
HD_USABLE_WORKSPACE_DIMENSIONS = 0x2551
HD_CURRENT_FORCE = 0x2700
HD_FORCE_OUTPUT = 0x4000
HD_MAX_SCHEDULER_PRIORITY = (1 << 16) - 1
HD_DEFAULT_SCHEDULER_PRIORITY = HD_MAX_SCHEDULER_PRIORITY // 2
ERROR_NAMES = {0x0100: "HD_INVALID_ENUM", 0x0104: "HD_BAD_HANDLE", 0x0201: "HD_EXCEEDED_MAX_FORCE",
               0x0202: "HD_EXCEEDED_MAX_FORCE_IMPULSE", 0x0203: "HD_EXCEEDED_MAX_VELOCITY",
               0x0300: "HD_DEVICE_FAULT", 0x0302: "HD_COMM_ERROR", 0x0303: "HD_COMM_CONFIG_ERROR",
               0x0304: "HD_TIMER_ERROR", 0x0400: "HD_ILLEGAL_BEGIN", 0x0401: "HD_ILLEGAL_END"}


class HDErrorInfo(ctypes.Structure):
    """``HDErrorInfo`` (hdDefines.h)."""

    _fields_ = [("errorCode", HDerror), ("internalErrorCode", ctypes.c_int), ("hHD", HHD)]


class HDLibraryError(OSError):
    """libHD is missing, unloadable or too old (the text says which)."""


@dataclass
class HD:
    """The loaded library with its prototypes set (``lib``), and where it came from."""

    lib: ctypes.CDLL
    path: str
    version: str


def find() -> str | None:
    """The path :func:`load` would load, or None."""
    env = os.environ.get(LIB_ENV)
    if env:
        return env
    return ctypes.util.find_library("HD") or None


def load() -> HD:
    """Load libHD and declare the functions the driver uses (HDLibraryError otherwise)."""
    path = find()
    if not path:
        raise HDLibraryError("OpenHaptics (libHD) not found: install 3D Systems' OpenHaptics and the Touch device "
                             f"driver, or set ${LIB_ENV} to libHD.so")
    try:
        lib = ctypes.CDLL(path)
    except OSError as exc:
        raise HDLibraryError(f"OpenHaptics library {path} could not be loaded: {exc}") from None
    proto = {
        "hdInitDevice": (HHD, [ctypes.c_char_p]), "hdDisableDevice": (None, [HHD]),
        "hdMakeCurrentDevice": (None, [HHD]), "hdGetCurrentDevice": (HHD, []),
        "hdEnable": (None, [HDenum]), "hdDisable": (None, [HDenum]),
        "hdStartScheduler": (None, []), "hdStopScheduler": (None, []),
        "hdScheduleAsynchronous": (HDSchedulerHandle, [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_ushort]),
        "hdUnschedule": (None, [HDSchedulerHandle]),
        "hdGetError": (HDErrorInfo, []), "hdGetErrorString": (ctypes.c_char_p, [HDerror]),
        "hdGetString": (ctypes.c_char_p, [HDenum]),
        "hdGetDoublev": (None, [HDenum, ctypes.POINTER(ctypes.c_double)]),
        "hdGetIntegerv": (None, [HDenum, ctypes.POINTER(ctypes.c_int)]),
        "hdSetDoublev": (None, [HDenum, ctypes.POINTER(ctypes.c_double)]),
        "hdBeginFrame": (None, [HHD]), "hdEndFrame": (None, [HHD]),
    }
    for name, (restype, argtypes) in proto.items():
        try:
            fn = getattr(lib, name)
        except AttributeError:
            raise HDLibraryError(f"{path} is not OpenHaptics' HD library (no {name})") from None
        fn.restype, fn.argtypes = restype, argtypes
    raw = lib.hdGetString(HD_VERSION)
    version = raw.decode("ascii", "replace") if raw else "?"
    try:
        major_minor = tuple(int(p) for p in version.split(".")[:2])
    except ValueError:
        major_minor = (0, 0)
    if major_minor < MIN_VERSION:
        raise HDLibraryError(f"OpenHaptics {version} at {path} is too old: this driver needs "
                             f"{MIN_VERSION[0]}.{MIN_VERSION[1]} or newer")
    return HD(lib, path, version)


def error_text(hd: HD, info: HDErrorInfo) -> str:
    """A readable text for an HD error."""
    raw = hd.lib.hdGetErrorString(info.errorCode)
    text = raw.decode("ascii", "replace") if raw else ""
    return f"{ERROR_NAMES.get(info.errorCode, hex(info.errorCode))}{': ' + text if text else ''} " \
           f"(internal {info.internalErrorCode})"
