"""A firmware emulator over a real pty whose hand holds still, recording every current the host commands."""

import threading

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
    handle_frame = emu.handle

    def recording(frame):
        if frame.type == P.CURRENT:
            sent.append(P.decode_current(frame.payload))
        handle_frame(frame)

    emu.handle = recording
    port = emu.open_pty()
    stop = threading.Event()
    thread = threading.Thread(target=emu.serve, args=(stop,), name="hfam-emulator", daemon=True)
    thread.start()
    return port, EmulatorHandle(port, emu, thread, stop), sent
