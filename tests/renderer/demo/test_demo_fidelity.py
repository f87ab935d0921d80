"""Issue 36, items 1-4 and 6: the thesis's claims measured on the demo's own taps (renderer/demo/fidelity.py).

One default demo (``make demo``'s settings: 0.05/0.08/0.11/0.15/0.2/0.3 m/s x 1/2/3 N, thirteen renderings) is
run per session (tests/conftest.py ``default_demo``). The operating point is section 4.5.4's: the speeds within
0.05-0.15 m/s weighted by a normal density of mean 0.10 and s.d. 0.042 m/s, grips 1-3 N.

Targets the default sim meets are asserted as targets; those it does not are asserted at the measured value
(so a change shows) and as reported "no" in fidelity.csv: docs/sim.md, "The thesis's operating
point", shows with measurements why they contradict each other on this sim.
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
        "grip_nrmse_foam", "grip_peak_foam", "sinusoid_correlation", "sinusoid_frequency",
        "hfam_open_loop", "hfam_refined_unseen", "hfam_saturation"}
    for r in rows:
        c = claims[r["id"]]
        assert float(r["measured"]) == pytest.approx(c.measured, rel=1e-5)
        assert r["holds"] == ("yes" if c.holds else "no")
        assert r["section"] and r["thesis"] and r["target"] and r["measured_text"]


def test_operating_point_weights_are_section_4_5_4s():
    w = fidelity.operating_weights((0.03, 0.05, 0.08, 0.11, 0.15, 0.2, 0.3))
    assert list(w) == [0.05, 0.08, 0.11, 0.15]
    ref = stats.norm.pdf(OP_V, loc=0.10, scale=0.042)
    np.testing.assert_allclose(list(w.values()), ref / ref.sum(), rtol=1e-12)


def test_figure_4_19_depths(default_demo, claims):
    """Item 1 (section 4.5.5, Figure 4.19). Measured (operating point, mm): wood 0.205, wood on foam 0.248,
    foam 1.628, soft 1.499 (whole grid 2.137 / 2.088); firm 0.999 and very firm 0.768 are shallower than 2 of
    the 6 event-based renderings (sinusoid over soft 1.147, HFAM over soft 1.061)."""
    for cid, name in (("penetration_wood", "real_wood"), ("penetration_wood_on_foam", "real_wood_on_foam"),
                      ("penetration_foam", "real_foam"), ("penetration_soft", "soft")):
        assert claims[cid].measured == pytest.approx(_row_pen_mm(default_demo, name), rel=1e-9)
    # met: the real wood and wood on foam stop the stylus within 0.25 mm
    assert claims["penetration_wood"].measured < 0.25 and claims["penetration_wood"].holds
    assert claims["penetration_wood_on_foam"].measured < 0.25 and claims["penetration_wood_on_foam"].holds
    # not met (docs/sim.md): > 2 mm needs an arm of ~0.22 kg, where the sinusoid cuts 1.14x
    assert 1.4 < claims["penetration_foam"].measured < 1.8 and not claims["penetration_foam"].holds
    assert 1.3 < claims["penetration_soft"].measured < 1.7 and not claims["penetration_soft"].holds
    for cid in ("firm_shallower", "very_firm_shallower"):
        assert claims[cid].measured == 2 and not claims[cid].holds
    pen = {n: fidelity.penetration_mm(default_demo.traces, n)[0] for n in ("firm", "sinusoid_soft", "hfam_soft")}
    assert pen["firm"] < pen["sinusoid_soft"] and pen["firm"] < pen["hfam_soft"]


def test_factor_of_two(default_demo, claims):
    """Item 2 (section 4.5.5). Measured (operating point): pulse 2.08x / 2.36x, sinusoid 1.38x / 1.31x,
    HFAM 1.66x / 1.41x over firm / soft: mean 1.70x (target 1.8, not met), each >= 1.3 (met)."""
    cuts = fidelity.transient_cuts(default_demo.traces, default_demo.cfg.renderings)
    assert set(cuts) == set(fidelity.EVENT_BASED)
    for name, (op, _grid) in cuts.items():
        wall = "firm" if name.endswith("firm") else "soft"
        assert op == pytest.approx(_row_pen_mm(default_demo, wall) / _row_pen_mm(default_demo, name), rel=1e-9)
        assert op >= 1.3, (name, op)
    assert claims["transient_cut_each"].holds
    assert claims["transient_cut_mean"].measured == pytest.approx(np.mean([c[0] for c in cuts.values()]))
    assert 1.65 <= claims["transient_cut_mean"].measured < 1.8 and not claims["transient_cut_mean"].holds
    assert cuts["pulse_firm"][0] >= 2.0 and cuts["pulse_soft"][0] >= 2.0


def test_real_contact_against_grip(default_demo, claims):
    """Item 3 (section 4.4.1). Measured: peak acceleration within -13..+18 % (wood), -13..+16 % (wood on foam),
    -2..+8 % (foam) of the 2 N tap's (met); median NRMSE 0.589 / 0.387 / 0.570 (target 0.3, not met: the
    grip impedance that makes the device's dynamics grip-dependent, Figure 3.12 and 4.13, moves the ring)."""
    for s in ("wood", "wood_on_foam", "foam"):
        gi = fidelity.grip_independence(default_demo.traces, f"real_{s}", default_demo.fs_hz)
        assert len(gi["nrmse"]) == 2 * len(OP_V)
        assert claims[f"grip_peak_{s}"].holds and claims[f"grip_peak_{s}"].measured <= 25.0
        assert all(0.75 <= r <= 1.25 for r in gi["peak_ratio"])
        if s != "foam":
            # the light grip gives the larger peak, the firm grip the smaller (less hand coupled at 1 N)
            assert all(a > 1.0 > b for a, b in zip(gi["peak_ratio"][::2], gi["peak_ratio"][1::2])), gi
        assert claims[f"grip_nrmse_{s}"].measured == pytest.approx(gi["median_nrmse"])
        assert not claims[f"grip_nrmse_{s}"].holds
    assert 0.3 < claims["grip_nrmse_wood_on_foam"].measured < 0.45
    assert 0.3 < claims["grip_nrmse_wood"].measured < 0.65
    assert 0.3 < claims["grip_nrmse_foam"].measured < 0.65


def test_sinusoid_keeps_what_it_has(default_demo, claims):
    """Item 4. Measured: the sinusoid's correlation with the real wood-on-foam tap is above the pulse's in 24
    of 24 cells; its dominant frequency 55 Hz against the real tap's 56 Hz (2 %)."""
    sp = fidelity.sinusoid_against_pulse(default_demo.traces)
    assert sp["cells"] == 2 * len(OP_V) * 3
    assert sp["fraction"] >= 2 / 3 and claims["sinusoid_correlation"].holds
    assert sp["f_dev"] <= 0.2 and claims["sinusoid_frequency"].holds
    assert 45 <= sp["f_real_hz"] <= 65 and 50 <= sp["f_sinusoid_hz"] <= 60


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
    assert len(c) == 16 and not any(x.holds for x in c)
    assert all(math.isnan(x.measured) for x in c)
    line = fidelity.format_fidelity(c)
    assert line.startswith("Thesis claims reproduced by the sim: 0 of 16; not measured by these taps")
    assert "(not:" not in line


def test_printed_line_counts_what_holds(claims):
    line = fidelity.format_fidelity(claims.values())
    n = sum(c.holds for c in claims.values())
    assert line.startswith(f"Thesis claims reproduced by the sim: {n} of 19 (not: ")
    assert "not measured" not in line


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
