"""The forced-choice experiments as an experiment kind: ``experiment`` (the ``[experiment]`` table, stimuli, the
plan), ``perception`` (the simulated participant's judgments) and ``kind`` (its trials, rows and views)."""
