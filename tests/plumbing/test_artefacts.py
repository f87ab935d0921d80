"""Every shipped artefact derived from the sim matches the code that made it (plumbing/artefacts.py).

Cheap: the stamps are compared with the sources and the files as they are now; nothing is rebuilt. A failure
names the artefact and why; ``make artefacts`` rebuilds and re-stamps.
"""

from pathlib import Path

from plumbing import artefacts as A


def test_every_artefact_matches_its_stamp():
    stale = A.check()
    assert not stale, "stale artefacts (rebuild with `make artefacts`):\n" + "\n".join(
        f"  {name}: {'; '.join(why)}" for name, why in stale.items())


def test_the_artefacts_are_the_sims(tmp_path):
    """The shipped library and the gallery are registered, their commands run the packages' own commands, and
    the library comes first (the gallery's study plays it)."""
    names = [a.name for a in A.ARTEFACTS]
    assert names == ["hfam-library", "gallery"]
    lib, gallery = A.ARTEFACTS
    assert "stimuli/libraries/wood_on_foam_sim.npz" in lib.outputs and "stimuli/hfam" in lib.inputs
    assert "docs/gallery" in gallery.outputs and "docs/img/demo_penetration.png" in gallery.outputs
    assert lib.command[:3] == ("-m", "stimuli", "sim-library")


def test_a_stamp_notices_changed_code_and_edited_files(tmp_path: Path):
    art = A.Artefact("x", ("out",), ("src",), ("-c", "pass"), "out/x.stamp.json")
    (tmp_path / "src").mkdir()
    (tmp_path / "out").mkdir()
    (tmp_path / "src" / "m.py").write_text("K = 1\n")
    (tmp_path / "src" / "notes.txt").write_text("not an input\n")
    (tmp_path / "out" / "r.csv").write_text("1\n")
    assert A.stale(art, tmp_path) == [f"out/x.stamp.json: no readable stamp"]
    A.write_stamp(art, tmp_path)
    assert A.stale(art, tmp_path) == []
    (tmp_path / "src" / "notes.txt").write_text("still not an input\n")
    assert A.stale(art, tmp_path) == []
    (tmp_path / "out" / "r.csv").write_text("2\n")
    assert A.stale(art, tmp_path) == ["out/r.csv edited since the stamp"]
    (tmp_path / "out" / "r.csv").write_text("1\n")
    (tmp_path / "src" / "m.py").write_text("K = 2\n")
    assert A.stale(art, tmp_path) == ["its inputs (src) changed since it was made"]
    (tmp_path / "src" / "m.py").write_text('"""A docstring."""\nK = 1  # a comment reworded\n')
    assert A.stale(art, tmp_path) == []    # words are not code: the artefact is still what this code makes
    (tmp_path / "src" / "m.py").write_text("K = 1\n")
    (tmp_path / "out" / "new.png").write_bytes(b"x")
    assert A.stale(art, tmp_path) == ["out/new.png added since the stamp"]
