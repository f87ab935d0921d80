"""Lab Streaming Layer (LSL): the device's state and the session's events as streams a lab records beside EEG,
EMG or motion capture (LabRecorder, or any LSL inlet), on one clock.

Three streams per publisher (``name`` and ``source_id`` from the command):

* ``<name> state`` -- the servo's log at a decimated rate (``rate_hz``, e.g. 1 kHz of a 10 kHz loop; a
  sample every ``servo rate / rate_hz`` ticks): :data:`STATE_CHANNELS` (position, velocity, force, current,
  handle acceleration, grip), double precision, with their units in the stream's description;
* ``<name> markers`` -- the session's events (attempt start, tap cue, question, answer, recorded) as JSON
  strings, at the moment they happen;
* ``<name> contacts`` -- every contact the servo detected (its time on the device's clock, incoming velocity,
  penetration, clipping) as JSON strings.

Time stamps are LSL's clock (``pylsl.local_clock``). The device's samples carry the device's clock; a sample at
device time ``t`` is stamped ``t + offset``, with ``offset`` = LSL time minus device time when its chunk is
published, never decreasing (a simulated device that runs ahead of the wall clock keeps the offset of its
first chunk), so every stream's time stamps are monotone. Each window's pair (device time, LSL time) is kept:
:meth:`LslPublisher.record` returns them for ``session.json`` (``lsl.clock_offsets``), so a trace file's
``t_s`` converts to the LSL recording's time.

Publishing never waits on the servo: the servo's callback puts a chunk into a bounded queue (``put_nowait``;
a full queue drops the chunk and counts it) and a thread pushes the queue into the outlets
(``benchmarks/bench_lsl.py`` measures the callback). Without pylsl (or its liblsl), :func:`open_publisher`
returns None and the reason, and the session runs without streams (one warning line).

A process keeps its closed outlets for :data:`LINGER_S` before it ends (:func:`linger`, also at exit): liblsl
sends from its own threads, and a process that ends at once loses what they had not sent yet (measured: a
session's last contacts and state samples, with two sessions' servo processes on two busy cores).

Loopback without multicast (tests, one computer): an ``lsl_api.cfg`` with ``KnownPeers = {127.0.0.1}`` and
``ResolveScope = machine`` under ``[multicast]``, named by the environment variable ``LSLAPICFG`` (liblsl's
configuration file).
"""

from __future__ import annotations

import atexit
import json
import queue
import threading
import time

import numpy as np

try:   # optional (the ``lsl`` extra): pylsl's wheel carries liblsl
    import pylsl
    LSL_MISSING = None
except (ImportError, OSError, RuntimeError) as exc:   # not installed, or its liblsl cannot load
    pylsl = None
    LSL_MISSING = f"{type(exc).__name__}: {exc}"

#: the state stream's channels: (servo log column(s), label, unit); force is the proportional plus the transient
STATE_CHANNELS = (("position_m", "position", "m"), ("velocity_m_s", "velocity", "m/s"),
                  ("force_prop_N+force_transient_N", "force", "N"), ("current_A", "current", "A"),
                  ("accel_m_s2", "acceleration", "m/s^2"), ("grip_N", "grip", "N"))
#: closed publishers' outlets, kept until the process ends (:meth:`LslPublisher.close`)
_RETIRED: list = []
#: how long (s) a process keeps its outlets after the last close before it may end (:func:`linger`)
LINGER_S = 1.0
#: ``time.monotonic()`` of the last :meth:`LslPublisher.close` in this process, or None
_closed_at: float | None = None   # time.monotonic() of this process's last close
#: the servo log's columns the state stream reads (its device time first)
LOG_COLUMNS = ("t_s", "position_m", "velocity_m_s", "force_prop_N", "force_transient_N", "current_A", "accel_m_s2",
               "grip_N")


