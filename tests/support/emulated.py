"""A firmware emulator over a real pty whose hand holds still, recording every current the host commands."""

import os
import threading
import time

from devices.firmware.emulator import EmulatorHandle, build_emulator
from devices.hardware import wire_protocol as P


def recording_emulator(hold_m: float, grip_N: float = 3.0):
    """A streaming emulator in a thread of this process; its prescribed hand holds the stylus at ``hold_m`` (m).

    Returns
    -------
    port : str
        The pty a host opens with ``serial:<port>``.
    handle : devices.firmware.emulator.EmulatorHandle
        ``handle.stop()`` ends it.
    sent : list of float
        Every CURRENT the host commanded (A), in order, appended as frames arrive.
    """
    emu = build_emulator("streaming", taps_m_s=())
    emu.set_hand(hold_m, grip_N=grip_N, hand="prescribed")
    sent = []
    pings = []
    handle_frame = emu.handle

    def recording(frame):
        if frame.type == P.CURRENT:
            sent.append(P.decode_current(frame.payload))
        elif frame.type == P.PING:
            pings.append(frame.payload)
        handle_frame(frame)

    emu.handle = recording
    port = emu.open_pty()
    stop = threading.Event()
    thread = threading.Thread(target=emu.serve, args=(stop,), name="hfam-emulator", daemon=True)
    thread.start()
    handle = EmulatorHandle(port, emu, thread, stop)
    handle.pings = pings   # PING payloads handled, for drain()
    return port, handle, sent


def drain(port: str, handle, timeout_s: float = 30.0) -> None:
    """Return once the emulator has handled every frame a host wrote to ``port`` before this call.

    A PING with a unique payload is written to the pty after them; the emulator reads the pty in order, so when it
    has handled that PING it has recorded every earlier frame. (Counting ``sent`` the moment a host exits races
    the emulator thread: on a loaded machine the host's last frames can still sit in the pty.)
    """
    token = os.urandom(4)
    fd = os.open(port, os.O_WRONLY | os.O_NOCTTY)
    try:
        os.write(fd, P.encode_frame(P.PING, 0, token))
    finally:
        os.close(fd)
    deadline = time.monotonic() + timeout_s
    while token not in handle.pings:
        if time.monotonic() > deadline:
            raise AssertionError(f"the emulator did not handle a PING within {timeout_s:g} s")
        time.sleep(0.005)
