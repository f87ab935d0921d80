"""The method of adjustment end to end on the sim device: the plan, a session in a counterbalanced design's
order, the comparison rendered at the values recorded, the simulated participant's constant error, bad tables,
the servo process, and SIGKILL then ``--resume`` giving the uninterrupted run's rows."""

import json
import math
import signal
from pathlib import Path

import numpy as np
import pytest

from devices.sim import SimDevice
from stimuli import load_catalog
from study.__main__ import main
from study.adjustment.experiment import AdjustmentConfig, plan_trials
from study.adjustment.kind import Adjustment
from study.design.blocks import block_order
from study.session.config import protocol_from, read_protocol_file
from study.forcedchoice.perception import tap_stiffness_N_m
from study.varied import varied_name

from tests.support.kills import QUICK, ForcedChoiceKillHarness
from tests.support.study import read_rows, read_session, write

ADJUST = QUICK + """
[experiment]
kind = "adjustment"
sample = "firm"
references = [500.0, 800.0]
trials_per_reference = 2
"""
ROOT = Path(__file__).resolve().parents[3]
KEY = ("trial", "attempt", "block", "condition", "start_value", "start_side", "final_value", "matched", "n_steps",
       "values")


def run(tmp, subject, protocol, *extra, seed=2):
    proto = write(tmp / f"{subject}.toml", protocol)
    return main(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject", subject,
                 "--seed", str(seed), "--out", str(tmp / "DATA"), "--protocol", str(proto), *map(str, extra)])


def test_the_shipped_example_loads_and_plans():
    """examples/adjustment.toml: the protocol's keys, the kind's settings, the references derived from the
    default catalog at 400, 700 and 1000 N/m, and 132 trials (44 per reference: 22 above, 22 below)."""
    path = ROOT / "examples" / "adjustment.toml"
    data, table = read_protocol_file(path)
    assert protocol_from(data, path).tap_window_s == 3.0
    exp = Adjustment.configure(table, str(path))
    refs = Adjustment.samples(exp, lambda _: load_catalog(None), str(path))
    assert exp.conditions == ["400", "700", "1000"] and len(refs) == 3
    assert sorted(s.stiffness_N_m for s in refs) == [400.0, 700.0, 1000.0]
    _, order = block_order(exp.conditions, exp.order, exp.design, "S01", 1, str(path))
    plan = plan_trials(exp, order, 1, "S01")
    assert len(plan) == 132 and sorted(order) == sorted(exp.conditions)
    for cond in exp.conditions:
        assert sorted(t.side for t in plan if t.condition == cond) == ["above"] * 22 + ["below"] * 22


def test_the_plan_starts_half_above_half_below_seeded_per_subject():
    exp = AdjustmentConfig(sample="firm", references=[500.0, 800.0], trials_per_reference=7)
    plan = plan_trials(exp, ["800", "500"], 3, "S1")
    assert [t.trial for t in plan] == list(range(1, 15)) and [t.block for t in plan] == [1] * 7 + [2] * 7
    assert [t.condition for t in plan] == ["800"] * 7 + ["500"] * 7
    for block in (1, 2):
        sides = [t.side for t in plan if t.block == block]
        assert sorted(sides).count("above") in (3, 4) and len(sides) == 7
    for t in plan:   # above: a factor 1.2-1.6 over the reference, below: under it, on the grid of 2 % steps
        f = exp.value(1.0, t.start_k)
        assert (1.2 / 1.02 <= f <= 1.6 * 1.02) if t.side == "above" else (1 / 1.6 / 1.02 <= f <= 1 / 1.2 * 1.02)
    assert plan_trials(exp, ["800", "500"], 3, "S1") == plan
    assert plan_trials(exp, ["800", "500"], 3, "S2") != plan


def test_a_session_runs_in_the_designs_order_and_renders_the_values_it_records(tmp_path):
    plist = write(tmp_path / "people.txt", "K\nL\nM\nN\n")
    assert main(["design", "--participants", str(plist), "--conditions", "500,800", "--out",
                 str(tmp_path / "design")]) == 0
    text = (tmp_path / "design" / "design.csv").read_text().splitlines()
    want = next(line.split(",")[2].split(";") for line in text[1:] if line.startswith("M,"))
    assert run(tmp_path, "M", ADJUST + 'design = "design/design.csv"\n') == 0
    folder = tmp_path / "DATA" / "M"
    rows = read_rows(folder)
    session = read_session(folder)
    exp = session["experiment"]
    assert exp["order"] == want and exp["design_file"] == str(tmp_path / "design" / "design.csv")
    assert exp["config"]["order"] == want and exp["unit"] == "N/m" and exp["reference_values"] == {"500": 500.0,
                                                                                                   "800": 800.0}
    assert [r["condition"] for r in rows] == [want[0]] * 2 + [want[1]] * 2
    assert {r["sequence"] for r in rows} == {str(exp["sequence"])} and exp["sequence"] >= 1
    fpa = SimDevice().info.force_per_amp_N_A
    ratios = []
    for r in rows:
        values = [float(v) for v in r["values"].split(";")]
        ref = float(r["reference_value"])
        assert values[0] == float(r["start_value"]) and values[-1] == float(r["final_value"])
        assert (values[0] > ref) == (r["start_side"] == "above") and r["matched"] == "1"
        steps = [math.log(v / ref) / math.log(1.02) for v in values]
        assert np.allclose(steps, np.round(steps), atol=1e-6)            # on the grid of 2 % steps
        assert int(r["n_comparisons"]) == len(values) and int(r["n_steps"]) == len(values) - 1
        # every comparison rendered what its row says (force over penetration on the sim)
        t = f"t{int(r['trial']):03d}_a{int(r['attempt']):02d}"
        for j, v in enumerate(values, start=2):
            trace = dict(np.load(folder / "traces" / f"comparison{j:02d}_{t}.npz"))
            assert str(trace["sample"]) == varied_name("firm", "stiffness_N_m", v)
            ratios.append(np.nanmedian(tap_stiffness_N_m(trace, fpa)) / v)
        trace = dict(np.load(folder / "traces" / f"reference01_{t}.npz"))
        ratios.append(np.nanmedian(tap_stiffness_N_m(trace, fpa)) / ref)
    # a tap's force at its deepest point over that depth: the rendered stiffness (a hard tap's current limit
    # or its bounce can take a few per cent off one tap)
    assert np.median(ratios) == pytest.approx(1.0, abs=0.002) and min(ratios) > 0.85 and max(ratios) < 1.02