class LslPublisher:
    """The three outlets and the thread that feeds them (module docstring).

    Parameters
    ----------
    name : str
        The streams' name prefix (e.g. ``"hfam study S01"``).
    source_id : str
        Their source id prefix (a recorder reconnects to the same source after a restart).
    rate_hz : float
        The state stream's nominal rate.
    queue_size : int
        Chunks held for the thread; beyond, chunks are dropped (counted), never waited for.
    streams : tuple of str
        The outlets this process makes (a session whose servo runs in its own process makes the state and
        contacts there, the markers in the runner).
    """

    def __init__(self, name: str, source_id: str, rate_hz: float, queue_size: int = 4096,
                 streams: tuple = ("state", "markers", "contacts")) -> None:
        self.name, self.source_id, self.rate_hz, self.streams = name, source_id, float(rate_hz), tuple(streams)
        self.outlets = {}
        if "state" in streams:
            self.outlets["state"] = self._state_outlet()
        for kind in ("markers", "contacts"):
            if kind in streams:
                info = pylsl.StreamInfo(f"{name} {kind}", "Markers", 1, pylsl.IRREGULAR_RATE, pylsl.cf_string,
                                        f"{source_id}-{kind}")
                self.outlets[kind] = pylsl.StreamOutlet(info)
        self.queue: queue.Queue = queue.Queue(maxsize=queue_size)
        self.offset: float | None = None
        self.clock_offsets: list = []
        self.dropped = self.samples = 0
        self.pushed = {"markers": 0, "contacts": 0}
        self._last = {"markers": -np.inf, "contacts": -np.inf}
        self._thread = threading.Thread(target=self._drain, name="lsl-publisher", daemon=True)
        self._thread.start()

    def _state_outlet(self):
        name, source_id = self.name, self.source_id
        state = pylsl.StreamInfo(f"{name} state", "Haptics", len(STATE_CHANNELS), self.rate_hz,
                                 pylsl.cf_double64, f"{source_id}-state")
        chans = state.desc().append_child("channels")
        for _, label, unit in STATE_CHANNELS:
            ch = chans.append_child("channel")
            ch.append_child_value("label", label)
            ch.append_child_value("unit", unit)
        return pylsl.StreamOutlet(state, chunk_size=0, max_buffered=60)

    @staticmethod
    def now() -> float:
        """LSL's clock (s)."""
        return pylsl.local_clock()

    def wait_for_consumers(self, timeout_s: float) -> bool:
        """Wait until every outlet has a consumer (a recorder or an inlet connected), at most ``timeout_s`` in all;
        True if they all have one."""
        deadline = pylsl.local_clock() + timeout_s
        return all(outlet.wait_for_consumers(max(0.0, deadline - pylsl.local_clock()))
                   for outlet in self.outlets.values())

    # -- the servo's side: never blocks ----------------------------------------------------------------------
    def device_chunk(self, t_device_s: np.ndarray, values: np.ndarray) -> None:
        """Queue the state samples ``values`` (shape (n, channels)) taken at device times ``t_device_s``."""
        if not len(t_device_s):
            return
        self.device_time(float(t_device_s[-1]))
        self._put(("state", values, t_device_s + self.offset))

    def device_time(self, t_device_s: float) -> float:
        """The device's clock now is ``t_device_s``: update the offset (never decreasing); returns it."""
        off = pylsl.local_clock() - t_device_s
        if self.offset is None or off > self.offset:
            self.offset = off
        return self.offset

    def servo_rows(self, loop, start: int, end: int, step: int, offset: float) -> None:
        """Queue the servo log's ticks ``start..end`` (every ``step``-th), read by the thread from the loop's ring
        (:meth:`ServoStream.__call__`: the servo only names them)."""
        self._put(("rows", (loop, start, end, step), offset))

    def contact(self, event: dict) -> None:
        """Queue a contact (``event["t_s"]``: its device time)."""
        t = event["t_s"] + self.offset if self.offset is not None else pylsl.local_clock()
        self._put(("contacts", json.dumps(event), t))

    def marker(self, event: dict) -> None:
        """Queue a session event, stamped now."""
        self._put(("markers", json.dumps(event), pylsl.local_clock()))

    def clock_pair(self, t_device_s: float) -> None:
        """Keep the pair (device time, LSL time) of a window's start (:meth:`record`)."""
        if self.offset is not None:
            self.clock_offsets.append([float(t_device_s), float(t_device_s) + self.offset])

    def _put(self, item) -> None:
        try:
            self.queue.put_nowait(item)
        except queue.Full:
            self.dropped += 1

    # -- the thread ------------------------------------------------------------------------------------------
    def settle(self, timeout_s: float = 2.0) -> bool:
        """Wait until the thread has pushed everything queued (before a loop's ring is written again: a new
        run); True if it has."""
        q = self.queue
        with q.all_tasks_done:
            return q.all_tasks_done.wait_for(lambda: q.unfinished_tasks == 0, timeout_s)

    def _drain(self) -> None:
        while True:
            item = self.queue.get()
            try:
                if item is None:
                    return
                self._push(*item)
            finally:
                self.queue.task_done()

    def _push(self, kind, data, ts) -> None:
        if kind == "rows":    # read the ring here, not in the servo's callback
            loop, start, end, step = data
            _, arr = loop.log_since(start, LOG_COLUMNS, step, end)
            if not arr.shape[1]:
                return
            kind, ts = "state", arr[0] + ts
            data = np.column_stack([arr[1], arr[2], arr[3] + arr[4], arr[5], arr[6], arr[7]])
        if kind == "state":
            self.outlets["state"].push_chunk(np.ascontiguousarray(data, dtype=np.float64), ts.tolist())
            self.samples += len(ts)
            time.sleep(0)    # hand the GIL back to the servo's thread between chunks
        else:
            t = max(float(ts), self._last[kind])   # monotone within the stream
            self._last[kind] = t
            self.outlets[kind].push_sample([data], t)
            self.pushed[kind] += 1

    def close(self, timeout_s: float = 5.0) -> dict:
        """Push what is queued, stop the thread; returns :meth:`record`. The outlets stay open until the process
        ends: liblsl sends their last samples from its own threads, and an outlet destroyed at once loses
        what it had not sent yet (measured: the last attempt's markers of a simulated session)."""
        try:
            self.queue.put(None, timeout=timeout_s)
        except queue.Full:
            pass
        self._thread.join(timeout_s)
        global _closed_at
        _RETIRED.append(self.outlets)
        if _closed_at is None:
            atexit.register(linger)    # a process started by multiprocessing skips atexit: it calls linger itself
        _closed_at = time.monotonic()
        return self.record()

    def record(self) -> dict:
        """What ``session.json`` keeps: the streams, the clock pairs, the counts."""
        return {"streams": [{"name": f"{self.name} {k}", "source_id": f"{self.source_id}-{k}"}
                            for k in self.streams],
                "state_rate_hz": self.rate_hz, "channels": [{"label": lb, "unit": u} for _, lb, u in STATE_CHANNELS],
                "clock_offsets": self.clock_offsets, "clock_offsets_meaning": "[device time s, LSL time s]",
                "samples": self.samples, "markers": self.pushed["markers"], "contacts": self.pushed["contacts"],
                "dropped_chunks": self.dropped}


