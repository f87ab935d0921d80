"""The thesis's claims measured on the demo's own taps and beyond (renderer/demo/fidelity.py, thesis_rows.py).

One default demo (``make demo``'s settings: 0.05/0.08/0.11/0.15/0.2/0.3 m/s x 1/2/3 N, thirteen renderings) is
run per session (tests/conftest.py ``default_demo``). The operating point is section 4.5.4's: the speeds within
0.05-0.15 m/s weighted by a normal density of mean 0.10 and s.d. 0.042 m/s, grips 1-3 N.

Targets the default sim meets are asserted as targets; those it does not are asserted at the measured value
(so a change shows) and as reported "no" in fidelity.csv: docs/sim.md, "The thesis's operating point", says
which modelling choice causes each miss.
"""

import csv
import math

import numpy as np
import pytest
from scipy import stats

from renderer.demo import fidelity
from renderer.demo.fidelity import Claim, claims_from_dicts, write_fidelity

OP_V = (0.05, 0.08, 0.11, 0.15)


@pytest.fixture(scope="module")
def claims(default_demo):
    return {c.id: c for c in default_demo.claims}


def _row_pen_mm(res, name):
    """Operating-point penetration from summary rows, weights from scipy's normal density (a cross-check)."""
    w = stats.norm.pdf(OP_V, loc=0.10, scale=0.042)
    pens = [np.mean([res.row(name, v, g)["penetration_mean_m"] for g in res.cfg.grips_N]) for v in OP_V]
    return 1e3 * float(np.dot(w, pens) / w.sum())