def test_the_simulated_participants_constant_error_shows_in_its_matches(tmp_path):
    """A participant told to over-adjust by 25 % sets the comparison above the reference (8 matches: the
    geometric mean within the noise of 8 settings, about 8 %)."""
    part = write(tmp_path / "biased.toml", "adjust_bias_frac = 0.25\np_reject = 0\np_overpower = 0\np_hard_tap = 0\n")
    protocol = ADJUST.replace("references = [500.0, 800.0]", "references = [600.0]").replace(
        "trials_per_reference = 2", "trials_per_reference = 8")
    assert run(tmp_path, "B", protocol, "--participant-config", part, seed=7) == 0
    finals = [float(r["final_value"]) for r in read_rows(tmp_path / "DATA" / "B")]
    pse = math.exp(np.mean(np.log(finals)))
    assert 1.25 * 600 * 0.8 < pse < 1.25 * 600 * 1.2, finals


@pytest.mark.parametrize("table, message", [
    ('sample = "firm"', "give the conditions as references (values of vary) or as reference_samples"),
    ('sample = "firm"\nreferences = [500.0]\nstart_factors = [0.9, 1.5]', "start_factors must be [low, high]"),
    ('sample = "firm"\nreferences = [500.0]\nvary = "amplitude_Ns_m"',
     "sample 'firm' has no transient, so only stiffness_N_m can vary"),
    ('sample = "pulse_firm"\nreferences = [5.0]\nvary = "decay"', "'decay' is not a parameter of sample 'pulse_firm'"),
    ('sample = "firm"\nreference_samples = ["wood"]', "sample 'wood' must be a virtual sample"),
    ('sample = "firm"\nreferences = [500.0]\nstep = 0.02\nrefrences = 3', "unknown [experiment] key(s) ['refrences']"),
    ('sample = "firm"\nreferences = [500.0, 800.0]\norder = ["500"]', "order ['500'] must list each condition once"),
    ('sample = "firm"\nreferences = [500.0, 800.0]\ndesign = "nowhere.csv"', "nowhere.csv"),
])
def test_a_bad_table_is_one_error_naming_the_file_and_writes_nothing(tmp_path, capsys, table, message):
    proto = write(tmp_path / "a.toml", QUICK + '[experiment]\nkind = "adjustment"\n' + table + "\n")
    assert main(["run", "--subject", "E1", "--out", str(tmp_path / "DATA"), "--protocol", str(proto)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "DATA" / "E1").exists()


def test_in_the_servo_process_the_comparisons_are_made_and_released_there(tmp_path):
    assert run(tmp_path, "I1", ADJUST.replace("trials_per_reference = 2", "trials_per_reference = 1"),
               "--servo-process", "on") == 0
    rows = read_rows(tmp_path / "DATA" / "I1")
    assert len(rows) == 2 and read_session(tmp_path / "DATA" / "I1")["device"]["servo_process"] is True


def test_sigkill_after_a_row_and_mid_trial_then_resume_gives_the_same_rows(tmp_path):
    harness = ForcedChoiceKillHarness(tmp_path, ADJUST, key=KEY)
    assert len(harness.reference) == 4
    where = [s.split(" ", 1)[1] for s in harness.steps]
    rows = [i + 1 for i, w in enumerate(where) if w.startswith("row written")]
    comparisons = [i + 1 for i, w in enumerate(where) if "trace written: comparison03" in w]
    # after a row (the next trial not started), and mid-trial (the reference and two comparisons on disk)
    picks = [rows[0], comparisons[2]]
    results = [harness.case(step, i) for i, step in enumerate(picks)]
    assert [r.get("error") for r in results] == [None, None], results
    assert all(r["killed"] == -signal.SIGKILL for r in results) and [r["rows_before"] for r in results] == [1, 2]
    for r in results:
        events = [json.loads(ln) for ln in (r["folder"] / "schedule.jsonl").read_text().splitlines()]
        assert [e["event"] for e in events].count("resume") == 1
        assert read_session(r["folder"])["finished_at"] is not None
