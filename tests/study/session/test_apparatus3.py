"""Studies on the 3-DOF simulated device (study.session.apparatus3): the catalog's samples as blocks on a table,
tapped from above by the simulated participant; a rating session, a 2-interval stiffness discrimination and an
adaptive staircase end to end, in-process; the operator page (headless Chromium) showing the hand over the table."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from playwright.sync_api import expect, sync_playwright

from devices.sim import Sim3Device
from renderer.scene3 import pack_scene
from stimuli import load_catalog
from study.__main__ import main
from study.session.apparatus3 import (GRID_SPAN_M, TABLE_Z_M, Apparatus3, TapAxis, make_apparatus,
                                      table_scene)
from study.session.config import ProtocolConfig
from study.session.participants import SimulatedParticipant
from study.session.uistate import UiState
from study.session.webui import WebUI

from tests.support.needs import chromium
from tests.support.study import read_rows, read_session, write

QUICK = """
tap_window_s = 0.8
homing_after_s = 0.3
homing_before_max_s = 0.1
familiarization_sample = ""
"""
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]
#: the simulated participant's tap speeds (m/s): what a contact's v_n must lie in, straight down
TAP_RANGE_M_S = (0.02, 0.45)


def _run(tmp: Path, subject: str, protocol: str, *extra, seed: int = 2) -> Path:
    proto = write(tmp / f"{subject}.toml", protocol)
    rc = main(["run", "--device", "sim:3d", "--participant", "simulated", "--quiet", "--subject", subject,
               "--seed", str(seed), "--out", str(tmp / "DATA"), "--protocol", str(proto), *extra])
    assert rc == 0
    return tmp / "DATA" / subject


def _traces(folder: Path) -> dict:
    out = {}
    for f in sorted((folder / "traces").glob("*.npz")):
        with np.load(f) as d:
            out[f.stem] = {k: d[k] for k in d.files}
    return out


def _contacts_on_their_block(traces: dict) -> int:
    """Every contact of every window was on the presented sample's block; returns the number of contacts."""
    n = 0
    for name, tr in traces.items():
        objs = [str(o) for o in tr.get("event_object", [])]
        block = str(tr["sample"]).split("@")[0]     # a derived stimulus is rendered on its base sample's block
        assert objs == [block] * len(tr["event_t_s"]), (name, objs, str(tr["sample"]))
        v = tr["event_incoming_velocity_m_s"]
        assert np.all((v > TAP_RANGE_M_S[0]) & (v < TAP_RANGE_M_S[1])), (name, v)
        assert np.all(tr["event_max_penetration_m"] > 1e-5), name
        # the trace's height is above the tapped surface: the hand comes down to it (0) and presses in
        assert np.min(tr["position_m"]) < 0.0 < np.max(tr["position_m"])
        n += len(objs)
    return n


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """One short session of each kind on sim:3d (shared by the tests below)."""
    tmp = tmp_path_factory.mktemp("study3d")
    rating = _run(tmp, "R01", QUICK, "--samples", "firm,pulse_firm,soft", seed=1)
    disc = _run(tmp, "D01", QUICK + """
[experiment]
kind = "discrimination"
sample = "firm"
reference = 680.0
levels = [450.0, 1000.0]
trials_per_level = 2
""", seed=2)
    stair = _run(tmp, "S01", QUICK + """
[experiment]
kind = "detection"
sample = "pulse_firm"
method = "updown"
intensity_scale = "log10"

[experiment.staircases.A]
start = 4.0
step_down = [0.3, 0.15]
max_trials = 4
""", seed=3)
    return {"rating": rating, "discrimination": disc, "staircase": stair}


def test_a_rating_session_on_the_3dof_sim_taps_each_sample_on_its_block(sessions):
    folder = sessions["rating"]
    session = read_session(folder)
    assert session["device"]["spec"] == "sim:3d" and session["device"]["info"]["axes"] == 3
    rows = read_rows(folder)
    testing = [r for r in rows if r["phase"] == "testing"]
    assert len(testing) >= 6 and {r["sample"] for r in testing} == {"firm", "pulse_firm", "soft"}
    valid = [r for r in testing if r["valid"] == "true"]
    assert len(valid) >= 3
    for r in valid:
        assert 1 <= int(r["rating"]) <= 7 and int(r["n_taps"]) >= 1
        assert TAP_RANGE_M_S[0] < float(r["incoming_velocity_mean_m_s"]) < TAP_RANGE_M_S[1]
        assert 1e-5 < float(r["penetration_mean_m"]) < 5e-3
    traces = _traces(folder)
    assert _contacts_on_their_block(traces) >= len(valid)
    # a softer block lets the stylus in deeper (the same hand): the renderer's stiffness reached the taps
    depth = {s: np.mean([float(r["penetration_mean_m"]) for r in valid if r["sample"] == s]) for s in ("firm", "soft")}
    assert depth["soft"] > depth["firm"]


def test_a_two_interval_stiffness_discrimination_on_the_3dof_sim(sessions):
    folder = sessions["discrimination"]
    rows = read_rows(folder)
    assert len(rows) == 4
    for r in rows:
        assert {r["sample_1"], r["sample_2"]} == {"firm@stiffness_N_m=680",
                                                   f"firm@stiffness_N_m={float(r['intensity_physical']):g}"}
        assert int(r["n_taps_1"]) >= 1 and int(r["n_taps_2"]) >= 1 and r["response"] in ("1", "2")
        for k in ("1", "2"):
            assert TAP_RANGE_M_S[0] < float(r[f"incoming_velocity_mean_{k}_m_s"]) < TAP_RANGE_M_S[1]
            assert float(r[f"sim_percept_{k}"]) > 100.0          # a stiffness felt, N/m
    # the simulated person felt the stiffer wall stiffer on average (its percept is measured from the taps)
    felt = {}
    for r in rows:
        for k in ("1", "2"):
            felt.setdefault(r[f"sample_{k}"], []).append(float(r[f"sim_percept_{k}"]))
    assert np.mean(felt["firm@stiffness_N_m=1000"]) > np.mean(felt["firm@stiffness_N_m=450"])
    assert _contacts_on_their_block(_traces(folder)) >= 8


