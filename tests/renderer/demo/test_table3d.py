"""The 3-D demo (renderer/demo/table3d.py): the samples on a table, tapped from several directions."""

import numpy as np
import pytest

from renderer.demo import table3d


@pytest.fixture(scope="module")
def runs():
    return table3d.run_taps()


def test_each_tap_meets_its_sample_along_the_surface_normal(runs):
    assert [r["object"] for r in runs] == ["pulse_firm", "sinusoid_firm", "soft", "very_firm"]
    for r in runs:
        ev = r["result"].events
        assert len(ev) == 3 and {e.object for e in ev} == {r["object"]}
        side = r["direction"][0] == 1.0
        normal = (-1.0, 0.0, 0.0) if side else (0.0, 0.0, 1.0)
        for e in ev:
            assert (e.normal_x, e.normal_y, e.normal_z) == pytest.approx(normal)
        # v_n is the tap's speed along the normal: 30 degrees off vertical gives cos 30 of it
        cos = abs(np.dot(r["direction"], normal))
        v = [e.incoming_velocity_m_s for e in ev]
        np.testing.assert_allclose(v, cos * np.array(table3d.SPEEDS_M_S), rtol=0.12)
    depth = {r["object"]: np.mean([e.max_penetration_m for e in r["result"].events]) for r in runs}
    assert depth["soft"] > 2.5 * depth["pulse_firm"]


def test_the_figure_data_aligns_each_tap_at_contact(runs):
    data = table3d.figure_data(runs)
    assert data["t_ms"][0] == pytest.approx(-5.0) and len(data["runs"]) == 4
    for r in data["runs"]:
        for d, f, _ in r["traces"]:
            assert np.all(d[:50] == 0.0) and d[50:].max() > 0.2      # out before contact, then in
