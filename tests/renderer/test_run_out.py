"""``renderer run --out`` is checked before the run (auditor: renderer_out_parent_file: the taps ran, then a
traceback at mkdir): one ``error:`` line naming the path, exit 2, the user's file untouched."""

import subprocess
import sys


def test_run_out_below_a_file_is_refused_before_the_run(tmp_path):
    (tmp_path / "afile").write_text("my file\n")
    for out in ("afile/run1", "afile"):
        res = subprocess.run([sys.executable, "-m", "renderer", "run", "--device", "sim", "--taps", "1", "--out", out],
                             cwd=tmp_path, capture_output=True, text=True, timeout=300)
        assert res.returncode == 2, (res.stdout, res.stderr)
        assert "Traceback" not in res.stderr
        assert res.stderr.strip() in ("error: cannot write --out afile/run1: afile is a file, not a folder",
                                      "error: --out afile is a file, not a folder")
        assert (tmp_path / "afile").read_text() == "my file\n"
