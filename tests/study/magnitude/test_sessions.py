"""Magnitude estimation end to end on the sim device: the plan (the standard at each block's start and every k
trials), sessions with and without a modulus, numbers typed on the subject page in headless Chromium, bad
tables, and SIGKILL then ``--resume`` giving the uninterrupted run's rows."""

import json
import math
import signal
from pathlib import Path

import numpy as np
import pytest
from playwright.sync_api import sync_playwright

from stimuli import load_catalog
from study.__main__ import main
from study.design.blocks import block_order
from study.magnitude.kind import Magnitude
from study.session.config import protocol_from, read_protocol_file
from study.magnitude.experiment import MagnitudeConfig, plan_trials
from study.session.uistate import NUMBER_HINT, UiState, number_key
from study.session.webui import WebUI

from tests.support.kills import QUICK, ForcedChoiceKillHarness
from tests.support.needs import chromium
from tests.support.study import read_rows, read_session, write

MAGNITUDE = QUICK + """
[experiment]
kind = "magnitude"
samples = ["firm"]
levels = [250.0, 500.0, 1000.0, 2000.0]
repetitions = 2
"""
KEY = ("trial", "attempt", "block", "condition", "level", "modulus_shown", "number")


def run(tmp, subject, protocol, *extra, seed=2):
    proto = write(tmp / f"{subject}.toml", protocol)
    return main(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject", subject,
                 "--seed", str(seed), "--out", str(tmp / "DATA"), "--protocol", str(proto), *map(str, extra)])


ROOT = Path(__file__).resolve().parents[3]


def test_the_shipped_example_loads_and_plans():
    """examples/magnitude.toml: two samples at six stiffnesses, 19 repetitions (228 trials), the standard
    (630 N/m, "10") first in each block and every 6 trials; every stimulus derived from the default catalog."""
    path = ROOT / "examples" / "magnitude.toml"
    data, table = read_protocol_file(path)
    assert protocol_from(data, path).tap_window_s == 3.0
    exp = Magnitude.configure(table, str(path))
    stimuli = Magnitude.samples(exp, lambda _: load_catalog(None), str(path))
    assert len(stimuli) == 2 * 6 and {s.stiffness_N_m for s in stimuli} == set(exp.levels)   # the modulus is a level
    _, order = block_order(exp.conditions, exp.order, exp.design, "S01", 1, str(path))
    plan = plan_trials(exp, order, 1, "S01")
    assert len(plan) == 228 and sorted(order) == ["firm", "pulse_firm"]
    for block in (1, 2):
        assert [t.modulus_shown for t in plan if t.block == block] == [1, 0, 0, 0, 0, 0] * 19


def test_the_plan_shows_the_standard_first_in_each_block_and_every_k_trials():
    exp = MagnitudeConfig(samples=["firm", "pulse_firm"], levels=[200.0, 400.0, 800.0], repetitions=3,
                          modulus=400.0, modulus_every=4)
    plan = plan_trials(exp, ["pulse_firm", "firm"], 1, "S1")
    assert len(plan) == 18 and [t.condition for t in plan] == ["pulse_firm"] * 9 + ["firm"] * 9
    for block in (1, 2):
        trials = [t for t in plan if t.block == block]
        assert [t.modulus_shown for t in trials] == [1, 0, 0, 0, 1, 0, 0, 0, 1]
        assert sorted(t.level for t in trials) == [200.0] * 3 + [400.0] * 3 + [800.0] * 3
    free = MagnitudeConfig(samples=["firm"], levels=[200.0, 400.0, 800.0])
    assert not any(t.modulus_shown for t in plan_trials(free, ["firm"], 1, "S1"))
    assert plan_trials(exp, ["pulse_firm", "firm"], 1, "S2") != plan


def test_a_session_with_a_modulus_scales_the_numbers_to_it(tmp_path):
    """The standard (500 N/m, "10") comes first; the participant's numbers follow its power law (exponent 0.8)
    through the standard: a number near 10 * (level / 500)^0.8 (within the percept's and the answer's noise)."""
    part = write(tmp_path / "p.toml", "p_reject = 0\np_overpower = 0\np_hard_tap = 0\n")
    assert run(tmp_path, "M1", MAGNITUDE + "modulus = 500.0\nmodulus_every = 4\n", "--participant-config", part) == 0
    folder = tmp_path / "DATA" / "M1"
    rows = read_rows(folder)
    assert len(rows) == 8 and [r["modulus_shown"] for r in rows] == ["1", "0", "0", "0"] * 2
    exp = read_session(folder)["experiment"]
    assert exp["modulus"] == 500.0 and exp["modulus_number"] == 10.0 and exp["unit"] == "N/m"
    ratio = [math.log(float(r["number"]) / (10 * (float(r["level"]) / 500) ** 0.8)) for r in rows]
    assert abs(np.mean(ratio)) < 0.25 and np.std(ratio) < 0.45, ratio
    traces = sorted(p.name for p in (folder / "traces").iterdir())
    assert "modulus_t001_a01.npz" in traces and "stimulus_t001_a01.npz" in traces and len(traces) == 8 + 2
    for r in rows:   # two significant digits, as people answer
        assert float(r["number"]) == float(f"{float(r['number']):.2g}")


