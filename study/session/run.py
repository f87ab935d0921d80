"""One session, of any experiment kind, from the command line to its summary: the one path every kind runs.

In order: the views' socket is bound (before anything is written); the session is planned
(:func:`study.session.setup.plan_session`: subject, device, protocol, the experiment kind); the masking
audio is set up (required on hardware); a hardware session's servo timing is checked through its device
(:mod:`study.session.servo_timing`); the device, its servo loops and the homing start (in a servo process of
their own on hardware, :mod:`study.session.isolated`); the session's folder is created or resumed
(:func:`study.session.setup.start_session`) and the timing check recorded in it; the views start serving;
the attempt loop runs (:class:`study.session.loop.SessionLoop`) with the masking noise on; the session is
marked finished; the device is zeroed and closed; the views stop once the operator page has seen the end;
the kind prints its summary.

Ctrl-C, SIGTERM and SIGHUP end the session with the output zeroed and the data so far kept for ``--resume``
(exit 130, or 128 + the signal's number); an operator's abort exits 3, a servo that stopped itself 4, a
trials.csv changed under the runner 5.
"""

from __future__ import annotations

import sys
import threading
from dataclasses import asdict

from devices import DeviceError, make_device
from plumbing.lsl import ServoStream, open_publisher
from plumbing.progress import Progress
from plumbing.stopsignals import Terminated, stop_on_signals

from .apparatus import ServoStopped
from .apparatus3 import make_apparatus
from .audio import MaskingAudio, SilentAudio, check_output_device
from .isolated import IsolatedApparatus
from .loop import SessionLoop
from .participants import SimulatedParticipant, load_participant_config
from .servo_timing import merge_summaries, pre_session_check, window_summary
from .setup import plan_session, start_session
from .store import DataFileChanged, release_all_locks
from .uistate import Aborted, UiState
from .webui import WebUI


def run_session(args, kinds) -> int:
    """Run (or resume) one session of one of ``kinds``; the subject lock is released on every way out.

    Parameters
    ----------
    args : argparse.Namespace
        The ``run`` command's arguments.
    kinds : sequence of type or study.session.kind.KindAt
        The experiment kinds (:class:`study.session.kind.ExperimentKind` classes, or where they are); the
        protocol names the session's.

    Returns
    -------
    int
        The exit code (module docstring).
    """
    try:
        with stop_on_signals():
            return _run(args, kinds)
    finally:
        release_all_locks()


def _run(args, kinds) -> int:
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, flush=True))
    if getattr(args, "lsl", False) and not 0 < args.lsl_rate_hz <= 100_000:
        raise ValueError(f"--lsl-rate-hz must be in (0, 100000] Hz (the servo's rate at most), got {args.lsl_rate_hz}")
    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port must be 0..65535 (0: any free port), got {args.port}")
    plan = plan_session(args, kinds)
    # the views' socket is bound before anything is written: a busy port or an address this computer does not
    # have is refused here, with no subject folder made (a rerun on a free port then starts afresh)
    web = bind_views(args)
    try:
        return _session(args, plan, say, web)
    finally:
        if web is not None:
            web.stop()


def bind_views(args):
    """The views' server, bound to ``--host``/``--port`` but not serving yet; None when no view is served.

    Raises
    ------
    ValueError
        The address cannot be served (in use, not an address of this computer, unknown host name).
    """
    if not (args.participant == "keyboard" or args.serve):
        return None
    try:
        web = WebUI(UiState(), host=args.host, port=args.port, token=args.token)
    except OSError as exc:  # EADDRINUSE, EADDRNOTAVAIL, a host name that does not resolve
        raise ValueError(f"--host {args.host} --port {args.port}: cannot serve the views there "
                         f"({exc.strerror or exc}); nothing was written") from None
    return web


def masking_audio(args, plan, say) -> tuple[object, dict]:
    """The masking audio (required on hardware, silent in sim unless asked) and its record for session.json."""
    protocol, is_sim = plan.protocol, plan.is_sim
    want_audio = args.audio == "on" or (args.audio == "auto" and not is_sim)
    if want_audio:
        device_name = check_output_device(_audio_device(args.audio_device))
        audio = MaskingAudio(level_dbfs=protocol.masking_level_dbfs, fs_hz=protocol.audio_fs_hz,
                             seed=plan.seed, device=_audio_device(args.audio_device),
                             cue_level_db=protocol.cue_level_db, phrases=plan.kind.phrases)
        audio_info = {"output": device_name, "level_dbfs": protocol.masking_level_dbfs,
                      "cue_source": audio.cue_source, "cue_spoken": audio.cue_spoken,
                      "cue_level_db": protocol.cue_level_db}
        if not audio.cue_spoken:
            print(f"warning: the cues are chimes, not spoken: {audio.cue_source}", file=sys.stderr)
        return audio, audio_info
    audio = SilentAudio()
    if is_sim:
        say("note: sim session runs silently (no masking audio); use --audio on to play it")
    else:
        audio.cue_source = "none (--audio off: no masking, not valid for a blind study)"
        print("warning: --audio off: no masking noise or cues; the session is not blind to sound", file=sys.stderr)
    return audio, {"output": None, "level_dbfs": None, "cue_source": audio.cue_source, "cue_spoken": False,
                   "cue_level_db": None}


