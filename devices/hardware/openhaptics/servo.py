"""The Touch's servo callback, compiled by numba: it runs in OpenHaptics' 1 kHz scheduler thread and touches
no Python object, so nothing in the Python process (the GIL, a garbage collection, a slow tick of the
servo loop) can stall it.

A callback that is a Python function (as pyOpenHaptics' ``hd_callback``) must take the GIL on every tick:
when another Python thread holds it, the scheduler thread waits (up to the interpreter's switch interval,
5 ms by default, or longer), and the device's servo misses its 1 ms. A test measures both against a fake
HD library (tests/devices/hardware/contract/test_touch_fake_hd.py).

Shared block (float64[BLOCK], its address is the callback's user data; the host thread reads and writes
it with plain loads and stores):

====  =============================================================================
0-2   position (mm, HD frame: x right, y up, z towards the user), written each tick
3-5   velocity (mm/s), written each tick
6     buttons (bit mask), written each tick
7     tick counter (+1 per callback)
8-10  force command (N, HD frame), written by the host
11    command sequence number, incremented by the host after writing 8-10
12    last sequence seen by the callback
13    ticks since the command sequence last changed
14    watchdog (ticks; 0: off): that many ticks without a new command -> zero force
15    1 while the watchdog holds the force at zero
16    force magnitude limit (N): a larger command is scaled down to it, a NaN one zeroed
17    1: the callback returns HD_CALLBACK_DONE (unschedules itself)
18-20 (scratch) the force sent to the device this tick (N)
21    address of this block (float64, exact below 2^53)
22    address of the int32 buttons cell
====  =============================================================================
"""

from __future__ import annotations

import ctypes
import math

import numpy as np
from numba import carray, cfunc, types

from . import hdapi as A

BLOCK = 32


def compile_callback(hd: A.HD):
    """The numba ``cfunc`` (``HDCallbackCode (*)(void *)``) bound to this library's functions."""
    lib = hd.lib
    # pointer arguments as int64: the same register on the x86-64 and AArch64 calling conventions
    i64 = ctypes.c_int64
    get_dev = ctypes.CFUNCTYPE(A.HHD)(("hdGetCurrentDevice", lib))
    begin = ctypes.CFUNCTYPE(None, A.HHD)(("hdBeginFrame", lib))
    end = ctypes.CFUNCTYPE(None, A.HHD)(("hdEndFrame", lib))
    getd = ctypes.CFUNCTYPE(None, A.HDenum, i64)(("hdGetDoublev", lib))
    geti = ctypes.CFUNCTYPE(None, A.HDenum, i64)(("hdGetIntegerv", lib))
    setd = ctypes.CFUNCTYPE(None, A.HDenum, i64)(("hdSetDoublev", lib))
    POS, VEL, BTN, FORCE = A.HD_CURRENT_POSITION, A.HD_CURRENT_VELOCITY, A.HD_CURRENT_BUTTONS, A.HD_CURRENT_FORCE
    DONE, CONTINUE = A.HD_CALLBACK_DONE, A.HD_CALLBACK_CONTINUE

    @cfunc(types.uint32(types.voidptr), nopython=True, cache=False)
    def servo(user):
        b = carray(user, (BLOCK,), np.float64)
        base = np.int64(b[21])
        ibtn = np.int64(b[22])
        h = get_dev()
        begin(h)
        getd(POS, base)
        getd(VEL, base + 24)
        geti(BTN, ibtn)
        seq = b[11]
        if seq != b[12]:
            b[12] = seq
            b[13] = 0.0
        else:
            b[13] += 1.0
        fx, fy, fz = b[8], b[9], b[10]
        m2 = fx * fx + fy * fy + fz * fz
        lim = b[16]
        if (b[14] > 0.0 and b[13] >= b[14]) or not (m2 == m2) or m2 == math.inf:
            b[15] = 1.0 if b[14] > 0.0 and b[13] >= b[14] else b[15]
            fx = fy = fz = 0.0
        else:
            b[15] = 0.0
            if m2 > lim * lim:
                s = lim / math.sqrt(m2)
                fx *= s
                fy *= s
                fz *= s
        b[18], b[19], b[20] = fx, fy, fz
        setd(FORCE, base + 8 * 18)
        end(h)
        b[7] += 1.0
        if b[17] != 0.0:
            return DONE
        return CONTINUE

    return servo


def new_block(max_force_N: float, watchdog_ticks: int) -> tuple[np.ndarray, np.ndarray]:
    """The shared float64 block and its int32 buttons cell, addresses filled in."""
    block = np.zeros(BLOCK, dtype=np.float64)
    buttons = np.zeros(1, dtype=np.int32)
    block[16] = max_force_N
    block[14] = watchdog_ticks
    block[21] = float(block.ctypes.data)
    block[22] = float(buttons.ctypes.data)
    assert int(block[21]) == block.ctypes.data and int(block[22]) == buttons.ctypes.data
    return block, buttons
