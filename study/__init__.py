"""Sessions with people (or a simulated participant) on the haptic device: thesis section 4.5 and its
psychophysics (``python -m study run``, docs/study.md).

``session``       the machinery every experiment shares: set-up of device, audio, timing check and views on one
                  path (``run``), the record and resume checks (``setup``), the crash-safe store (``store``),
                  the attempt loop (``loop``), the interface an experiment kind implements (``kind``),
                  apparatus (device, servo loops, homing; ``isolated``: in its own process), masking audio,
                  the views (``webui``, ``uistate``), participants and the synthetic rater, servo timing, seeds
``ratings``       the blind real-vs-virtual rating study: its schedule and its attempt
``forcedchoice``  the forced-choice experiments (real vs virtual, discrimination, detection): the
                  ``[experiment]`` table, the plan, the simulated participant's judgments, the attempt
``cli_run``       the ``run`` command (parser: ``cli_run_parser``); ``cli_simulate_observer`` and
                  ``observer_figures``: an adaptive method against a simulated observer (psychophysics)
"""
