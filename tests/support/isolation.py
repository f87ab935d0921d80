"""The successive isolation of the default simulated joystick (``identify_successive("sim")``, seed 0, ~10 s of
CPU), computed once per test run for every xdist worker (:mod:`tests.support.shared`).

Two set-ups need it: the isolation's own tests (tests/devices/identify/test_successive.py, which save it with
its stage figures) and the teleoperation tests' CIMM model (tests/renderer/teleop/conftest.py, which save its
``model.json``). The README test runs the same isolation end to end through ``devices identify``.
"""

from __future__ import annotations

from tests.support.shared import shared_value


def default_isolation(tmp_path_factory):
    """The :class:`devices.identify.successive.SuccessiveResult` of the default joystick; readers must not
    change it."""
    from devices.identify.successive import identify_successive

    return shared_value(tmp_path_factory, "successive_default",
                        lambda folder: identify_successive("sim", seed=0, log=lambda *a, **k: None))