def _session(args, plan, say, web) -> int:
    """The session of ``plan`` (views on ``web`` if not None, started once the session's folder is open)."""
    store, previous, subject, is_sim = plan.store, plan.previous, plan.subject, plan.is_sim
    protocol, seed = plan.protocol, plan.seed
    audio, audio_info = masking_audio(args, plan, say)
    timing_rec = None
    if not is_sim:  # the servo's timing through this device, before any trial (study.session.servo_timing)
        say(f"checking the servo's timing through {args.device} ({protocol.timing_check_s:g} s, motor off) ...")
        timing_rec = pre_session_check(args.device, protocol, args.accept_timing)
        if timing_rec["accepted_override"]:
            print(f"warning: the servo timing check failed ({'; '.join(timing_rec['verdict']['failed'])}); "
                  "running anyway as --accept-timing asks (recorded in session.json)", file=sys.stderr)
    sim_participant = None
    if is_sim:
        pcfg = load_participant_config(args.participant_config if previous is None
                                       else previous.get("participant_config_file"))
        sim_participant = SimulatedParticipant(subject, plan.info.experience, seed, pcfg)
    isolate = args.servo_process == "on" or (args.servo_process == "auto" and not is_sim)
    device_options = {"seed": seed} if is_sim else {}
    device = apparatus = None
    markers, lsl = None, None
    if getattr(args, "lsl", False):   # Lab Streaming Layer (plumbing.lsl): the runner's markers here, the servo's
        lsl = (f"hfam study {subject}", f"hfam-study-{subject}", args.lsl_rate_hz)   # streams beside the servo
        markers, why = open_publisher(*lsl, streams=("markers",) if isolate else ("state", "markers", "contacts"))
        if markers is None:
            print(f"warning: --lsl: the session runs without Lab Streaming Layer streams: {why}", file=sys.stderr)
            lsl = None
    if isolate:
        apparatus = IsolatedApparatus(args.device, device_options, plan.catalog, protocol, plan.library_dir,
                                      sim_participant, realtime=True if args.realtime else None, lsl=lsl)
        device_info = apparatus.device_info
    else:
        try:
            device = make_device(args.device, **device_options)
            device.open()
        except DeviceError as exc:
            raise ValueError(f"device {args.device}: {exc}") from None
        device_info = asdict(device.info)
    plan.device_info = device_info
    try:
        if apparatus is None:
            apparatus = make_apparatus(device, plan.catalog, protocol, library_dir=plan.library_dir,
                                  sim_participant=sim_participant, realtime=True if args.realtime else None)
            if markers is not None:
                apparatus.monitor = ServoStream(markers, apparatus.fs_hz)
        participant = sim_participant if args.participant == "simulated" else KeyboardParticipant()
        kind = plan.kind(plan, apparatus)
        rows, events = start_session(plan, args, kind, device_info, isolate, sim_participant, audio_info,
                                     apparatus.real_saturation_detection)
        record_timing(store, timing_rec, getattr(apparatus, "servo_policy", None), previous is not None)
        ui = None
        if web is not None:
            ui = web.ui
            web.start()
            print(f"subject view:  {web.subject_url}", flush=True)
            print(f"operator view: {web.operator_url}", flush=True)
            if args.participant == "keyboard":
                participant.ui = ui
        loop = SessionLoop(store=store, kind=kind, apparatus=apparatus, participant=participant, audio=audio, ui=ui,
                           protocol=protocol, markers=markers)
        if sim_participant is not None:
            reference = kind.reference(apparatus)
            if reference is not None:
                store.log_event(reference)
        if markers is not None and args.lsl_wait_s > 0:   # a recorder connected before the first attempt
            t_end = markers.now() + args.lsl_wait_s
            ok = apparatus.wait_streams(args.lsl_wait_s) if isolate else True
            if not (ok and markers.wait_for_consumers(max(0.0, t_end - markers.now()))):
                print(f"warning: --lsl-wait-s: no recorder connected to every stream within {args.lsl_wait_s:g} s; "
                      "the session starts anyway", file=sys.stderr)
        audio.start()
        stop_watch = threading.Event()
        watch = threading.Thread(target=_watch_progress, args=(kind, stop_watch, subject), daemon=True,
                                 name="progress")
        if not args.quiet and kind.progress() is not None:
            watch.start()
        try:
            loop.run()
            audio.wait_cues(3.0)  # let the last spoken question finish
        finally:
            stop_watch.set()
            if watch.is_alive():
                watch.join(2.0)
            audio.stop()
        kind.finish(store.session)
        if markers is not None:   # each part's streams and the clock pairs of its windows (plumbing.lsl)
            servo = apparatus.close_streams() if isolate else None
            record = markers.close()
            if servo is not None:
                record = {**servo, "streams": servo["streams"] + record["streams"], "markers": record["markers"],
                          "dropped_chunks": servo["dropped_chunks"] + record["dropped_chunks"]}
            store.session.setdefault("lsl", []).append(record)
        if hasattr(apparatus, "window_timing"):  # the servo process's tapping windows against the thresholds
            store.session["servo_timing"] = merge_summaries(store.session.get("servo_timing"),
                                                            window_summary(apparatus.window_timing))
        store.finish()
    except KeyboardInterrupt:
        print(f"interrupted: data so far is in {store.dir}; continue with --resume", file=sys.stderr)
        return 130
    except Terminated as exc:  # SIGTERM/SIGHUP: as Ctrl-C, with the signal's exit status
        print(f"{exc}: data so far is in {store.dir}; continue with --resume", file=sys.stderr)
        return exc.code
    except Exception as exc:
        if isinstance(exc, Aborted):
            print(f"aborted by the operator: data so far is in {store.dir}; continue with --resume", file=sys.stderr)
            return 3
        if isinstance(exc, DataFileChanged):
            print(f"error: {exc}", file=sys.stderr)
            return 5
        if isinstance(exc, ServoStopped):
            print(f"error: {servo_stopped_message(exc)}; the attempt in progress is not recorded; data so far is "
                  f"in {store.dir}; continue with --resume", file=sys.stderr)
            return 4
        raise
    finally:
        if device is not None:
            device.close()
        elif apparatus is not None:
            apparatus.close()
        if web is not None:
            if store.session and store.session.get("finished_at"):
                web.stop_when_seen()   # the operator page shows "session complete", not "runner stopped"
            else:
                web.stop()
    kind.summary(store.read_trials(), store, say)
    return 0