def linger() -> float:
    """Wait until :data:`LINGER_S` after this process's last :meth:`LslPublisher.close`, so that liblsl's threads
    send what the closed outlets still hold before the process ends; returns the time waited (s), 0 when no
    publisher closed or the time has passed."""
    if _closed_at is None:
        return 0.0
    wait_s = _closed_at + LINGER_S - time.monotonic()
    if wait_s > 0:
        time.sleep(wait_s)
    return max(0.0, wait_s)


def open_publisher(name: str, source_id: str, rate_hz: float,
                   streams: tuple = ("state", "markers", "contacts")) -> tuple[LslPublisher | None, str | None]:
    """``(publisher, None)``, or ``(None, reason)`` when LSL is unavailable (pylsl missing, or an outlet cannot
    be made)."""
    if pylsl is None:
        return None, f"pylsl is not installed or its liblsl cannot load ({LSL_MISSING}); install the lsl extra"
    try:
        return LslPublisher(name, source_id, rate_hz, streams=streams), None
    except Exception as exc:   # liblsl refused an outlet (no network interface, a bad lsl_api.cfg)
        return None, f"an LSL outlet could not be made ({type(exc).__name__}: {exc})"


class ServoStream:
    """The servo loop's callback that publishes its log and contacts (duck-typed: any loop with ``ticks``,
    ``events`` and ``log_since(tick, columns, step)``).

    Call :meth:`begin` before a run, the object itself from the loop's ``until`` callback (it returns False:
    it never stops the loop), and :meth:`flush` after the run (the last ticks)."""

    def __init__(self, publisher: LslPublisher, servo_rate_hz: float | None = None) -> None:
        self.publisher = publisher
        self.servo_rate_hz = servo_rate_hz
        self.step = 0
        self.tick = self.events = 0

    def begin(self, loop) -> None:
        """A run starts: from its first tick and first event (the servo's rate, if not given, is the loop's);
        the thread has first pushed what an earlier run of the same loop left queued (its ring is reused)."""
        self.publisher.settle()
        self.step = 0      # set at the first call: a loop knows its rate once it runs
        self.tick = self.events = 0

    def __call__(self, loop) -> bool:
        if not self.step:
            rate = self.servo_rate_hz or float(loop.fs_hz)
            self.step = max(1, int(round(rate / self.publisher.rate_hz)))
        n = loop.ticks
        if n > self.tick:
            offset = self.publisher.device_time(float(loop.time_s))
            if self.tick == 0:
                self.publisher.clock_pair(float(loop.time_s) - n / float(loop.fs_hz))
            self.publisher.servo_rows(loop, self.tick, n, self.step, offset)
            self.tick = n
        evs = loop.events
        while self.events < len(evs):
            e = evs[self.events]
            self.publisher.contact({"event": "contact", "t_s": float(e.t_s),
                                    "incoming_velocity_m_s": float(e.incoming_velocity_m_s),
                                    "max_penetration_m": float(e.max_penetration_m), "clipped": bool(e.clipped)})
            self.events += 1
        return False

    def flush(self, loop) -> None:
        """After the run: the ticks and contacts since the last call."""
        self(loop)
