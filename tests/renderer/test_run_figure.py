"""Issue 39 part 3: ``renderer run`` draws its run (position, forces, acceleration, events, the wall) beside its data."""

import csv

import numpy as np

import figstyle
from plumbing.outdir import MARKER
from renderer.loop import RunResult
from renderer.run_figure import envelope, plot_run, run_figure_data
from tests.support.cli import run_cli


def test_envelope_keeps_every_peak_and_the_time_order():
    t = np.arange(100_000) / 10_000.0
    y = np.sin(2 * np.pi * 3 * t)
    y[12_345] = 9.0       # one spike: an impact
    y[67_890] = -7.0
    te, ye = envelope(t, y, buckets=1000)
    assert len(te) == len(ye) == 2000 and np.all(np.diff(te) >= 0)
    assert ye.max() == 9.0 and ye.min() == -7.0
    assert te[np.argmax(ye)] <= t[12_345] <= te[np.argmax(ye) + 1]   # in the bucket that held it
    short_t, short_y = envelope(t[:500], y[:500], buckets=1000)
    assert np.array_equal(short_y, y[:500])


def test_run_command_draws_the_run_in_the_project_style(tmp_path, capsys):
    out = tmp_path / "run"
    proc = run_cli(capsys, "renderer", "run", "--device", "sim", "--transient", "pulse", "--taps", "2", "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert "run.png" in proc.stdout and (out / "run.png").stat().st_size > 10_000 and (out / "run.svg").exists()
    result = RunResult.load(out)
    with open(out / "run.plot.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    col = {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}
    # the CSV holds what the log holds: the peaks of position and acceleration, the force = current x rho k_t / h
    assert np.isclose(col["accel_m_s2"].max(), result.log["accel_m_s2"].max())
    assert np.isclose(col["position_mm"].min(), 1000 * result.log["position_m"].min())
    d = result.device
    kf = d["gear_ratio"] * d["torque_constant_Nm_A"] / d["handle_length_m"]
    assert np.isclose(col["force_N"].max(), kf * result.log["current_A"].max())
    data = run_figure_data(result)
    assert len(data["event_t_s"]) == len(result.events) == 2
    fig = plot_run(data)
    try:
        assert figstyle.unlabelled_axes(fig) == [] and figstyle.legend_overlaps(fig) == []
        lines = [ln for ax in fig.axes for ln in ax.get_lines()]
        walls = [ln for ln in lines if ln.get_label() == "wall surface"]
        assert walls and walls[0].get_ydata()[0] == 0.0
        marks = [c for c in fig.axes[0].collections if c.get_label() == "contact event"]
        assert [seg[0][0] for seg in marks[0].get_segments()] == [e.t_s for e in result.events]
    finally:
        import matplotlib.pyplot as plt  # deferred: the figure's own library, loaded by plot_run
        plt.close(fig)


def test_no_figure_leaves_only_the_data(tmp_path, capsys):
    out = tmp_path / "run"
    proc = run_cli(capsys, "renderer", "run", "--device", "sim", "--taps", "1", "--no-figure", "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "events.csv", "log.npz", "run.json"]


def test_an_on_device_run_does_not_draw_the_boards_forces_as_zero(tmp_path, capsys):
    """On-device rendering: the board computes the wall and the transient and reports neither; the figure says
    so and draws only the commanded total, and its CSV holds NaN (not 0) for the parts. The run that makes the
    log is a set-up, in the test's process (tests/support/cli.py)."""
    out = tmp_path / "run"
    proc = run_cli(capsys, "renderer", "run", "--device", "sim", "--transient", "pulse", "--taps", "1", "--no-figure",
                   "--out", out)
    assert proc.returncode == 0, proc.stderr
    result = RunResult.load(out)
    host = run_figure_data(result)
    assert not host["on_device"] and np.nanmax(np.abs(host["force_prop_N"])) > 0.1
    result.timing = dict(result.timing, on_device=True)
    data = run_figure_data(result)
    assert data["on_device"] and np.isnan(data["force_prop_N"]).all() and np.isnan(data["force_transient_N"]).all()
    np.testing.assert_array_equal(data["force_N"], host["force_N"])
    fig = plot_run(data)
    try:
        labels = [ln.get_label() for ln in fig.axes[1].get_lines()]
        assert labels == ["commanded force (after saturation)"]
        assert any("computed on the board" in t.get_text() for t in fig.axes[1].texts)
        assert figstyle.legend_overlaps(fig) == []
    finally:
        import matplotlib.pyplot as plt  # deferred: the figure's own library, loaded by plot_run
        plt.close(fig)
