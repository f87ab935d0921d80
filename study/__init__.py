"""Blind realism study runner (thesis section 4.5): protocol, apparatus, masking audio, views, crash-safe data.

Command: ``python -m study run`` (see docs/study.md). Modules:

``protocol``      replayable seeded schedule (familiarization, demonstration, testing, redraws)
``data``          session folder: session.json, trials.csv, schedule.jsonl, traces/*.npz
``apparatus``     device + one renderer.ServoLoop per sample + homing (renderer.homing); sim hand and samples
``isolated``      the apparatus in its own process (hardware default)
``audio``         white-noise masker with cues through sounddevice/PortAudio
``uistate``       state shared by the runner and the views; the abort signal
``webui``         subject and operator views (local HTTP server)
``participants``  simulated participant; ``rater``: synthetic rater (pipeline test, not perception)
``runner``        one attempt and the session loop; ``cli_run``: the ``run`` command
"""