def test_fidelity_csv_has_one_row_per_claim(default_demo, claims):
    with open(default_demo.out / "fidelity.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == fidelity.COLUMNS
    assert [r["id"] for r in rows] == [c.id for c in default_demo.claims]
    assert set(claims) == {
        "penetration_wood", "penetration_wood_on_foam", "penetration_foam", "penetration_soft",
        "firm_shallower", "very_firm_shallower", "transient_cut_mean", "transient_cut_each",
        "grip_nrmse_wood", "grip_peak_wood", "grip_nrmse_wood_on_foam", "grip_peak_wood_on_foam",
        "grip_nrmse_foam", "grip_peak_foam", "figure_4_13", "sinusoid_correlation", "sinusoid_frequency",
        "hfam_open_loop", "hfam_refined_unseen", "hfam_saturation",
        "wall_resonance", "held_device_slopes", "grip_independent_70hz",
        "teleop_lambda_1", "teleop_lambda_3_buzz", "teleop_cimm_lambda_10", "teleop_stable_15", "hfam_delay",
        "study_real_wood_first", "study_hfam_first_virtual", "study_proportional_near_foam", "study_saturations"}
    for r in rows:
        c = claims[r["id"]]
        if math.isnan(c.measured):
            assert r["measured"] == "nan"
        else:
            assert float(r["measured"]) == pytest.approx(c.measured, rel=1e-5)
        assert r["holds"] == ("yes" if c.holds else "no")
        assert r["section"] and r["thesis"] and r["target"] and r["measured_text"]


def test_operating_point_weights_are_section_4_5_4s():
    w = fidelity.operating_weights((0.03, 0.05, 0.08, 0.11, 0.15, 0.2, 0.3))
    assert list(w) == [0.05, 0.08, 0.11, 0.15]
    ref = stats.norm.pdf(OP_V, loc=0.10, scale=0.042)
    np.testing.assert_allclose(list(w.values()), ref / ref.sum(), rtol=1e-12)


def test_figure_4_19_depths(default_demo, claims):
    """Section 4.5.5, Figure 4.19, on the one-dof device. Measured (operating point, mm): wood 0.189, wood on foam
    0.229, foam 1.665, soft 1.531; firm 1.01 and very firm 0.78 are shallower than 2 of the 6 event-based
    renderings ("many": met at >= 2). A population of persons (arm 0.05-0.2 kg) reaches > 2 mm in the foam from
    0.15 kg, where the cuts miss, and never in the soft wall (docs/sim.md)."""
    for cid, name in (("penetration_wood", "real_wood"), ("penetration_wood_on_foam", "real_wood_on_foam"),
                      ("penetration_foam", "real_foam"), ("penetration_soft", "soft")):
        assert claims[cid].measured == pytest.approx(_row_pen_mm(default_demo, name), rel=1e-9)
    assert claims["penetration_wood"].measured < 0.25 and claims["penetration_wood"].holds
    assert claims["penetration_wood_on_foam"].measured < 0.25 and claims["penetration_wood_on_foam"].holds
    assert 1.4 < claims["penetration_foam"].measured < 1.9 and not claims["penetration_foam"].holds
    assert 1.3 < claims["penetration_soft"].measured < 1.8 and not claims["penetration_soft"].holds
    for cid in ("penetration_foam", "penetration_soft"):
        assert "Population at 2 N (arm 0.05 kg:" in claims[cid].measured_text and "0.2 kg" in claims[cid].measured_text
    assert "no person of the population reaches 2 mm" in claims["penetration_soft"].measured_text
    for cid in ("firm_shallower", "very_firm_shallower"):
        assert claims[cid].measured == 2 and claims[cid].holds


def test_factor_of_two(default_demo, claims):
    """Section 4.5.5 ("roughly ... a factor of two"). Measured (operating point): pulse 2.04x / 2.23x, sinusoid
    1.35x / 1.29x, HFAM 1.70x / 1.45x over firm / soft: mean 1.67x (>= 1.5 met), each >= 1.2 (met)."""
    cuts = fidelity.transient_cuts(default_demo.traces, default_demo.cfg.renderings)
    assert set(cuts) == set(fidelity.EVENT_BASED)
    for name, (op, _grid) in cuts.items():
        wall = "firm" if name.endswith("firm") else "soft"
        assert op == pytest.approx(_row_pen_mm(default_demo, wall) / _row_pen_mm(default_demo, name), rel=1e-9)
        assert op >= 1.2, (name, op)
    assert claims["transient_cut_each"].holds
    assert claims["transient_cut_mean"].measured == pytest.approx(np.mean([c[0] for c in cuts.values()]))
    assert 1.55 <= claims["transient_cut_mean"].measured < 1.8 and claims["transient_cut_mean"].holds
    assert cuts["pulse_firm"][0] >= 1.9 and cuts["pulse_soft"][0] >= 2.0


def test_real_contact_against_grip(default_demo, claims):
    """Section 4.4.1 over the contact's first 20 ms. Measured: median NRMSE 0.229 (wood), 0.224 (wood on foam):
    met; foam 0.331, not met: its 20-1000 Hz tap is at the accelerometer's noise (a hand with no grip dependence
    at all gives 0.22-0.25, docs/sim.md). Peaks within -1..+15 % of the 2 N tap's (met)."""
    for s in ("wood", "wood_on_foam", "foam"):
        gi = fidelity.grip_independence(default_demo.traces, f"real_{s}", default_demo.fs_hz)
        assert len(gi["nrmse"]) == 2 * len(OP_V)
        assert claims[f"grip_peak_{s}"].holds and claims[f"grip_peak_{s}"].measured <= 25.0
        assert all(0.75 <= r <= 1.25 for r in gi["peak_ratio"])
        assert claims[f"grip_nrmse_{s}"].measured == pytest.approx(gi["median_nrmse"])
        # the 20 ms window is what the row measures; the 100 ms one is never smaller
        whole = fidelity.grip_independence(default_demo.traces, f"real_{s}", default_demo.fs_hz, window_s=0.1)
        assert whole["median_nrmse"] >= gi["median_nrmse"] - 0.01
    assert claims["grip_nrmse_wood"].holds and claims["grip_nrmse_wood"].measured < 0.27
    assert claims["grip_nrmse_wood_on_foam"].holds and claims["grip_nrmse_wood_on_foam"].measured < 0.27
    assert 0.3 < claims["grip_nrmse_foam"].measured < 0.4 and not claims["grip_nrmse_foam"].holds


def test_figure_4_13(default_demo, claims):
    """Section 4.4.3, Figure 4.13: the medium-grip transient without grip compensation gives 1.14x the 20-1000 Hz
    RMS acceleration at 1 N and 0.94x at 3 N (met: > 1 and within 0.5-1.0)."""
    f = fidelity.figure_4_13(default_demo.traces, default_demo.fs_hz)
    assert len(f["soft"]) == len(f["firm"]) == len(OP_V)
    assert claims["figure_4_13"].measured == pytest.approx(f["firm_median"])
    assert 1.05 < f["soft_median"] < 1.3 and 0.85 < f["firm_median"] < 0.99 and claims["figure_4_13"].holds


def test_sinusoid_keeps_what_it_has(default_demo, claims):
    """Table 4.1's sinusoid: its correlation with the real wood-on-foam tap is above the pulse's in 24 of 24
    cells (met); its 55 Hz is 32 % below the real tap's 82 Hz (not met: the wood on foam, chosen to ring at 55 Hz
    under the hand without a fingertip, rings higher with less of the hand on the tile)."""
    sp = fidelity.sinusoid_against_pulse(default_demo.traces)
    assert sp["cells"] == 2 * len(OP_V) * 3
    assert sp["fraction"] >= 2 / 3 and claims["sinusoid_correlation"].holds
    assert 0.25 < sp["f_dev"] < 0.4 and not claims["sinusoid_frequency"].holds
    assert 75 <= sp["f_real_hz"] <= 90 and 50 <= sp["f_sinusoid_hz"] <= 60


def test_device_and_teleoperation_rows(claims):
    """The rows beyond the taps (renderer/demo/thesis_rows.py, renderer/teleop/claims.py), measured: the 1000 N/m
    wall resonates at 15.9 Hz (section 2.2.1: <= 15 Hz, not met); the held one-dof device's slopes are +18 and +9
    dB/decade (section 3.4.6: +40 and +20, not met); the held joystick's resonance 92-124 Hz (section 3.5.2: 70 Hz,
    not met); at lambda = 1 pf settles in 28/37 ms (40-60 ms, not met; met at a 4 mm press); lambda = 3 holds
    contact but settles in 24-49 ms (no buzz); cancellation at lambda = 10 settles in 59 ms on the mean (met);
    holds contact to 10 of 15 at 2 mm (met at 3 and 4 mm); the master-slave delay 1.8 ms (2.2 +/- 0.4, met)."""
    assert 15.0 < claims["wall_resonance"].measured < 17.0 and not claims["wall_resonance"].holds
    assert claims["held_device_slopes"].measured > 10.0 and not claims["held_device_slopes"].holds
    assert not claims["grip_independent_70hz"].holds
    assert 25 < claims["teleop_lambda_1"].measured < 40 and not claims["teleop_lambda_1"].holds
    assert "4 mm: 53 s/54 s (met)" in claims["teleop_lambda_1"].measured_text
    assert claims["teleop_lambda_3_buzz"].measured < 100 and not claims["teleop_lambda_3_buzz"].holds
    assert 50 <= claims["teleop_cimm_lambda_10"].measured <= 60 and claims["teleop_cimm_lambda_10"].holds
    assert not claims["teleop_stable_15"].holds and "3 mm: holds contact to lambda 15" in \
        claims["teleop_stable_15"].measured_text
    assert claims["hfam_delay"].measured == pytest.approx(1.8, abs=0.2) and claims["hfam_delay"].holds


def test_study_rows_come_from_the_current_gallery_or_are_not_measured(claims):
    """The simulated study's rows are read from the docs gallery's study when its stamp matches the code, else
    "not measured" with the reason (renderer/demo/study_rows.py)."""
    from plumbing.artefacts import is_current

    rows = [claims[k] for k in ("study_real_wood_first", "study_hfam_first_virtual",
                                "study_proportional_near_foam", "study_saturations")]
    if is_current("gallery"):
        assert all(math.isfinite(c.measured) for c in rows)
        assert all("simulated study, 16 subjects" in c.measured_text for c in rows)
    else:
        assert all(math.isnan(c.measured) and not c.holds and "make artefacts" in c.measured_text for c in rows)


def test_writer_takes_extra_rows_as_dicts(tmp_path, claims):
    extra = [{"id": "hfam_open_loop_median", "section": "4.4.1", "thesis": "record, smooth, invert",
              "target": "median NRMSE <= 0.30", "measured": 0.28, "measured_text": "median 0.28", "holds": True}]
    path = write_fidelity(list(claims.values()), tmp_path / "fidelity.csv", extra=extra)
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(claims) + 1
    assert rows[-1]["id"] == "hfam_open_loop_median" and rows[-1]["holds"] == "yes"
    assert float(rows[-1]["measured"]) == 0.28
    # extra Claim objects too, in order after the sim's
    c = claims_from_dicts(extra)[0]
    assert isinstance(c, Claim) and c.measured == 0.28


@pytest.mark.parametrize("bad, match", [
    ({"id": "x", "section": "4.4.1", "thesis": "t", "target": "t", "measured": 1.0, "holds": True},
     "missing measured_text"),
    ({"id": "x", "section": "4.4.1", "thesis": "t", "target": "t", "measured": 1.0, "measured_text": "",
      "holds": True, "unit": "mm"}, "unexpected unit"),
    ({"id": "x", "section": "4.4.1", "thesis": "t", "target": "t", "measured": "0.3", "measured_text": "",
      "holds": True}, "measured must be a number"),
    ({"id": "x", "section": "4.4.1", "thesis": "t", "target": "t", "measured": 0.3, "measured_text": "",
      "holds": "yes"}, "holds must be True or False"),
])
def test_malformed_extra_rows_are_one_clear_error(tmp_path, bad, match):
    with pytest.raises(ValueError, match=match):
        write_fidelity([], tmp_path / "fidelity.csv", extra=[bad])
    assert not (tmp_path / "fidelity.csv").exists()


def test_duplicate_claim_ids_are_refused(tmp_path, claims):
    c = claims["penetration_wood"]
    with pytest.raises(ValueError, match="given twice: penetration_wood"):
        write_fidelity([c], tmp_path / "fidelity.csv", extra=[c])


def test_nan_measurement_does_not_hold():
    c = fidelity.measure_claims({}, (), 10_000.0)
    assert len(c) == 17 and not any(x.holds for x in c)
    assert all(math.isnan(x.measured) for x in c)
    line = fidelity.format_fidelity(c)
    assert line.startswith("Thesis claims reproduced by the sim: 0 of 17; not measured by these taps")
    assert "(not:" not in line


def test_printed_line_counts_what_holds(claims):
    line = fidelity.format_fidelity(claims.values())
    n = sum(c.holds for c in claims.values())
    unmeasured = sum(math.isnan(c.measured) for c in claims.values())
    assert line.startswith(f"Thesis claims reproduced by the sim: {n} of {len(claims)} (not: ")
    assert ("not measured" in line) == (unmeasured > 0)


def test_the_hfam_claims_are_the_scoring_of_the_demos_own_pipeline_kept_in_its_cache_entry(default_demo, claims):
    """fidelity.csv carries item 5's rows (stimuli.hfam.scoring.hfam_claims on the demo's pipeline), computed
    once per cache entry: the entry's hfam_claims.json holds the same numbers the demo wrote."""
    import json

    from renderer.demo.cache import HFAM_CLAIMS_FILE

    ids = ("hfam_open_loop", "hfam_refined_unseen", "hfam_saturation")
    assert all(i in claims for i in ids)
    kept = {r["id"]: r for r in json.loads((default_demo.pipeline.directory / HFAM_CLAIMS_FILE).read_text())}
    for i in ids:
        assert claims[i].measured == pytest.approx(kept[i]["measured"], rel=1e-12)
        assert claims[i].holds == kept[i]["holds"]
    # the open-loop figure is a median NRMSE of real taps: a number between the HFAM rows' and the wall's
    assert 0.1 < claims["hfam_open_loop"].measured < 1.0
    assert claims["hfam_saturation"].measured >= 0
