"""The CIMM model of the teleoperation tests: one successive isolation of the simulated master per test session.

Successive isolation (thesis section 3.5, ``devices.identify.successive``) of the simulated master, made once per
test run (tests/support/isolation.py), saved with the project's saver and loaded with ``load_sim_params`` -- never
the simulator's own parameters. Session-scoped so the sweep tests and the servo-bandwidth study share one
identification.
"""

from __future__ import annotations

import pytest

from devices.sim.params import default_params
from devices.sim.teleop import CimmModel
from renderer.teleop.models import cimm_params
from tests.support.isolation import default_isolation


@pytest.fixture(scope="session")
def cimm_file(tmp_path_factory):
    """The one place the CIMM model comes from: successive isolation of the simulated master (shared with the
    isolation's own tests, tests/support/isolation.py)."""
    from devices.identify.successive import save_result

    out = tmp_path_factory.mktemp("successive")
    save_result(default_isolation(tmp_path_factory), out, figures=False)
    return out / "model.json"


@pytest.fixture(scope="session")
def cimm_model(cimm_file):
    params, source = cimm_params(cimm_file)
    assert params.mechanics["k_c_N_m"] != default_params().mechanics["k_c_N_m"]  # identified, not copied
    return CimmModel(params, source=source)
