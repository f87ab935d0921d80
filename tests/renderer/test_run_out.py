"""``renderer run --out`` is checked before the run (auditor: renderer_out_parent_file: the taps ran, then a
traceback at mkdir): one ``error:`` line naming the path, exit 2, the user's file untouched."""

from tests.support.cli import run_cli


def test_run_out_below_a_file_is_refused_before_the_run(tmp_path, capsys):
    (tmp_path / "afile").write_text("my file\n")
    for out in ("afile/run1", "afile"):
        res = run_cli(capsys, "renderer", "run", "--device", "sim", "--taps", "1", "--out", out, cwd=tmp_path)
        assert res.returncode == 2, (res.stdout, res.stderr)
        assert "Traceback" not in res.stderr
        assert res.stderr.strip() in ("error: cannot write --out afile/run1: afile is a file, not a folder",
                                      "error: --out afile is a file, not a folder")
        assert (tmp_path / "afile").read_text() == "my file\n"
