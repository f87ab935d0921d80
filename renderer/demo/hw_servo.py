"""The hardware demo's servo process: the loop of one rendering's taps, and the shared ring the parent's scope reads.

A module of its own because the spawned child imports the module of its target: this one needs only the loop,
the device and the stop signals, not the parent's matplotlib, scipy.signal and metrics (~1.4 s of CPU per
rendering's process; :mod:`renderer.demo.hw_demo` is the parent side).
"""

from __future__ import annotations

import math

from devices.registry import make_device
from plumbing.stopsignals import ParentWatch

from ..loop import ServoLoop
from ..process import replying, servo_child

RING = 4096          # ticks kept in the shared scope ring
MAX_EVENTS = 256


def tap_child(conn, spec, cfg, transient, n_taps, post_s, timeout_s, ring, ring_n, events, stop,
              parent_pid) -> None:
    """Servo process: run the loop until the ``n_taps``-th contact's window (``post_s``) and 0.2 s more are over,
    ``timeout_s`` or ``stop``.

    Every tick's time, position and acceleration go into ``ring`` (``RING`` ticks of 3 doubles; ``ring_n`` ticks
    written so far), each contact's incoming velocity and grip into ``events`` (count first). SIGTERM/SIGHUP,
    and the parent's death, stop it with the output zeroed (renderer.process.servo_child)."""
    loop = None

    def failed(exc):
        return ("error", loop.result if loop is not None else None, f"{type(exc).__name__}: {exc}")

    with replying(conn, failed):
        with servo_child(parent_pid):
            dev = make_device(spec)
            with dev:
                loop = ServoLoop(dev, cfg, transient)
                state = dev.read()
                done_at = [math.inf]
                parent_gone = ParentWatch(parent_pid, every=1000)  # until runs every tick here

                def until(lp) -> bool:
                    k = ring_n.value
                    j = 3 * (k % RING)
                    ring[j] = state.t_s
                    ring[j + 1] = state.position_m
                    ring[j + 2] = state.accel_m_s2
                    ring_n.value = k + 1
                    ne = len(lp.events)
                    if ne and ne <= MAX_EVENTS and events[0] < ne:
                        ev = lp.events[ne - 1]
                        events[1 + 2 * (ne - 1)] = ev.incoming_velocity_m_s
                        events[2 + 2 * (ne - 1)] = ev.grip_N
                        events[0] = ne
                    if ne >= n_taps and done_at[0] == math.inf:
                        done_at[0] = lp.time_s + post_s + 0.2
                    return stop.is_set() or lp.time_s >= done_at[0] or parent_gone()

                result = loop.run(duration_s=timeout_s, until=until, realtime=None)
        conn.send(("ok", result, ""))
