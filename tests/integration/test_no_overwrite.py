"""No command silently overwrites earlier results: an existing output is refused, naming it and --force."""

import pytest

from plumbing.fileio import clear_products, refuse_overwrite
from tests.support.cli import run_cli


def test_refuse_overwrite_names_the_path_and_the_flag(tmp_path):
    assert refuse_overwrite(tmp_path / "new", False) == tmp_path / "new"
    (tmp_path / "empty").mkdir()
    refuse_overwrite(tmp_path / "empty", False)               # an empty folder is fine
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("1")
    with pytest.raises(ValueError, match=r"full exists and is not empty.*pass --force"):
        refuse_overwrite(tmp_path / "full", False)
    with pytest.raises(ValueError, match=r"x exists; not overwriting it.*--force"):
        refuse_overwrite(tmp_path / "full" / "x", False)
    refuse_overwrite(tmp_path / "full", True)


def test_clear_products_removes_only_the_commands_files(tmp_path):
    (tmp_path / "recordings").mkdir()
    (tmp_path / "recordings" / "g7N_t0.csv").write_text("old")
    for name in ("accel_g7N.json", "position_g7N.json", "model_set.json", "notes.txt"):
        (tmp_path / name).write_text("old")
    from devices.cli_identify import IDENTIFY_PRODUCTS

    gone = clear_products(tmp_path, IDENTIFY_PRODUCTS)
    assert sorted(p.name for p in gone) == ["accel_g7N.json", "model_set.json", "position_g7N.json", "recordings"]
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]


def test_commands_refuse_existing_outputs(tmp_path, capsys):
    def cli(*args):
        return run_cli(capsys, *args)

    rec = tmp_path / "REC.csv"
    r = cli("devices", "record", "--device", "sim", "--sample", "wood", "--velocities", "0.1", "--out", str(rec))
    assert r.returncode == 0, r.stderr
    before = rec.read_bytes()
    r = cli("devices", "record", "--device", "sim", "--sample", "wood", "--velocities", "0.2", "--out", str(rec))
    assert r.returncode == 2 and f"error: {rec} exists; not overwriting it" in r.stderr and "--force" in r.stderr
    assert rec.read_bytes() == before
    # identify: refused before the device is touched; the stale model stays untouched
    ident = tmp_path / "ident"
    ident.mkdir()
    (ident / "accel_g7N.json").write_text("{}")
    r = cli("devices", "identify", "--device", "sim", "--grip", "2", "--out", str(ident))
    assert r.returncode == 2 and f"--out {ident} already holds earlier results (accel_g7N.json)" in r.stderr \
        and "--force" in r.stderr
    assert (ident / "accel_g7N.json").read_text() == "{}"
    run = tmp_path / "run"
    r = cli("renderer", "run", "--device", "sim", "--taps", "1", "--no-figure", "--out", str(run))
    assert r.returncode == 0, r.stderr
    r = cli("renderer", "run", "--device", "sim", "--taps", "1", "--out", str(run))
    assert r.returncode == 2 and f"--out {run} already holds earlier results (events.csv, log.npz, run.json)" \
        in r.stderr and "--force" in r.stderr
    r = cli("renderer", "run", "--device", "sim", "--taps", "1", "--out", str(run), "--force")
    assert r.returncode == 0, r.stderr
    report = tmp_path / "REPORT"
    report.mkdir()
    (report / "report.md").write_text("mine")
    r = cli("analysis", "report", str(tmp_path / "DATA"), "--out", str(report))
    assert r.returncode == 2 and f"--out {report} already holds earlier results (report.md)" in r.stderr \
        and "--force" in r.stderr
    assert (report / "report.md").read_text() == "mine"
