"""The session machinery every experiment kind shares (docs/architecture.md, "A new experiment kind").

``kind``          the interface an experiment kind implements
``run``           one session from the command line to its summary: views, audio, timing check, device
``setup``         the checks before a session starts, the new session's record or the resumption's
``loop``          the attempt loop: one confirm, pause, present, ask and record
``store``         the crash-safe subject folder: locks, trials.csv held, durable appends, torn lines
``apparatus``     device + one servo loop per sample + homing; sim hand and samples (``isolated``: in a
                  process of its own)
``audio``         white-noise masker with spoken cues; ``webui`` + ``uistate``: the subject and operator views
``participants``  the simulated participant; ``rater``: its synthetic rater (tests the pipeline, not perception)
``servo_timing``  the timing check before a hardware session; ``config``: the protocol and subject details;
``rng``           the session's seeded random numbers
"""
