"""The Touch adapter against a fake OpenHaptics library (./fake_hd/fake_hd.c, compiled in the test): its servo
callback runs no Python, so a Python thread holding the GIL cannot stall the device's 1 kHz servo (measured);
a callback written in Python (as pyOpenHaptics' ``hd_callback``) is stalled by it."""

import ctypes
import sys
import time

import pytest

from devices.hardware.openhaptics import hdapi as A
from devices.hardware.openhaptics.servo import compile_callback, new_block

HOG_S = 0.3
SWITCH_S = 0.05


@pytest.fixture
def hd(fake_hd, monkeypatch):
    monkeypatch.setenv("HFAM_OPENHAPTICS_LIB", str(fake_hd))
    lib = A.load()
    lib.lib.hdInitDevice(b"Default Device")
    stats = ctypes.CDLL(str(fake_hd))
    yield lib, stats
    lib.lib.hdStopScheduler()
    lib.lib.hdDisableDevice(0)


def _hold_the_gil(seconds: float) -> int:
    """Pure-Python work that never releases the GIL by itself (only the interpreter's switch interval does)."""
    n = 0
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        n += 1
    return n


def _measure(hd, callback_address, user_address) -> tuple[float, float, float]:
    lib, stats = hd
    sched = lib.lib.hdScheduleAsynchronous(ctypes.c_void_p(callback_address), ctypes.c_void_p(user_address),
                                           A.HD_MAX_SCHEDULER_PRIORITY)
    lib.lib.hdStartScheduler()
    time.sleep(0.05)
    stats.fakehd_reset_stats()
    old = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_S)
    try:
        _hold_the_gil(HOG_S)
    finally:
        sys.setswitchinterval(old)
    out = (ctypes.c_double * 10)()
    stats.fakehd_stats(out)
    lib.lib.hdStopScheduler()
    lib.lib.hdUnschedule(sched)
    return out[1] * 1e-6, out[2] * 1e-6, out[3]   # max period (ms), max callback (ms), periods over 2 ms


def test_the_compiled_callback_keeps_the_servo_period_while_python_holds_the_gil(hd):
    lib, _ = hd
    cb = compile_callback(lib)
    block, buttons = new_block(3.3, 20)
    block[8:11] = (0.0, 0.2, 0.0)
    max_period_ms, max_cb_ms, slow = _measure(hd, cb.address, block.ctypes.data)
    assert block[7] > 100                     # it ran: ~300 ticks during the 0.3 s the GIL was held
    assert max_cb_ms < 1.0                    # no callback waited for anything (measured 1-7 us here)
    # the period itself also depends on the OS giving the scheduler thread a core (2 cores, one of them spinning
    # here: 3-9 ms seen), but never waits for the interpreter's switch interval
    assert max_period_ms < SWITCH_S * 1000, f"servo period reached {max_period_ms:.1f} ms"


def test_a_python_callback_is_stalled_by_a_python_thread_holding_the_gil(hd):
    lib, _ = hd
    L = lib.lib
    pos = (ctypes.c_double * 3)()
    force = (ctypes.c_double * 3)(0.0, 0.2, 0.0)

    @ctypes.CFUNCTYPE(ctypes.c_uint, ctypes.c_void_p)
    def py_callback(user):   # pyOpenHaptics' hd_callback: begin frame, the Python function, end frame
        h = L.hdGetCurrentDevice()
        L.hdBeginFrame(h)
        L.hdGetDoublev(A.HD_CURRENT_POSITION, pos)
        L.hdSetDoublev(A.HD_CURRENT_FORCE, force)
        L.hdEndFrame(h)
        return A.HD_CALLBACK_CONTINUE

    address = ctypes.cast(py_callback, ctypes.c_void_p).value
    max_period_ms, max_cb_ms, slow = _measure(hd, address, 0)
    # the scheduler thread waited for the GIL: its callback took about the switch interval, the period with it
    assert max_cb_ms > 0.6 * SWITCH_S * 1000 and max_period_ms > 0.6 * SWITCH_S * 1000 and slow >= 1
