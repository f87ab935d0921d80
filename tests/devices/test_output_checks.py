"""Output paths are checked before anything is measured (auditor: validate_plot_overwrite, record_out_dir,
record_out_parent_file, linearity_out_is_file): one ``error:`` line naming the path, exit 2, the user's files
byte for byte as they were."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.support.cli import run_cli
from tests.support.files import sha256
from tests.support.stimuli import minimum_phase_model


@pytest.fixture
def _devices(capsys):
    def run(tmp: Path, *args):
        return run_cli(capsys, "devices", *args, cwd=tmp)
    return run


def _one_error_line(res, *words):
    assert res.returncode == 2, (res.stdout, res.stderr)
    err = res.stderr.strip()
    assert err.startswith("error: ") and len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, err
    return err


def test_validate_plot_refuses_an_existing_file_before_measuring(tmp_path, _devices):
    model = minimum_phase_model(grip_N=2.0).save(tmp_path / "accel_g2N.json")
    fig = tmp_path / "myfig.png"
    fig.write_text("my figure\n")
    before = sha256(fig)
    res = _devices(tmp_path, "validate", model, "--device", "sim", "--plot", "myfig.png")
    _one_error_line(res, "myfig.png", "--force")
    assert "time-domain validation" not in res.stdout          # refused before measuring
    assert sha256(fig) == before
    res = _devices(tmp_path, "validate", model, "--device", "sim", "--plot", "myfig.png", "--force")
    assert res.returncode == 0, res.stderr
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("out, words", [
    ("adir", ["--out adir is a folder"]),                     # an existing (empty) folder
    ("afile/rec.csv", ["afile/rec.csv", "afile is a file, not a folder"]),
])
def test_record_checks_out_before_tapping(tmp_path, _devices, out, words):
    (tmp_path / "adir").mkdir()
    (tmp_path / "afile").write_text("my file\n")
    before = sha256(tmp_path / "afile")
    for force in ((), ("--force",)):
        res = _devices(tmp_path, "record", "--device", "sim", "--velocities-m-s", "0.05", "--out", out, *force)
        _one_error_line(res, *words)
        assert "tap 0" not in res.stdout
    assert sha256(tmp_path / "afile") == before and not any((tmp_path / "adir").iterdir())


def test_linearity_out_that_is_a_file_is_refused_before_measuring(tmp_path, _devices):
    (tmp_path / "afile").write_text("my file\n")
    before = sha256(tmp_path / "afile")
    res = _devices(tmp_path, "linearity", "--device", "sim", "--trials", "2", "--out", "afile")
    _one_error_line(res, "--out afile is a file, not a folder")
    assert "[1/7]" not in res.stdout                            # before the first condition
    assert sha256(tmp_path / "afile") == before


def test_linearity_report_is_staged_and_keeps_the_users_files(tmp_path, capsys):
    """Its report is written beside --out and swapped in (an earlier one refused without --force, replaced with
    it; the folder's other files kept); a study's subject folder is refused whatever --force."""
    from devices.__main__ import main
    out = tmp_path / "L"
    out.mkdir()
    (out / "notes.txt").write_text("the user's\n")
    (out / "linearity.json").write_text("{}\n")                 # an earlier report
    args = ["linearity", "--device", "sim", "--trials", "2", "--out", str(out)]
    assert main(args) == 2
    assert f"--out {out} already holds a linearity report (linearity.json)" in capsys.readouterr().err
    assert main(args + ["--force"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["linearity.json", "linearity.plot.csv", "linearity.png",
                                                     "linearity.svg", "linearity.txt", "notes.txt"]
    assert (out / "notes.txt").read_text() == "the user's\n" and "conclusion" in (out / "linearity.json").read_text()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]   # no staging folder, no lock
    subject = tmp_path / "DATA" / "S01"
    subject.mkdir(parents=True)
    (subject / "session.json").write_text("{}")
    (subject / "trials.csv").write_text("subject\n")
    capsys.readouterr()
    assert main(["linearity", "--device", "sim", "--trials", "2", "--out", str(subject), "--force"]) == 2
    assert "is the subject folder" in capsys.readouterr().err
    assert sorted(p.name for p in subject.iterdir()) == ["session.json", "trials.csv"]
