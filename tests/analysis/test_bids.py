"""``python -m analysis export-bids``: a rating study and a psychophysics study as BIDS datasets, validated by the
BIDS validator itself (``bids-validator-deno``: the schema validator compiled for Deno, run without Node and
without network access) with no error; the events, sidecars, participants and motion files checked; bad input
refused in one line with nothing written."""

from __future__ import annotations

import csv
import json
import subprocess
from pathlib import Path

import bids_validator_deno
import numpy as np
import pytest
from deno import find_deno_bin

from analysis.__main__ import main as analysis_main
from analysis.synthetic import write_synthetic_study
from study.__main__ import main as study_main

QUICK = "tap_window_s = 0.6\nhoming_after_s = 0.3\nhoming_before_max_s = 0.1\n"
DISCRIMINATION = QUICK + ('[experiment]\nkind = "discrimination"\nsample = "firm"\nreference = 700.0\n'
                          'levels = [500.0, 950.0]\ntrials_per_level = 1\n')
MAGNITUDE = QUICK + '[experiment]\nkind = "magnitude"\nsamples = ["firm"]\nlevels = [300.0, 600.0, 1200.0]\nrepetitions = 1\n'


def validate(folder: Path) -> list[dict]:
    """The BIDS validator's issues for ``folder`` (no network permission given: it validates offline)."""
    bundle = Path(bids_validator_deno.__file__).with_name("bids-validator.js")
    out = subprocess.run([str(find_deno_bin()), "run", "--allow-read", "--allow-env", str(bundle), str(folder),
                          "--json"], capture_output=True, text=True, timeout=300)
    assert out.stdout.strip(), out.stderr
    return json.loads(out.stdout)["issues"]["issues"]


def read_tsv(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh, delimiter="\t"))


@pytest.fixture(scope="module")
def psychophysics(tmp_path_factory):
    """A discrimination session and a magnitude-estimation session on the sim device, one data folder."""
    root = tmp_path_factory.mktemp("psy")
    for name, text in (("d", DISCRIMINATION), ("m", MAGNITUDE)):
        (root / f"{name}.toml").write_text(text)
        assert study_main(["run", "--device", "sim", "--participant", "simulated", "--quiet", "--subject",
                           f"P_{name}", "--seed", "3", "--out", str(root / "DATA"), "--protocol",
                           str(root / f"{name}.toml")]) == 0
    return root / "DATA"


def test_a_rating_study_exports_without_a_validation_error(tmp_path, capsys):
    write_synthetic_study(tmp_path / "DATA", 2, seed=2, traces=1)
    assert analysis_main(["export-bids", str(tmp_path / "DATA"), "--out", str(tmp_path / "BIDS")]) == 0
    assert "2 subject(s), task(s) realism" in capsys.readouterr().out
    issues = validate(tmp_path / "BIDS")
    assert [i for i in issues if i["severity"] == "error"] == []
    bids = tmp_path / "BIDS"
    desc = json.loads((bids / "dataset_description.json").read_text())
    assert desc["BIDSVersion"] == "1.10.0" and desc["GeneratedBy"][0]["Name"] == "hfam-haptics"
    participants = read_tsv(bids / "participants.tsv")
    assert [p["participant_id"] for p in participants] == ["sub-S001", "sub-S002"]
    events = read_tsv(bids / "sub-S001" / "beh" / "sub-S001_task-realism_events.tsv")
    trials = list(csv.DictReader(open(tmp_path / "DATA" / "S001" / "trials.csv", newline="")))
    assert len(events) == len(trials)
    onsets = [float(e["onset"]) for e in events]
    assert onsets == sorted(onsets) and onsets[0] >= 0
    sidecar = json.loads((bids / "task-realism_events.json").read_text())
    assert set(events[0]) <= set(sidecar) | {"TaskName"}                    # every column described
    assert sidecar["incoming_velocity_mean_m_s"]["Units"] == "m/s" and sidecar["onset"]["Units"] == "s"
    scans = read_tsv(bids / "sub-S001" / "sub-S001_scans.tsv")
    assert len(scans) == len(list((tmp_path / "DATA" / "S001" / "traces").glob("*.npz"))) > 0
    assert all((bids / "sub-S001" / s["filename"]).is_file() for s in scans)


def test_a_psychophysics_study_exports_with_its_motion_data(psychophysics, tmp_path):
    assert analysis_main(["export-bids", str(psychophysics), "--out", str(tmp_path / "BIDS"),
                          "--motion-rate-hz", "500"]) == 0
    issues = validate(tmp_path / "BIDS")
    assert [i for i in issues if i["severity"] == "error"] == []
    bids = tmp_path / "BIDS"
    assert {p.name for p in bids.glob("task-*_events.json")} == {"task-discrimination_events.json",
                                                                  "task-magnitude_events.json"}
    channels = read_tsv(next((bids / "sub-Pd" / "motion").glob("*run-1_channels.tsv")))
    assert [c["type"] for c in channels][:3] == ["LATENCY", "POS", "ACCEL"]
    meta = json.loads(next((bids / "sub-Pd" / "motion").glob("*run-1_motion.json")).read_text())
    assert meta["SamplingFrequency"] == 500.0 and meta["MotionChannelCount"] == len(channels)
    # the first run is the first trial's first interval: its position decimated 20-fold, anti-aliased
    trace = np.load(psychophysics / "P_d" / "traces" / "interval1_t001_a01.npz")
    motion = np.loadtxt(next((bids / "sub-Pd" / "motion").glob("*run-1_motion.tsv")), delimiter="\t")
    assert np.allclose(motion[:, 0], trace["t_s"][::20][:len(motion)])
    assert np.max(np.abs(motion[5:-5, 1] - trace["position_m"][::20][5:len(motion) - 5])) < 2e-4
    events = read_tsv(bids / "sub-Pm" / "beh" / "sub-Pm_task-magnitude_events.tsv")
    assert [e["trial_type"] for e in events] == ["firm"] * 3 and {e["number"] != "n/a" for e in events} == {True}


def test_bad_input_is_one_error_line_and_nothing_written(tmp_path, capsys):
    for sub in ("S_1", "S-1"):
        write_synthetic_study(tmp_path / "tmp" / sub, 1, seed=1)
        (tmp_path / "tmp" / sub / "S001").rename(tmp_path / f"x{sub}")
    data = tmp_path / "DATA"
    data.mkdir()
    for sub in ("S_1", "S-1"):
        (tmp_path / f"x{sub}").rename(data / sub)
        session = json.loads((data / sub / "session.json").read_text())
        session["subject"] = sub
        (data / sub / "session.json").write_text(json.dumps(session))
        rows = (data / sub / "trials.csv").read_text().replace("S001,", f"{sub},")
        (data / sub / "trials.csv").write_text(rows)
    assert analysis_main(["export-bids", str(data), "--out", str(tmp_path / "B")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: subjects 'S-1' and 'S_1' both become sub-S1") and err.count("\n") == 1, err
    assert not (tmp_path / "B").exists() and not list(tmp_path.glob(".B*"))
    assert analysis_main(["export-bids", str(tmp_path / "none"), "--out", str(tmp_path / "B")]) == 2
    assert "not a folder" in capsys.readouterr().err
    assert analysis_main(["export-bids", str(data), "--out", str(data / "inside")]) == 2
    assert "must not be inside the data folder" in capsys.readouterr().err