def servo_stopped_message(exc) -> str:
    """What stopped the servo, saying once that the output was zeroed (the device's or the loop's own
    message often says so already: "disconnected (...); output zeroed by the device watchdog")."""
    text = str(exc)
    return text if "zeroed" in text else f"{text}; the output was zeroed"


def record_timing(store, timing_rec, servo_policy, resumed: bool) -> None:
    """Put the pre-session timing check and the servo's granted policy into session.json and schedule.jsonl."""
    if timing_rec is None and servo_policy is None:
        return
    if timing_rec is not None:
        store.log_event({"event": "timing_check", "met": timing_rec["verdict"]["met"],
                         "failed": timing_rec["verdict"]["failed"],
                         "accepted_override": timing_rec["accepted_override"]})
        store.session.setdefault("timing_checks", []).append(timing_rec)
        if not resumed:
            store.session["timing_check"] = timing_rec
    if servo_policy is not None:
        store.session.setdefault("servo_policy", []).append(servo_policy)
    store.write_session()


def _watch_progress(kind, stop, subject: str, period_s: float = 0.5) -> None:
    """Report the session's progress on stderr until ``stop`` is set: phase, trial n of N, elapsed, time left.

    A tqdm bar on a terminal, plain lines otherwise (plumbing.progress). Runs in its own thread and only reads
    the kind's counts, so it never delays the session.
    """
    done, total, _ = kind.progress()
    prog = Progress(total, f"study {subject}", unit="trial", initial=done)
    last = None
    while not stop.wait(period_s):
        done, total, phase = kind.progress()
        if (done, total, phase) != last:
            last = (done, total, phase)
            prog.update(done, status=phase, total=total)
    done, total, phase = kind.progress()
    if (done, total) != (last or (None, None))[:2]:
        prog.update(done, status=phase, total=total)
    prog.close()


def _audio_device(value):
    if value is None:
        return None
    return int(value) if value.isdigit() else value


class KeyboardParticipant:
    """A person: answers (and the end of familiarization) come from the subject view."""

    kind = "keyboard"
    ui = None
