"""``python -m stimuli build-library`` and ``show`` end to end, through real files."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from devices.recording import record_taps, write_tap_recording
from devices.sim import SimDevice
from stimuli import HfamLibrary
from stimuli.__main__ import main
from tests.support.cli import run_cli
from tests.support.files import sha256
from tests.support.stimuli import (
    minimum_phase_model,
    rhp_zero_model,
    synthetic_taps,
    write_taps_csv,
)

VELOCITIES = (0.04, 0.06, 0.08, 0.1, 0.13, 0.16, 0.2, 0.25, 0.3, 0.35)


def _numeric_row(line: str) -> bool:
    parts = line.split()
    try:
        [float(x) for x in parts[:6]]
    except ValueError:
        return False
    return len(parts) >= 6


@pytest.fixture
def inputs(tmp_path):
    rec = tmp_path / "rec.csv"
    write_taps_csv(rec, synthetic_taps(VELOCITIES, noise=0.02))
    m1 = minimum_phase_model(grip_N=1.0).save(tmp_path / "grip1.json")
    m2 = rhp_zero_model(grip_N=4.0).save(tmp_path / "grip4.json")
    return rec, m1, m2


def test_build_library_and_show(tmp_path, inputs, capsys):
    rec, m1, m2 = inputs
    out = tmp_path / "lib.npz"
    rc = main(["build-library", "--recordings", str(rec), "--model", str(m2), "--model", str(m1), "--out", str(out),
               "--device", "none", "--force-per-amp", "2.35", "--peak-current-A", "50"])
    text = capsys.readouterr().out
    assert rc == 0
    assert "selected 8 taps" in text and "not needed for 8 evenly spaced velocities" in text
    assert "verification through the forward models, 20-1000 Hz" in text
    rows = [ln.split() for ln in text.splitlines() if _numeric_row(ln)]
    assert len(rows) == 16
    assert max(float(r[4]) for r in rows) < 0.1  # NRMSE column
    lib = HfamLibrary.load(out)
    assert lib.currents_A.shape == (8, 2, 1000) and lib.grips_N.tolist() == [1.0, 4.0]
    meta = lib.metadata
    assert meta["source_files"]["recordings"]["path"] == str(rec)
    assert len(meta["source_files"]["recordings"]["sha256"]) == 64
    assert [m["name"] for m in meta["models"]] == [str(m1), str(m2)]
    assert meta["settings"]["smooth_hz"] == 500.0 and meta["software_version"].startswith("hfam-haptics")
    assert len(meta["verification"]) == 16
    # refuses to overwrite
    assert main(["build-library", "--recordings", str(rec), "--model", str(m1), "--out", str(out),
                 "--device", "none", "--force-per-amp", "2.35"]) == 2
    assert "lib.npz exists; not overwriting it: choose another --out or pass --force to replace it" in capsys.readouterr().err
    # show
    png = tmp_path / "fig.png"
    assert main(["show", str(out), "--out", str(png)]) == 0
    text = capsys.readouterr().out
    assert "8 velocities x 2 grip level(s) x 1000 samples at 10000 Hz" in text
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20000


def test_build_library_peak_limit_message(tmp_path, inputs, capsys):
    rec, m1, _ = inputs
    rc = main(["build-library", "--recordings", str(rec), "--model", str(m1), "--out", str(tmp_path / "x.npz"),
               "--device", "none", "--force-per-amp", "2.35", "--peak-current-A", "0.05"])
    err = capsys.readouterr().err
    assert rc == 2 and "error: transient at velocity" in err and "grip 1 N" in err and "--scale-to-limit" in err
    assert not (tmp_path / "x.npz").exists()
    rc = main(["build-library", "--recordings", str(rec), "--model", str(m1), "--out", str(tmp_path / "x.npz"),
               "--device", "none", "--force-per-amp", "2.35", "--peak-current-A", "0.05", "--scale-to-limit"])
    out = capsys.readouterr().out
    assert rc == 0 and "warning: scaled transient at velocity" in out
    assert np.max(np.abs(HfamLibrary.load(tmp_path / "x.npz").currents_A)) <= 0.05 + 1e-12


def test_build_library_uses_device_limits_and_rate(tmp_path, inputs, capsys):
    rec, m1, _ = inputs
    out = tmp_path / "sim.npz"
    assert main(["build-library", "--recordings", str(rec), "--model", str(m1), "--out", str(out),
                 "--peak-current-A", "50"]) == 0
    lib = HfamLibrary.load(out)
    assert lib.force_per_amp_N_A == pytest.approx(2.35) and lib.metadata["device"] == "sim"


@pytest.mark.parametrize("which,match", [("model", "not stable"), ("improper", "improper"),
                                         ("recordings", "missing column")])
def test_bad_files_exit_2_naming_the_file(tmp_path, inputs, capsys, which, match):
    rec, m1, _ = inputs
    if which == "model":
        data = json.loads(m1.read_text())
        data["poles_rad_s"].append([25.0, 0.0])
        data["zeros_rad_s"].append([-3.0, 0.0])
        m1.write_text(json.dumps(data))
        bad = m1
    elif which == "improper":
        data = json.loads(m1.read_text())
        data["zeros_rad_s"] += [[-1.0, 0.0]] * (len(data["poles_rad_s"]) + 1 - len(data["zeros_rad_s"]))
        m1.write_text(json.dumps(data))
        bad = m1
    else:
        rec.write_text("tap,t_s,accel_m_s2\n0,0.0,1.0\n")
        bad = rec
    rc = main(["build-library", "--recordings", str(rec), "--model", str(m1), "--out", str(tmp_path / "o.npz"),
               "--device", "none", "--force-per-amp", "2.35"])
    err = capsys.readouterr().err
    assert rc == 2 and str(bad) in err and match in err


def test_module_help_runs():
    res = subprocess.run([sys.executable, "-m", "stimuli", "build-library", "--help"], capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 0 and "--recordings" in res.stdout and "--scale-to-limit" in res.stdout


def test_model_set_directory_expands_to_its_accel_models(tmp_path, inputs, capsys):
    rec, m1, m2 = inputs
    mset = tmp_path / "set"
    mset.mkdir()
    m1.rename(mset / "accel_g1N.json")
    m2.rename(mset / "accel_g4N.json")
    (mset / "model_set.json").write_text(json.dumps({"kind": "model_set", "grip_N": [1.0, 4.0],
                                                    "models": {"accel_m_s2": ["accel_g1N.json", "accel_g4N.json"],
                                                               "position_m": [None, None]}}))
    out = tmp_path / "lib.npz"
    assert main(["build-library", "--recordings", str(rec), "--model", str(mset), "--out", str(out),
                 "--device", "none", "--force-per-amp", "2.35"]) == 0
    assert HfamLibrary.load(out).grips_N.tolist() == [1.0, 4.0]


def test_build_library_refine_reports_error_per_iteration(tmp_path, capsys):
    """--refine plays each transient on the sim and prints the error before and after every pass (issue 16)."""
    dev = SimDevice(seed=0, sample="wood_on_foam")
    fs = dev.info.servo_rate_hz
    taps = [t for v in (0.06, 0.1) for t in record_taps(dev, [v], grip_N=2.0,
                                                        trajectory_options={"press_depth_m": v * 0.045 / 1.5})]
    rec = write_tap_recording(tmp_path / "rec.csv", taps, fs)
    model = dev.linear_model(2.0).save(tmp_path / "g2.json")
    out = tmp_path / "lib.npz"
    assert main(["build-library", "--recordings", str(rec), "--model", str(model), "--out", str(out),
                 "--n-velocities", "2", "--scale-to-limit", "--refine", "2", "--refine-gain", "0.5",
                 "--refine-max-lag", "0.001", "--refine-recordings", "1"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("refinement iteration")]
    # 2 passes towards the smoothed target (0-2), then 1 towards the recordings (3: before, 4: after)
    assert [ln.split(":")[0] for ln in lines] == [f"refinement iteration {i}" for i in range(5)]
    assert [ln.endswith("target: smoothed)") for ln in lines] == [True] * 3 + [False] * 2
    for a, b in ((0, 2), (3, 4)):
        first, last = (float(ln.split("median ")[1].split(",")[0]) for ln in (lines[a], lines[b]))
        assert last <= first
    meta = HfamLibrary.load(out).metadata["refinement"]
    assert meta["iterations"] == 2 and meta["gain"] == 0.5 and meta["recording_iterations"] == 1


@pytest.mark.parametrize("case,match", [
    ("entry_number", ": key 'models.accel_m_s2'[0] must be a file name or null"),
    ("models_list", ": key 'models' must be an object of output -> list of files"),
    ("no_kind", ": key 'kind' must be \"model_set\""),
    ("csv_nonutf8", ":3: tap recording is not UTF-8 text (invalid start byte at byte "),
])
def test_build_library_refuses_bad_model_set_or_recording_like_validate(tmp_path, inputs, capsys, case, match):
    """Audit modelset_entry_number_build.txt, csv_nonutf8.txt: a number as a model file name was a raw TypeError
    (build-library had its own index parser); it now uses devices.identify.modelset's checks, the same message
    ``devices validate`` gives. A non-UTF-8 recording names the file and line. Exit 2, one ``error:`` line."""
    rec, m1, _ = inputs
    mset = tmp_path / "ms4"
    mset.mkdir()
    m1.rename(mset / "accel_g1N.json")
    index = {"kind": "model_set", "grip_N": [1.0, 4.0], "models": {"accel_m_s2": [5, "accel_g1N.json"]}}
    if case == "models_list":
        index["models"] = [["accel_g1N.json"]]
    elif case == "no_kind":
        del index["kind"]
    elif case == "csv_nonutf8":
        index["models"]["accel_m_s2"] = ["accel_g1N.json"]
        index["grip_N"] = [1.0]
        raw = rec.read_bytes().split(b"\n")
        raw[2] = raw[2] + b"\xff"
        rec.write_bytes(b"\n".join(raw))
    (mset / "model_set.json").write_text(json.dumps(index))
    bad = rec if case == "csv_nonutf8" else mset / "model_set.json"
    res = run_cli(capsys, "stimuli", "build-library", "--recordings", str(rec), "--model",
                  str(mset), "--out", str(tmp_path / "x.npz"), "--device", "none", "--force-per-amp-N-A", "2.35")
    assert res.returncode == 2, res.stderr
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:") or "Traceback" in ln]
    assert len(errors) == 1 and errors[0].startswith(f"error: {bad}{match}"), res.stderr
    assert not (tmp_path / "x.npz").exists()
    if case == "entry_number":   # the same words as `python -m devices validate ms4`
        val = run_cli(capsys, "devices", "validate", str(mset))
        assert val.returncode == 2 and errors[0] in val.stderr.splitlines(), val.stderr


@pytest.mark.parametrize("key", ["gain", "delay_s", "poles_rad_s"])
def test_build_library_refuses_a_400_digit_integer_in_a_model(tmp_path, inputs, capsys, key):
    """Audit model_bigint_gain.txt: a 400-digit integer gain raised OverflowError out of the model check; now
    exit 2 with one ``error:`` line naming the model file and key."""
    rec, m1, _ = inputs
    data = json.loads(m1.read_text())
    data[key] = [[-(10 ** 400), 0]] + data[key] if key == "poles_rad_s" else 10 ** 400
    m1.write_text(json.dumps(data))
    res = run_cli(capsys, "stimuli", "build-library", "--recordings", str(rec), "--model",
                  str(m1), "--out", str(tmp_path / "x.npz"), "--device", "none", "--force-per-amp-N-A", "2.35")
    assert res.returncode == 2, res.stderr
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:") or "Traceback" in ln]
    assert len(errors) == 1 and re.match(re.escape(f"error: {m1}: key ") + f"'?{key}'?", errors[0]), res.stderr
    assert "finite" in errors[0] and not (tmp_path / "x.npz").exists()


def test_build_library_names_a_model_file_that_is_not_utf8(tmp_path, inputs, capsys):
    """Audit model_nonutf8.txt: a model file that is not UTF-8 gave the codec's message without the file; now
    one ``error:`` line naming the file and line (plumbing.fileio.read_json_file, every JSON model/index reader)."""
    rec, m1, _ = inputs
    m1.write_bytes(m1.read_bytes().replace(b"{", b"{\n\"note\": \"\xff\",", 1))
    res = run_cli(capsys, "stimuli", "build-library", "--recordings", str(rec), "--model",
                  str(m1), "--out", str(tmp_path / "x.npz"), "--device", "none", "--force-per-amp-N-A", "2.35")
    assert res.returncode == 2, res.stderr
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:") or "Traceback" in ln]
    assert errors == [f"error: {m1}:2: model file is not UTF-8 text (invalid start byte at byte {m1.read_bytes().index(0xff)})"], \
        res.stderr
    assert not (tmp_path / "x.npz").exists()

def test_show_keeps_the_tap_recording_the_library_is_named_after(tmp_path, inputs, capsys):
    """Auditor: ``stimuli show wood.npz`` wrote wood.png/.svg and replaced the recording wood.csv with the plot's
    data. The plot's data is ``<stem>.plot.csv``; a second show refuses, naming every existing file, unless --force."""
    rec, m1, _ = inputs
    wood = tmp_path / "wood.csv"
    wood.write_bytes(rec.read_bytes())
    lib = tmp_path / "wood.npz"
    assert main(["build-library", "--recordings", str(wood), "--model", str(m1), "--out", str(lib),
                 "--device", "none", "--force-per-amp", "2.35", "--peak-current-A", "50"]) == 0
    before = sha256(wood)

    def show(*extra):
        return run_cli(capsys, "stimuli", "show", "wood.npz", *extra, cwd=tmp_path)

    res = show()
    assert res.returncode == 0, res.stderr
    assert sha256(wood) == before                                       # the recording survives
    assert wood.read_text().startswith("tap,incoming_velocity_m_s,t_s,accel_m_s2")
    plot_csv = tmp_path / "wood.plot.csv"
    assert plot_csv.read_text().startswith("t_ms,")
    sums = {p.name: sha256(p) for p in (tmp_path / "wood.png", tmp_path / "wood.svg", plot_csv)}
    # a second show refuses before drawing, naming each file it would replace
    res = show()
    assert res.returncode == 2
    err = res.stderr.strip()
    assert err.startswith("error: ") and len(err.splitlines()) == 1
    assert "wood.png" in err and "wood.svg" in err and "wood.plot.csv" in err and "--force" in err
    assert {n: sha256(tmp_path / n) for n in sums} == sums and sha256(wood) == before
    # an existing data file alone is enough to refuse
    (tmp_path / "wood.png").unlink()
    (tmp_path / "wood.svg").unlink()
    res = show()
    assert res.returncode == 2 and "wood.plot.csv" in res.stderr and not (tmp_path / "wood.png").exists()
    # --force replaces the figure's own files, still not the recording
    res = show("--force")
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "wood.png").exists() and sha256(wood) == before
    # --out naming a folder: refused (it wrote <folder>.png/.svg/.plot.csv beside it and said "wrote <folder>")
    (tmp_path / "figs").mkdir()
    res = show("--out", "figs")
    assert res.returncode == 2 and res.stderr.strip().startswith("error: figs is a folder; a figure is written as "
                                                                 "files (figs.png, ...)"), res.stderr
    assert not (tmp_path / "figs.png").exists() and not any((tmp_path / "figs").iterdir())
    res = show("--out", "figs/lib")
    assert res.returncode == 0 and f"wrote {Path('figs/lib.png')}" in res.stdout, (res.stdout, res.stderr)


