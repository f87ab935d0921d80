"""The apparatus in its own process, so the servo loop never shares an interpreter lock with UI or audio.

CPython hands its GIL between threads every ``sys.getswitchinterval()``
(5 ms): in one process, the web UI's handler threads and the PortAudio
callback (Python code) would delay a 10 kHz servo loop by up to milliseconds.
With ``--servo-process on`` (the default for hardware) the device, the servo
loops and the homing controller live in a child process started with the
"spawn" method; the runner talks to it through a pipe:

* every :class:`study.session.apparatus.Apparatus` call becomes a request/response
  (results, including the full-rate log, are pickled back);
* ``hold(until)``: the parent evaluates ``until()`` (UI state) every 20 ms and
  sets a shared event; the child's homing loop checks the event;
* ``tap_window(on_clip)``: the child puts a message on a queue at each
  saturation and the parent plays the low tone as it arrives.

The child zeroes and closes the device on every exit path (the Device base
class guarantees it); SIGTERM and SIGHUP stop it the same way
(plumbing.stopsignals). If the parent dies, the kernel sends the child SIGTERM
(Linux ``PR_SET_PDEATHSIG``); wherever that is missing or failed, the child
also polls ``os.getppid()`` (:class:`plumbing.stopsignals.ParentWatch`, as the
renderer's and the demo's servo children do) in every homing, hold and tapping
loop and between requests, and stops the same way (zero output, device closed,
exit status 143); between requests it also sees the pipe close and exits. With a hardware
device the child keeps homing between requests, so the device is commanded
every tick for the whole session (a streaming device's watchdog would
otherwise zero it in the gaps while the parent writes data).
"""

from __future__ import annotations

import os
import queue
import signal
from dataclasses import asdict

from devices import make_device
from plumbing import rtpolicy
from plumbing.lsl import ServoStream, linger, open_publisher
from plumbing.stopsignals import ParentWatch, Terminated
from renderer.process import SPAWN, servo_child, servo_process, shared_sync

from .apparatus import ServoStopped
from .apparatus3 import make_apparatus
from .rater import REFERENCE_SAMPLE, tap_features


def _child(conn, clip_q, hold_event, spec: str, device_options: dict, catalog, protocol, library_dir,
           sim_participant, realtime, parent_pid, core=None, lsl=None) -> None:
    # Ctrl-C: the parent decides (there it closes the pipe); SIGTERM (also on the parent's death) and SIGHUP raise
    # Terminated: _serve's finally zeroes and closes (renderer.process.servo_child)
    with servo_child(parent_pid):
        _serve(conn, clip_q, hold_event, spec, device_options, catalog, protocol, library_dir, sim_participant,
               realtime, parent_pid, core, lsl)


#: the servo process asks the OS for its parent once every this many loop stop checks (homing: every 200
#: ticks, so every 80 ms at 10 kHz, 0.8 s at 1 kHz; a tapping window: every 16-64 ticks)
PARENT_CHECK_EVERY = 4


def _serve(conn, clip_q, hold_event, spec: str, device_options: dict, catalog, protocol, library_dir,
           sim_participant, realtime, parent_pid: int, core=None, lsl=None) -> None:
    device = None
    policy = None
    try:
        device = make_device(spec, **device_options)
        device.open()
        if realtime is True or (realtime is None and not device.info.simulated):
            # paced for the whole session (homing between requests too): SCHED_FIFO, mlockall, its own core
            # (plumbing.rtpolicy; the loops sleep to their deadlines, so RT throttling is never reached)
            policy = rtpolicy.acquire(core=core)
        else:  # a simulation run as fast as possible: under SCHED_FIFO it would hit RT throttling
            policy = rtpolicy.describe_current()
        app = make_apparatus(device, catalog, protocol, library_dir=library_dir, sim_participant=sim_participant,
                        realtime=realtime)
        parent_gone = ParentWatch(parent_pid, every=PARENT_CHECK_EVERY)

        def check_parent() -> bool:
            # where PR_SET_PDEATHSIG is missing or failed: stop as its SIGTERM would (the loops zero the output)
            if parent_gone():
                raise Terminated(signal.SIGTERM)
            return False

        app.stop_check = check_parent
        if lsl is not None:   # the servo's streams live here, beside the loop (plumbing.lsl); the runner has the markers
            publisher, _ = open_publisher(*lsl, streams=("state", "contacts"))
            app.monitor = ServoStream(publisher, app.fs_hz) if publisher is not None else None

        conn.send(("ok", {"real_saturation_detection": app.real_saturation_detection, "device_info": asdict(device.info),
                          "simulated_hand": app.simulated_hand, "is_sim": app.is_sim, "fs_hz": app.fs_hz,
                          "servo_policy": policy}))
        while True:
            if not app.is_sim:
                # a streaming device must be commanded every tick (its watchdog zeroes it otherwise): keep homing
                # while the parent writes data, updates the views or waits for the next request
                while not conn.poll(0):
                    check_parent()
                    app._home(0.02, zero_at_end=False)
            try:
                method, args = conn.recv()
            except EOFError:
                break
            if method == "close":
                conn.send(("ok", None))
                break
            try:
                if method == "tap_window":
                    result = app.tap_window(*args, on_clip=lambda: clip_q.put_nowait(1))
                elif method == "hold":
                    result = app.hold(until=hold_event.is_set, max_s=args[0])
                else:
                    result = getattr(app, method)(*args)
                conn.send(("ok", result))
            except Exception as exc:  # report and keep serving; the parent decides whether to stop
                conn.send(("error", (type(exc).__name__, str(exc))))
    except Exception as exc:
        try:
            conn.send(("error", (type(exc).__name__, str(exc))))
        except Exception:
            pass
    finally:
        if device is not None:
            device.close()
        conn.close()
        linger()   # the streams' last samples leave before the process ends (plumbing.lsl; zero output is above)