def test_a_free_modulus_session_and_its_exponent(tmp_path):
    part = write(tmp_path / "p.toml", "p_reject = 0\np_overpower = 0\np_hard_tap = 0\nstevens_exponent = 1.3\n")
    assert run(tmp_path, "F1", MAGNITUDE.replace("repetitions = 2", "repetitions = 3"), "--participant-config",
               part, seed=5) == 0
    rows = read_rows(tmp_path / "DATA" / "F1")
    x = np.log([float(r["level"]) for r in rows])
    y = np.log([float(r["number"]) for r in rows])
    slope = np.polyfit(x, y, 1)[0]
    assert abs(slope - 1.3) < 0.3 and all(r["modulus"] == "" and r["modulus_shown"] == "0" for r in rows)


@pytest.mark.parametrize("table, message", [
    ('samples = ["firm"]\nlevels = [100.0, 200.0]', "levels must list at least 3 different values"),
    ('samples = ["firm"]\nlevels = [100.0, 200.0, 400.0]\nmodulus_every = 3', "modulus_every is for a session with a modulus"),
    ('samples = ["firm", "wood"]\nlevels = [100.0, 200.0, 400.0]', "sample 'wood' must be a virtual sample"),
    ('samples = "firm"\nlevels = [100.0, 200.0, 400.0]', "samples must be a list of names"),
    ('samples = ["firm"]\nlevels = [100.0, 200.0, 400.0]\nmodulus = -3.0', "modulus must be"),
])
def test_a_bad_table_is_one_error_naming_the_file_and_writes_nothing(tmp_path, capsys, table, message):
    proto = write(tmp_path / "m.toml", QUICK + '[experiment]\nkind = "magnitude"\n' + table + "\n")
    assert main(["run", "--subject", "E1", "--out", str(tmp_path / "DATA"), "--protocol", str(proto)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {proto}") and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "DATA" / "E1").exists()


def test_sigkill_after_a_row_and_mid_trial_then_resume_gives_the_same_rows(tmp_path):
    harness = ForcedChoiceKillHarness(tmp_path, MAGNITUDE + "modulus = 500.0\n", key=KEY)
    assert len(harness.reference) == 8
    where = [s.split(" ", 1)[1] for s in harness.steps]
    rows = [i + 1 for i, w in enumerate(where) if w.startswith("row written")]
    modulus = [i + 1 for i, w in enumerate(where) if "trace written: modulus_t001" in w]
    picks = [rows[2], modulus[0]]   # after a row; after the standard's trace, before the stimulus
    results = [harness.case(step, i) for i, step in enumerate(picks)]
    assert [r.get("error") for r in results] == [None, None], results
    assert all(r["killed"] == -signal.SIGKILL for r in results) and [r["rows_before"] for r in results] == [3, 0]
    for r in results:
        events = [json.loads(ln) for ln in (r["folder"] / "schedule.jsonl").read_text().splitlines()]
        assert [e["event"] for e in events].count("resume") == 1


@pytest.mark.parametrize("typed, taken", [("12.5", "12.5"), ("12,5", "12.5"), ("3e2", "300.0"), ("x", "x"),
                                          ("0", None), ("-4", None), ("abc", None), ("1" * 13, None), ("nan", None),
                                          ("inf", None), ("", None)])
def test_the_numbers_the_runner_takes(typed, taken):
    assert number_key(typed) == taken


def test_numbers_and_adjustment_keys_typed_on_the_subject_page_in_chromium():
    ui = UiState()
    web = WebUI(ui, token="tok").start()
    try:
        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=chromium(), args=["--no-sandbox", "--disable-gpu",
                                                                    "--disable-background-networking", "--no-first-run"])
            page = b.new_page(bypass_csp=True)
            page.goto(web.subject_url)
            ui.set_subject("How strong was it? Type a number and press Enter.", "number", "testing:1:1")
            page.wait_for_function("!document.getElementById('number').hidden")
            page.keyboard.type("abc")
            page.keyboard.press("Enter")
            page.wait_for_function(f"document.getElementById('hint').textContent === {json.dumps(NUMBER_HINT)}")
            assert ui.rating() is None
            page.fill("#number", "")
            page.keyboard.type("12,5")
            page.keyboard.press("Enter")
            assert ui.wait(lambda: ui._rating is not None, 5.0) and ui.rating() == "12.5"
            page.wait_for_function("document.getElementById('number').hidden")
            # the next presentation starts with an empty box
            ui.set_subject("How strong was it?", "number", "testing:2:1")
            page.wait_for_function("!document.getElementById('number').hidden")
            assert page.input_value("#number") == ""
            page.keyboard.type("7")
            page.keyboard.press("Enter")
            assert ui.wait(lambda: ui._rating is not None, 5.0) and ui.rating() == "7.0"
            # the method of adjustment's keys
            ui.set_subject("Does the comparison feel the same?", "adjust", "testing:3:1")
            page.wait_for_function("document.getElementById('message').textContent.startsWith('Does')")
            page.keyboard.press("5")
            page.wait_for_function("document.getElementById('hint').textContent.startsWith('Please use the arrow')")
            page.keyboard.press("PageUp")
            assert ui.wait(lambda: ui._rating is not None, 5.0) and ui.rating() == "PageUp"
            b.close()
    finally:
        web.stop()
