"""``python -m study run`` with an ``[experiment]`` protocol: start or resume a psychophysics session and run it.

Called by :mod:`study.cli_run` once the device, the apparatus, the participant and the masking audio are set
up exactly as for a realism session; this part writes the session's record (``session.json`` with its
``experiment``, the planned trials in ``schedule.jsonl``), serves the same subject and operator views, and runs
:class:`study.psyrun.ForcedChoiceRunner`.
"""

from __future__ import annotations

from stimuli import load_catalog

from .experiment import base_sample, handler_seed, plan_trials
from .psydata import read_psy_trials
from .psyrun import ForcedChoiceRunner, plan_events, summary
from .session import start_session
from .uistate import UiState
from .webui import WebUI


def run_experiment(plan, args, apparatus, participant, audio, audio_info: dict, device_info: dict, isolate: bool,
                   sim_participant, say) -> int:
    """Start (or resume) and run a psychophysics session; returns the exit code (0: complete).

    Parameters
    ----------
    plan : study.session.SessionPlan
        With ``plan.experiment`` set.
    args : argparse.Namespace
        The ``run`` command's arguments.
    apparatus, participant, audio
        As built by :mod:`study.cli_run`.
    audio_info, device_info : dict
        Recorded in session.json.
    isolate : bool
        Whether the servo loop runs in its own process.
    sim_participant : study.participants.SimulatedParticipant or None
    say : callable
        Prints unless ``--quiet``.
    """
    exp, store = plan.experiment, plan.store
    handler = base = None
    if exp.adaptive:
        trials = []
        handler = exp.handler(handler_seed(plan.seed, plan.subject))
        base = base_sample(load_catalog(plan.catalog_file, library_dir=plan.library_dir), exp)
        events = [{"event": "plan", "phase": "trials", "adaptive": exp.method,
                   "staircases": {label: m.state() for label, m in handler.methods.items()}}]
    else:
        trials = plan_trials(exp, plan.seed, plan.subject)
        events = plan_events(trials)
    rows, _ = start_session(plan, args, None, device_info, isolate, sim_participant, audio_info,
                            apparatus.real_saturation_detection, experiment_events=events,
                            read_rows=read_psy_trials)
    web = ui = None
    try:
        if args.participant == "keyboard" or args.serve:
            ui = UiState()
            web = WebUI(ui, host=args.host, port=args.port, token=args.token).start()
            print(f"subject view:  {web.subject_url}", flush=True)
            print(f"operator view: {web.operator_url}", flush=True)
            if args.participant == "keyboard":
                participant.ui = ui
        runner = ForcedChoiceRunner(store=store, exp=exp, trials=trials, apparatus=apparatus,
                                    participant=participant, audio=audio, ui=ui, protocol=plan.protocol,
                                    kinds={s.name: s.kind for s in plan.catalog},
                                    force_per_amp_N_A=device_info["gear_ratio"] * device_info["torque_constant_Nm_A"]
                                    / device_info["handle_length_m"],  # eq. 3.17, as DeviceInfo.force_per_amp_N_A
                                    handler=handler, base=base, seed=plan.seed)
        if rows or plan.previous is not None:
            runner.restore(rows, store.read_events())
            say(f"resuming {plan.subject}: {len(rows)} trials on disk")
        if sim_participant is not None and exp.kind == "real-virtual-2afc":
            # the simulated participant knows the real sample's own taps (motor off), as the rater knows wood on foam
            real = next(s for s in plan.catalog if s.name == exp.real_sample)
            ref = apparatus.record_reference(real.real_sample)
            store.log_event({"event": "rater_reference", "sample": real.real_sample, "a": ref.a, "b": ref.b,
                             "centroid_hz": ref.centroid_hz})
        audio.start()
        try:
            runner.run()
            audio.wait_cues(3.0)
        finally:
            audio.stop()
        store.finish()
    finally:
        if web is not None:
            web.stop()
    summary(store, exp, say, handler)
    return 0