class IsolatedApparatus:
    """Same interface as :class:`study.session.apparatus.Apparatus`, backed by a child process (see module doc).

    Create it in a thread that outlives it (the main thread): on Linux the child is sent SIGTERM when
    the thread that started it ends (``PR_SET_PDEATHSIG``, plumbing.stopsignals)."""

    def __init__(self, spec: str, device_options: dict, catalog, protocol, library_dir=None,
                 sim_participant=None, realtime=None, lsl=None) -> None:
        # paced: hardware, or a simulation paced to the clock (as the child decides with the device's info)
        paced = realtime is True or (realtime is None and spec.split(":", 1)[0] != "sim")
        core = rtpolicy.servo_core() if paced else None
        # the rest of the program (UI, audio, disk) keeps off the servo's core until close()
        self._avoid = rtpolicy.avoid_core(core)
        self._avoid.__enter__()
        try:
            self._start(spec, device_options, catalog, protocol, library_dir, sim_participant, realtime, core, lsl)
        except BaseException:
            self._avoid.__exit__(None, None, None)
            raise

    def _start(self, spec, device_options, catalog, protocol, library_dir, sim_participant, realtime, core,
               lsl=None) -> None:
        """Start the servo child and take its first answer (what the device and the OS granted)."""
        self._clip_q = shared_sync(SPAWN.Queue)
        self._hold = shared_sync(SPAWN.Event)
        self._proc, self._conn, child_conn = servo_process(
            _child, (self._clip_q, self._hold, spec, device_options, catalog, protocol, library_dir, sim_participant,
                     realtime, os.getpid(), core, lsl), "study-servo", duplex=True)
        self._proc.start()
        child_conn.close()
        info = self._recv()
        self.real_saturation_detection = info["real_saturation_detection"]
        self.simulated_hand = info["simulated_hand"]
        self.is_sim = info["is_sim"]
        self.fs_hz = info["fs_hz"]
        self.device_info = info["device_info"]
        self.servo_policy = info.get("servo_policy")
        rtpolicy.warn_once(self.servo_policy)
        self.window_timing: list = []  # each tapping window's timing verdict and figures (study.session.servo_timing)
        self.sim_participant = sim_participant
        self.reference = None
        self._pending = False

    def _recv(self, on_wait=None):
        while not self._conn.poll(0.02):
            if not self._proc.is_alive():
                self._child_ended()
            if on_wait is not None:
                on_wait()
        status, payload = self._conn.recv()
        if status != "ok":
            self._raise(payload)
        return payload

    @staticmethod
    def _raise(payload) -> None:
        """Raise the child's error ``(kind, message)`` as the command reports it."""
        kind, message = payload
        # user errors keep their type so the command reports them as such (exit code 2)
        if kind in ("ValueError", "FileNotFoundError"):
            raise {"ValueError": ValueError, "FileNotFoundError": FileNotFoundError}[kind](message)
        if kind == "DeviceError":
            raise ValueError(f"device: {message}")
        if kind == "ServoStopped":
            raise ServoStopped(message)
        raise RuntimeError(f"servo process: {kind}: {message}")

    def _call(self, method: str, *args, on_wait=None):
        try:
            self._conn.send((method, args))
        except OSError:  # BrokenPipeError: the child stopped between requests (its homing stopped itself)
            self._child_ended()
        self._pending = True
        result = self._recv(on_wait)
        self._pending = False
        return result

    def _child_ended(self) -> None:
        """The servo process ended on its own: raise the error it sent before it closed the pipe (a homing
        stop between requests is a ServoStopped, exit 4), else a ServoStopped naming its exit code. Before,
        the parent's next request failed with a BrokenPipeError, which ended the command with exit 1 and
        no message."""
        try:
            if self._conn.poll(0):
                status, payload = self._conn.recv()
                if status != "ok":
                    self._raise(payload)
        except (OSError, EOFError):
            pass
        self._proc.join(timeout=10)
        raise ServoStopped(f"the servo process ended (exit code {self._proc.exitcode}); output zeroed")

    def link_status(self) -> str:
        """The device link's health line, from the servo process (see ``Apparatus.link_status``)."""
        return self._call("link_status")

    def now_s(self) -> float:
        """Device time (s), from the servo process."""
        return self._call("now_s")

    def set_sample(self, name: str) -> None:
        """Select the sample in the servo process (see ``Apparatus.set_sample``)."""
        self._call("set_sample", name)

    def add_sample(self, sample) -> None:
        """Make a catalog sample's servo loop in the servo process (see ``Apparatus.add_sample``)."""
        self._call("add_sample", sample)

    def drop_sample(self, name: str) -> None:
        """Release a sample's servo loop in the servo process (see ``Apparatus.drop_sample``)."""
        self._call("drop_sample", name)

    def wait_streams(self, timeout_s: float) -> bool:
        """Wait for consumers of the servo process's streams (see ``Apparatus.wait_streams``)."""
        return self._call("wait_streams", timeout_s)

    def close_streams(self) -> dict | None:
        """Stop the servo process's Lab Streaming Layer streams (see ``Apparatus.close_streams``)."""
        return self._call("close_streams")

    def start_hand(self, plan, window_s: float) -> None:
        """Start the simulated hand's plan for a window of ``window_s`` s (servo process)."""
        self._call("start_hand", plan, window_s)

    def home(self, max_s: float) -> None:
        """Pre-trial homing in the servo process (at most ``max_s`` s)."""
        self._call("home", max_s)

    def after_window(self, duration_s: float) -> int:
        """Post-window homing for ``duration_s`` s; returns the surface contacts (overpowering)."""
        return self._call("after_window", duration_s)

    def hold(self, until, max_s: float = 24 * 3600.0) -> int:
        """Hold home until ``until()`` (polled here, signalled to the servo process); returns contacts."""
        self._hold.clear()

        def check():
            if until():
                self._hold.set()

        return self._call("hold", max_s, on_wait=check)

    def tap_window(self, window_s: float, first_tap_timeout_s: float, on_clip=None):
        """The tapping window in the servo process; clip notices reach ``on_clip`` here as they happen."""
        def drain():
            while True:
                try:
                    self._clip_q.get_nowait()
                except queue.Empty:
                    return
                if on_clip is not None:
                    on_clip()

        result = self._call("tap_window", window_s, first_tap_timeout_s, on_wait=drain)
        drain()
        tm = getattr(result, "timing", None) or {}
        if "timing_verdict" in tm:
            self.window_timing.append({"verdict": tm["timing_verdict"],
                                       **{k: tm.get(k, 0.0) for k in ("period_error_p99_us", "period_error_p999_us",
                                                                      "period_max_us")}})
        return result

    def features(self, tap):
        """The rater's features of a tap window, computed here from the returned log."""
        return tap_features(tap.log["t_s"], tap.log["accel_m_s2"], [e.t_s for e in tap.events], tap.fs_hz)

    def record_reference(self, reference_sample: str = REFERENCE_SAMPLE):
        """Record the rater's reference taps in the servo process; returns and keeps the reference."""
        self.reference = self._call("record_reference", reference_sample)
        return self.reference

    def close(self) -> None:
        """End the child: finish (or cut short, for a hold) its current call, then close the device there."""
        try:
            self._hold.set()  # an abort can leave the child holding home for the UI: release it
            if self._pending and self._proc.is_alive() and self._conn.poll(30.0):
                self._conn.recv()
            self._pending = False
            if self._proc.is_alive():
                self._call("close")
        except (RuntimeError, OSError, EOFError):
            pass
        finally:
            self._proc.join(timeout=10)
            if self._proc.is_alive():  # last resort; the device's own watchdog must zero the output then
                self._proc.kill()
                self._proc.join(timeout=5)
            self._conn.close()
            self._avoid.__exit__(None, None, None)
