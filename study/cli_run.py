"""``python -m study run``: run a blind realism session (thesis section 4.5.3).

Sim rehearsal, unattended, in seconds::

    python -m study run --device sim --participant simulated --subject S01 --seed 1 --out DATA

A person with the views (subject page and token-protected operator page)::

    python -m study run --device serial:/dev/ttyACM0 --participant keyboard --subject P07 \\
        --age 24 --gender female --handedness right --experience few --out DATA

Continue a killed or aborted session exactly where it stopped::

    python -m study run ... --subject P07 --out DATA --resume
"""

from __future__ import annotations

import sys
import threading
from dataclasses import asdict

from devices import DeviceError, make_device
from plumbing.progress import Progress
from plumbing.stopsignals import Terminated, stop_on_signals

from .apparatus import Apparatus, ServoStopped
from .audio import CHOICE_PHRASES, MaskingAudio, SilentAudio, check_output_device
from .data import DataFileChanged, SessionStore, release_all_locks
from .isolated import IsolatedApparatus
from .participants import SimulatedParticipant, load_participant_config
from .protocol import Schedule
from .psysession import run_experiment
from .runner import StudyRunner
from .servo_timing import merge_summaries, pre_session_check, window_summary
from .session import plan_session, start_session
from .uistate import Aborted, UiState
from .webui import WebUI


def run_command(args) -> int:
    """Run (or resume) one session; the subject lock is released on every way out.

    SIGTERM and SIGHUP end the session as Ctrl-C does (the output zeroed, the data so far kept for
    ``--resume``) and the command returns 128 + the signal's number (plumbing.stopsignals).
    """
    try:
        with stop_on_signals():
            return _run_command(args)
    finally:
        release_all_locks()


def _run_command(args) -> int:
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, flush=True))
    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port must be 0..65535 (0: any free port), got {args.port}")
    plan = plan_session(args)
    # the views' socket is bound before anything is written: a busy port or an address this computer does not
    # have is refused here, with no subject folder made (a rerun on a free port then starts afresh)
    web = _bind_views(args)
    try:
        return _run_session(args, plan, say, web)
    finally:
        if web is not None:
            web.stop()


def _bind_views(args):
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


def _run_session(args, plan, say, web) -> int:
    """The session of ``plan`` (views on ``web`` if not None, started once the session's folder is open)."""
    store, previous, subject, is_sim = plan.store, plan.previous, plan.subject, plan.is_sim
    protocol, seed, info, catalog, library_dir = plan.protocol, plan.seed, plan.info, plan.catalog, plan.library_dir

    # masking audio: required on hardware, silent in sim unless asked

    want_audio = args.audio == "on" or (args.audio == "auto" and not is_sim)
    if want_audio:
        device_name = check_output_device(_audio_device(args.audio_device))
        audio = MaskingAudio(level_dbfs=protocol.masking_level_dbfs, fs_hz=protocol.audio_fs_hz,
                             seed=seed, device=_audio_device(args.audio_device), cue_level_db=protocol.cue_level_db,
                             phrases=CHOICE_PHRASES if plan.experiment is not None else None)
        audio_info = {"output": device_name, "level_dbfs": protocol.masking_level_dbfs,
                      "cue_source": audio.cue_source, "cue_spoken": audio.cue_spoken,
                      "cue_level_db": protocol.cue_level_db}
        if not audio.cue_spoken:
            print(f"warning: the cues are chimes, not spoken: {audio.cue_source}", file=sys.stderr)
    else:
        audio = SilentAudio()
        if is_sim:
            say("note: sim session runs silently (no masking audio); use --audio on to play it")
        else:
            audio.cue_source = "none (--audio off: no masking, not valid for a blind study)"
            print("warning: --audio off: no masking noise or cues; the session is not blind to sound",
                  file=sys.stderr)
        audio_info = {"output": None, "level_dbfs": None, "cue_source": audio.cue_source, "cue_spoken": False,
                      "cue_level_db": None}



    timing_rec = None
    if not is_sim:  # the servo's timing through this device, before any trial (issue 40; study.servo_timing)
        say(f"checking the servo's timing through {args.device} ({protocol.timing_check_s:g} s, motor off) ...")
        timing_rec = pre_session_check(args.device, protocol, args.accept_timing)
        if timing_rec["accepted_override"]:
            print(f"warning: the servo timing check failed ({'; '.join(timing_rec['verdict']['failed'])}); "
                  "running anyway as --accept-timing asks (recorded in session.json)", file=sys.stderr)
    sim_participant = None
    if is_sim:
        pcfg = load_participant_config(args.participant_config if previous is None
                                       else previous.get("participant_config_file"))
        sim_participant = SimulatedParticipant(subject, info.experience, seed, pcfg)
    isolate = args.servo_process == "on" or (args.servo_process == "auto" and not is_sim)
    device_options = {"seed": seed} if is_sim else {}
    device = apparatus = None
    ui = None
    if isolate:
        apparatus = IsolatedApparatus(args.device, device_options, catalog, protocol, library_dir,
                                      sim_participant, realtime=True if args.realtime else None)
        device_info = apparatus.device_info
    else:
        try:
            device = make_device(args.device, **device_options)
            device.open()
        except DeviceError as exc:
            raise ValueError(f"device {args.device}: {exc}") from None
        device_info = asdict(device.info)
    try:
        if apparatus is None:
            apparatus = Apparatus(device, catalog, protocol, library_dir=library_dir,
                                  sim_participant=sim_participant, realtime=True if args.realtime else None)
        participant = sim_participant if args.participant == "simulated" else _KeyboardParticipant()
        if plan.experiment is not None:  # issue 34: a psychophysics session (2-interval forced choice)
            return run_experiment(plan, args, apparatus, participant, audio, audio_info, device_info, isolate,
                                  sim_participant, say)
        schedule = Schedule([s.name for s in catalog], protocol.repetitions, seed,
                            protocol.familiarization_sample or None, subject)
        rows, fam_ended = start_session(plan, args, schedule, device_info, isolate, sim_participant, audio_info,
                                        apparatus.real_saturation_detection)
        _record_timing(store, timing_rec, getattr(apparatus, "servo_policy", None), previous is not None)


        if web is not None:
            ui = web.ui
            web.start()
            print(f"subject view:  {web.subject_url}", flush=True)
            print(f"operator view: {web.operator_url}", flush=True)
            if args.participant == "keyboard":
                participant.ui = ui
        runner = StudyRunner(store=store, schedule=schedule, apparatus=apparatus, participant=participant,
                             audio=audio, ui=ui, protocol=protocol, kinds={s.name: s.kind for s in catalog})
        if rows:
            runner.restore(rows, fam_ended)
            say(f"resuming {subject}: {len(rows)} attempts on disk, next: {schedule.phase}")
        if sim_participant is not None:
            ref = apparatus.record_reference()
            store.log_event({"event": "rater_reference", "a": ref.a, "b": ref.b, "centroid_hz": ref.centroid_hz})
        audio.start()
        stop_watch = threading.Event()
        watch = threading.Thread(target=_watch_progress, args=(schedule, stop_watch, subject), daemon=True,
                                 name="progress")
        if not args.quiet:
            watch.start()
        try:
            runner.run()
            audio.wait_cues(3.0)  # let the last "Stop. Please rate." finish
        finally:
            stop_watch.set()
            if watch.is_alive():
                watch.join(2.0)
            audio.stop()
        store.session["order"] = schedule.summary()
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
            if store.session.get("finished_at"):
                web.stop_when_seen()   # the operator page shows "session complete", not "runner stopped"
            else:
                web.stop()
    _summary(store, say)
    return 0