@pytest.fixture
def _stimuli(capsys):
    def run(tmp_path, *args):
        return run_cli(capsys, "stimuli", *args, cwd=tmp_path)
    return run


def test_sim_library_refuses_an_existing_out_unless_forced(tmp_path, _stimuli):
    """Auditor (simlib_overwrite): ``sim-library --out my_results.npz`` replaced the user's file."""
    mine = tmp_path / "my_results.npz"
    mine.write_text("my precious library\n")
    res = _stimuli(tmp_path, "sim-library", "--out", "my_results.npz")
    assert res.returncode == 2
    assert res.stderr.strip() == ("error: my_results.npz exists; not overwriting it: choose another --out or pass "
                                  "--force to replace it")
    assert mine.read_text() == "my precious library\n"
    (tmp_path / "adir").mkdir()
    res = _stimuli(tmp_path, "sim-library", "--out", "adir", "--force")
    assert res.returncode == 2 and "error: --out adir is a folder" in res.stderr
    # with --force an existing file passes the check (the whole pipeline the command then runs, ~30 s, is
    # exercised by `make artefacts` and checked by tests/plumbing/test_artefacts.py's stamp of the shipped library)
    from plumbing.fileio import check_output_file
    check_output_file(mine, True)
    assert mine.read_text() == "my precious library\n"


def test_build_library_out_below_a_file_is_refused_before_building(tmp_path, inputs, _stimuli):
    """Auditor (build_out_parent_file): the whole build ran, then a traceback at mkdir."""
    rec, m1, _ = inputs
    (tmp_path / "afile").write_text("my file\n")
    res = _stimuli(tmp_path, "build-library", "--recordings", rec, "--model", m1, "--device", "none",
                   "--force-per-amp-N-A", "2.35", "--out", "afile/lib.npz")
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.strip() == "error: cannot write --out afile/lib.npz: afile is a file, not a folder"
    assert "reading" not in res.stdout                          # refused before reading or building
    assert (tmp_path / "afile").read_text() == "my file\n"
