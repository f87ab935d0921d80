"""Fixtures of the stimuli tests: the test device models (tests/support/stimuli.py)."""

from __future__ import annotations

import pytest

from tests.support.stimuli import minimum_phase_model, rhp_zero_model


@pytest.fixture
def mp_model():
    return minimum_phase_model()


@pytest.fixture
def rhp_model():
    return rhp_zero_model()
