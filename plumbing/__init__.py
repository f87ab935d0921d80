"""The plumbing every package shares: command dispatch and the flag grammar, atomic files and output
folders with their locks, stop signals, progress lines, provenance, config validation, the numba cache
and the system parts (found or provisioned).

It imports none of the project's domain packages (``devices``, ``stimuli``, ``renderer``, ``study``,
``analysis``); every one of them may import it (``tests/test_architecture.py``).
"""
