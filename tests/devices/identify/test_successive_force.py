"""``identify --method successive`` over an earlier model: refused without ``--force`` (naming the files);
with it, the earlier model is replaced only once the new run has written everything, so a run that fails
midway leaves it byte for byte (as the comprehensive method, tests/devices/identify/test_identify_force.py)."""

from __future__ import annotations

import json
from pathlib import Path

import devices.identify.successive.procedure as procedure
from devices.__main__ import main as devices_main
from devices.identify.successive import StageError
from tests.support.files import tree_hashes

QUICK = ["identify", "--method", "successive", "--device", "sim", "--stages", "timing,amplifier", "--no-figures"]


def _earlier_model(out: Path) -> dict:
    """An earlier successive identification (model, reports, a figure, its state) and a file of the user's."""
    out.mkdir(parents=True)
    files = {"model.json": json.dumps({"name": "the old model"}), "report.txt": "old report\n",
             "report.json": "{}", "stage_1_timing.png": "old png", "successive_state.json": '{"stages": []}',
             "my_notes.txt": "the user's own notes\n"}
    for name, text in files.items():
        (out / name).write_text(text)
    return tree_hashes(out)


def test_successive_refuses_an_earlier_model_without_force_naming_it(tmp_path, capsys):
    out = tmp_path / "ident"
    before = _earlier_model(out)
    assert devices_main([*QUICK, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"--out {out} already holds a model (model.json)" in err and "--force" in err
    (out / "model.json").unlink()  # the rest of a run is refused too, each file named
    assert devices_main([*QUICK, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "report.json, report.txt, stage_1_timing.png, successive_state.json" in err and "--force" in err
    del before["model.json"]
    assert tree_hashes(out) == before


def test_a_forced_successive_run_that_fails_midway_keeps_the_earlier_model(tmp_path, monkeypatch, capsys):
    out = tmp_path / "ident"
    before = _earlier_model(out)

    def broken_amplifier(bench, builder):  # the second stage fails, after the first wrote its state
        raise StageError("amplifier: the current sense reads 0 A at 1 A commanded")

    monkeypatch.setattr(procedure, "STAGES", tuple((n, broken_amplifier if n == "amplifier" else f)
                                                    for n, f in procedure.STAGES))
    assert devices_main([*QUICK, "--out", str(out), "--force"]) == 2
    err = capsys.readouterr().err
    kept = tmp_path / "ident.failed"
    assert "amplifier: the current sense reads 0 A" in err
    assert f"{out} keeps the earlier model" in err and f"--out {kept} --resume" in err
    assert tree_hashes(out) == before                              # every earlier file, byte for byte
    state = json.loads((kept / "successive_state.json").read_text())
    assert [s["stage"] for s in state["stages"]] == ["timing"]  # the finished stage, kept to resume
    assert not (kept / "model.json").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ident", "ident.failed"]   # no temporary folder left
    # failing again: the first failed run's stages are not replaced; this one's go beside them
    first = tree_hashes(kept)
    assert devices_main([*QUICK, "--out", str(out), "--force"]) == 2
    kept2 = tmp_path / "ident.failed.2"
    assert f"--out {kept2} --resume" in capsys.readouterr().err
    assert tree_hashes(kept) == first and tree_hashes(out) == before
    assert (kept2 / "successive_state.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ident", "ident.failed", "ident.failed.2"]


def test_a_forced_successive_run_replaces_the_earlier_model_when_it_succeeds(tmp_path, capsys):
    out = tmp_path / "ident"
    before = _earlier_model(out)
    assert devices_main([*QUICK, "--out", str(out), "--force"]) == 0
    assert f"wrote {out / 'model.json'} (use it as --device sim:{out / 'model.json'})" in capsys.readouterr().out
    after = tree_hashes(out)
    assert after["my_notes.txt"] == before["my_notes.txt"]     # not identify's: kept
    assert "stage_1_timing.png" not in after                  # the old run's figure: old and new never mix
    model = json.loads((out / "model.json").read_text())
    assert model != {"name": "the old model"} and "device" in model
    state = json.loads((out / "successive_state.json").read_text())
    assert [s["stage"] for s in state["stages"]] == ["timing", "amplifier"]
    assert ".identify-" not in (out / "report.json").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ident"]