def test_an_adaptive_staircase_on_the_3dof_sim(sessions):
    folder = sessions["staircase"]
    rows = read_rows(folder)
    assert len(rows) == 4 and all(r["staircase"] == "A" for r in rows)
    assert float(rows[0]["intensity_physical"]) == pytest.approx(4.0)          # the pulse's amplitude, N s/m
    for r in rows:                                                             # log10 steps of the protocol
        assert float(r["intensity"]) == pytest.approx(np.log10(float(r["intensity_physical"])), abs=1e-9)
    steps = {round(abs(float(b["intensity"]) - float(a["intensity"])), 6) for a, b in zip(rows, rows[1:])}
    assert steps <= {0.0, 0.3, 0.15} and steps - {0.0}       # it moved (a 2-down staircase: after two correct)
    # every trial's first attempt counted: the hand found the pulse's block each time
    assert [r["attempt"] for r in rows] == ["1"] * 4
    assert _contacts_on_their_block(_traces(folder)) >= 4


@pytest.fixture(scope="module")
def apparatus():
    catalog = [s for s in load_catalog() if s.name in ("firm", "pulse_firm", "soft", "wood_on_foam")]
    dev = Sim3Device(seed=4).open()
    app = make_apparatus(dev, catalog, ProtocolConfig(), sim_participant=SimulatedParticipant("P01", "none", 4))
    yield app
    dev.close()


def test_the_table_holds_every_sample_inside_the_workspace_without_overlap(apparatus):
    assert isinstance(apparatus, Apparatus3)
    scene = table_scene(apparatus.blocks, presented="pulse_firm")
    packed = pack_scene(scene, 680.0, apparatus.device.info.specs())
    assert packed.names == ["table", *apparatus.blocks] and len(packed.names) == 5
    boxes = [b for b in packed.bounds if b is not None]
    for i, (lo, hi) in enumerate(boxes):
        assert np.all(np.abs(lo[:2]) < GRID_SPAN_M / 2 + 1e-9) and lo[2] == pytest.approx(TABLE_Z_M)
        for lo2, hi2 in boxes[i + 1:]:
            assert np.any(hi[:2] < lo2[:2]) or np.any(hi2[:2] < lo[:2])     # apart in x or y
    # the presented block takes the loop's stiffness and transient; the others their own, no transient
    props = {o.props.name: o.props for o in scene.objects}
    assert props["pulse_firm"].stiffness_N_m is None and props["pulse_firm"].transient is None
    assert props["soft"].stiffness_N_m == 340.0 and props["soft"].transient == "none"
    assert props["wood_on_foam"].stiffness_N_m == 1020.0           # a real sample's block: motor off when presented


def test_homing_holds_the_hand_above_the_presented_block(apparatus):
    for name in ("soft", "pulse_firm"):
        apparatus.set_sample(name)
        apparatus.home(0.6)
        x, y, z = apparatus.hand_position()
        tx, ty, tz = apparatus.targets[name]
        assert (x, y) == pytest.approx((tx, ty), abs=1e-4)
        assert z - tz == pytest.approx(apparatus.protocol.home_height_m, abs=1.5e-3)
    assert isinstance(apparatus.homing.device, TapAxis)


def test_the_operator_page_shows_the_hand_over_the_table(apparatus):
    ui = UiState()
    web = WebUI(ui, token="tok-3d").start()
    try:
        apparatus.set_sample("pulse_firm")
        apparatus.home(0.6)
        view = apparatus.table_view()
        assert view["hand"]["over"] == "pulse_firm" and view["presented"] == "pulse_firm"
        ui.set_operator(subject="P01", phase="testing", trial=1, trials_total=6, table=view)
        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=chromium(), args=CHROMIUM_ARGS)
            page = b.new_page()
            page.goto(web.operator_url)
            hand = view["hand"]
            expect(page.locator("#hand")).to_have_text(
                f"x {hand['x_mm']:.1f} mm, y {hand['y_mm']:.1f} mm: {hand['height_mm']:.1f} mm above pulse_firm "
                "(presented: pulse_firm)", timeout=5000)
            dot = page.locator("#handdot")
            assert float(dot.get_attribute("cx")) == pytest.approx(hand["x_mm"], abs=1e-6)
            assert float(dot.get_attribute("cy")) == pytest.approx(-hand["y_mm"], abs=1e-6)
            assert page.locator("#table rect").count() == 4
            assert page.locator("#table rect.presented").get_attribute("data-name") == "pulse_firm"
            # the next sample: the hand moves over its block, the page follows
            apparatus.set_sample("soft")
            apparatus.home(0.6)
            view = apparatus.table_view()
            ui.set_operator(table=view)
            expect(page.locator("#hand")).to_contain_text("above soft (presented: soft)", timeout=5000)
            assert float(page.locator("#handdot").get_attribute("cx")) == pytest.approx(view["hand"]["x_mm"], abs=1e-6)
            assert abs(view["hand"]["x_mm"] - hand["x_mm"]) > 10.0
            b.close()
    finally:
        web.stop()
