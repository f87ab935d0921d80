"""``figstyle.save`` writes every file under a unique temporary name beside its target and renames it: two
writers of one figure never share a temporary file, a failed save leaves none behind and the earlier figure
as it was, and the plot CSV's text cells are never a spreadsheet formula.

Once: the temporary name was fixed (``<file>.tmp.<fmt>``): two runs collided and a failure left it behind.
"""

import csv

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402

import figstyle  # noqa: E402


def _figure():
    fig, ax = plt.subplots()
    ax.plot([0, 1, 2], [0, 1, 4])
    return fig


def test_two_writers_of_one_figure_get_different_temporary_files(tmp_path):
    target = tmp_path / "fig.png"
    with figstyle._temporary(target) as a, figstyle._temporary(target) as b:
        assert a != b and a.parent == b.parent == tmp_path
        assert a.name.startswith(".fig.png.") and a.name.endswith(".tmp")
        a.write_bytes(b"first")
        b.write_bytes(b"second")
    assert target.read_bytes() == b"first"           # the outer block ended last: its file is the figure
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig.png"]


def test_a_failed_save_leaves_the_earlier_figure_and_no_temporary_file(tmp_path, monkeypatch):
    path = tmp_path / "fig"
    figstyle.save(_figure(), path, data={"x_m": [0.0, 1.0], "name": ["=1+1", "wood"]})
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert sorted(before) == ["fig.plot.csv", "fig.png", "fig.svg"]
    with open(tmp_path / "fig.plot.csv", newline="") as fh:
        assert [r[1] for r in csv.reader(fh)] == ["name", "'=1+1", "wood"]   # never run as a formula
    fig = _figure()

    def disk_full(*a, **k):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(fig, "savefig", disk_full)
    with pytest.raises(OSError):
        figstyle.save(fig, path, data={"x_m": [5.0]}, force=True)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
