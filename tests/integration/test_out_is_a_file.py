"""Output folders that are files (auditor: synthetic_out_is_file, teleop_out_is_file, and ``renderer demo
--cache-dir`` on a file): each was a NotADirectoryError/FileExistsError traceback; now one ``error:`` line naming
the path, exit 2, before anything runs, and the user's file untouched."""

import pytest

from tests.support.cli import run_cli


@pytest.mark.parametrize("cmd,message", [
    (["analysis", "synthetic", "afile"],
     "error: afile is a file, not a folder; synthetic data is written into a new or empty folder"),
    (["renderer", "teleop", "--out", "afile"], "error: --out afile is a file, not a folder"),
    (["renderer", "teleop", "--out", "afile/s1"], "error: cannot write --out afile/s1: afile is a file, not a folder"),
    (["renderer", "demo", "--cache-dir", "afile", "--out", "demo"], "error: --cache-dir afile is a file, not a folder"),
])
def test_an_output_folder_that_is_a_file_is_one_error_line(tmp_path, capsys, cmd, message):
    (tmp_path / "afile").write_text("my file\n")
    res = run_cli(capsys, *cmd, cwd=tmp_path)
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert res.stderr.strip() == message, res.stderr
    assert (tmp_path / "afile").read_text() == "my file\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]  # nothing was started