def servo_stopped_message(exc) -> str:
    """What stopped the servo, saying once that the output was zeroed (the device's or the loop's own
    message often says so already: "disconnected (...); output zeroed by the device watchdog")."""
    text = str(exc)
    return text if "zeroed" in text else f"{text}; the output was zeroed"


def _record_timing(store, timing_rec, servo_policy, resumed: bool) -> None:
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


def _trial_counts(schedule) -> tuple[int, int]:
    """(attempts finished, attempts planned) over demonstration and testing; redrawn trials add attempts."""
    phases = [schedule.phases["demonstration"], schedule.phases["testing"]]
    left = sum(len(p.pool) + (p.current is not None) for p in phases)
    total = sum(len(p.planned) + len(p.redraws) for p in phases)
    return total - left, total


def _watch_progress(schedule, stop, subject: str, period_s: float = 0.5) -> None:
    """Report the session's progress on stderr until ``stop`` is set: phase, trial n of N, elapsed, time left.

    A tqdm bar on a terminal, plain lines otherwise (plumbing.progress). Runs in its own thread and only reads
    the schedule, so it never delays the session.
    """
    done, total = _trial_counts(schedule)
    prog = Progress(total, f"study {subject}", unit="trial", initial=done)
    last = None
    while not stop.wait(period_s):
        done, total = _trial_counts(schedule)
        phase = schedule.phase or "done"
        if (done, total, phase) != last:
            last = (done, total, phase)
            prog.update(done, status=phase, total=total)
    done, total = _trial_counts(schedule)
    if (done, total) != (last or (None, None))[:2]:
        prog.update(done, status=schedule.phase or "done", total=total)
    prog.close()


def _audio_device(value):
    if value is None:
        return None
    return int(value) if value.isdigit() else value


class _KeyboardParticipant:
    """A person: ratings and the end of familiarization come from the subject view."""

    kind = "keyboard"
    ui = None


def _summary(store: SessionStore, say) -> None:
    rows = store.read_trials()
    by_phase = {}
    for r in rows:
        d = by_phase.setdefault(r["phase"], {"attempts": 0, "valid": 0, "saturated": 0, "rejected": 0,
                                             "overpowered": 0})
        d["attempts"] += 1
        for key in ("valid", "saturated", "rejected", "overpowered"):
            d[key] += bool(r[key])
    print(f"session {store.subject} complete: {store.dir}")
    for phase, d in by_phase.items():
        print(f"  {phase:15s} attempts {d['attempts']:3d}  valid {d['valid']:3d}  saturated {d['saturated']:2d}  "
              f"rejected {d['rejected']:2d}  overpowered {d['overpowered']:2d}")
