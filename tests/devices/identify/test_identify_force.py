"""``identify --force`` over earlier results: they are replaced only once the new run has succeeded; a
failure or Ctrl-C leaves them as they were (auditor: identify_force_ctrlc, identify_force_deletes_before_fail)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

from devices.__main__ import main as devices_main
from tests.support.files import tree_hashes

ROOT = Path(__file__).resolve().parents[3]
FAST = ["--device", "sim", "--grips-N", "2", "--trials", "2", "--duration-s", "0.5", "--workers", "1"]


def _earlier_results(out: Path) -> dict:
    """An earlier identification's products (and a file of the user's) with their hashes."""
    (out / "recordings").mkdir(parents=True)
    files = {"model_set.json": json.dumps({"kind": "model_set", "grip_N": [10.0]}),
             "accel_g10N.json": '{"old": "model"}', "report.txt": "old report\n", "report.json": "{}",
             "etfe_accel.npz": "old etfe", "bode_accel.png": "old png", "recordings/g10N_t0.csv": "t_s\n0\n",
             "my_notes.txt": "the user's own notes\n"}
    for name, text in files.items():
        (out / name).write_text(text)
    return tree_hashes(out)


# The child is the real command with one gate: once a grip's recordings are on disk and before they are
# analysed, it says so on stderr and waits for a line on stdin. Ctrl-C then lands in the middle of the run by
# construction, however loaded the machine is (the run can neither finish first nor be caught before measuring).
_GATED_IDENTIFY = """
import sys
import devices.identify.pipeline as pipeline
from devices.__main__ import main

_analyse = pipeline._analyse_grip

def gated(*args, **kwargs):
    print("GATE: recordings written", file=sys.stderr, flush=True)
    sys.stdin.readline()
    return _analyse(*args, **kwargs)

pipeline._analyse_grip = gated
sys.exit(main(sys.argv[1:]))
"""


def test_ctrl_c_during_a_forced_identify_keeps_the_earlier_results(tmp_path):
    out = tmp_path / "identA"
    before = _earlier_results(out)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-c", _GATED_IDENTIFY, "identify", *FAST, "--duration-s", "2",
                             "--out", str(out), "--force"], cwd=tmp_path, env=env, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen = []
    for line in proc.stderr:                    # wait for the run's own announcement, however long it takes
        seen.append(line)
        if line.startswith("GATE:"):
            break
    assert seen and seen[-1].startswith("GATE:"), "".join(seen)
    measuring = list(tmp_path.glob(".identA.staging-*/recordings/g2N*.csv"))
    assert len(measuring) == 2                  # both trials of the grip recorded into the sibling folder
    proc.send_signal(signal.SIGINT)             # the run is parked at the gate: Ctrl-C arrives mid-run
    _, rest = proc.communicate(timeout=600)
    err = "".join(seen) + rest
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines[-1] == f"interrupted: identification stopped; nothing in {out} was replaced"
    assert tree_hashes(out) == before                              # every earlier file, byte for byte
    assert sorted(p.name for p in tmp_path.iterdir()) == ["identA"]   # the half-measured run is gone, no lock left


def test_a_failed_forced_identify_keeps_the_earlier_results(tmp_path, monkeypatch, capsys):
    import devices.identify.pipeline as pipeline

    out = tmp_path / "identA"
    before = _earlier_results(out)

    def failing(dev, cfg, out_dir, **kw):
        (Path(out_dir) / "recordings").mkdir(parents=True, exist_ok=True)
        (Path(out_dir) / "recordings" / "g2N_t0.csv").write_text("half\n")
        raise ValueError("the sweep failed half way")

    monkeypatch.setattr(pipeline, "identify_device", failing)
    assert devices_main(["identify", *FAST, "--out", str(out), "--force"]) == 2
    assert "error: the sweep failed half way" in capsys.readouterr().err
    assert tree_hashes(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["identA"]


def test_a_forced_identify_replaces_the_earlier_results_when_it_succeeds(tmp_path, capsys):
    out = tmp_path / "identA"
    before = _earlier_results(out)
    assert devices_main(["identify", *FAST, "--out", str(out), "--force"]) == 0
    assert f"wrote {out / 'model_set.json'}" in capsys.readouterr().out
    after = tree_hashes(out)
    assert after["my_notes.txt"] == before["my_notes.txt"]     # not identify's: kept
    assert "accel_g10N.json" not in after and "recordings/g10N_t0.csv" not in after   # old and new never mix
    assert json.loads((out / "model_set.json").read_text())["grip_N"] == [2.0]
    assert "accel_g2N.json" in after and "bode_accel.png" in after and after["report.txt"] != before["report.txt"]
    assert ".identify-" not in (out / "report.json").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["identA"]
