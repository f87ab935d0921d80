"""Every figure outside the study report (demo contact and HFAM grid, HFAM library, Bode plots) in the project
style: no legend overlaps another artist, every numeric axis names its unit, PNG + SVG + CSV written, the Bode
phase starts inside ±180 deg with low-coherence bins left out, and the CSV holds what is plotted."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import figstyle


@pytest.fixture
def checked(monkeypatch):
    """Wrap figstyle.save: record each figure's legend overlaps and unit-less axes before it is written."""
    seen = []
    orig = figstyle.save

    def spy(fig, path, data=None, **kw):
        seen.append({"path": path, "overlaps": figstyle.legend_overlaps(fig), "units": figstyle.unlabelled_axes(fig),
                     "texts": figstyle.text_problems(fig),
                     "legends": len([a for a in fig.findobj() if type(a).__name__ == "Legend"]), "fig": fig})
        return orig(fig, path, data, **kw)

    monkeypatch.setattr(figstyle, "save", spy)
    return seen


def _ring(f_hz, amp, n=1100, fs=10000.0, pre=0.01):
    t = np.arange(n) / fs - pre
    return np.where(t >= 0, amp * np.exp(-t / 0.01) * np.sin(2 * np.pi * f_hz * t.clip(0)), 0.0)


def test_demo_figures(tmp_path, checked):
    from renderer.demo.figures import contact_figure, hfam_grid_figure
    ref = _ring(300, 50)
    panels = [("firm wall 680 N/m", _ring(20, 5)), ("pulse over firm", _ring(60, 10)),
              ("HFAM over firm", _ring(280, 40)), ("real wood on foam", ref)]
    png = contact_figure(panels, ref, 10000.0, 0.01, 0.11, 2.0, tmp_path / "fig_contact.png")
    vs, grips = (0.05, 0.11), (1.0, 2.0, 3.0)
    cells = {(v, g): _ring(250, 400 * v * g) for v in vs for g in grips}
    refs = {v: _ring(300, 450 * v) for v in vs}
    cur = {(v, g): _ring(250, v * g) for v in vs for g in grips}
    fixed = {(v, g): _ring(250, 300 * v) for v in vs for g in (1.0, 3.0)}
    hfam_grid_figure(cells, refs, cur, fixed, vs, grips, 10000.0, 0.01, tmp_path / "fig_hfam_grid.png")
    assert len(checked) == 2
    for rec in checked:
        assert rec["overlaps"] == [] and rec["units"] == [] and rec["legends"] >= 1, rec["path"]
        assert rec["texts"] == [], (rec["path"], rec["texts"])
    for stem in ("fig_contact", "fig_hfam_grid"):
        assert all((tmp_path / f"{stem}.{ext}").stat().st_size > 1000 for ext in ("png", "svg", "plot.csv"))
    d = pd.read_csv(tmp_path / "fig_contact.plot.csv")
    np.testing.assert_allclose(d["HFAM over firm accel_m_s2"], panels[2][1])
    line = checked[0]["fig"].axes[2].lines[1]          # the HFAM panel: reference dashed, then HFAM
    np.testing.assert_allclose(line.get_ydata(), d["HFAM over firm accel_m_s2"])
    assert line.get_color() == figstyle.color("hfam_firm")
    assert png == tmp_path / "fig_contact.png"


def test_library_figure(tmp_path, checked):
    from stimuli.cli_show import plot_library
    from stimuli.library import HfamLibrary
    v, g = np.array([0.05, 0.08, 0.11]), np.array([1.0, 3.0])
    cur = np.stack([np.stack([_ring(200, vi * gi, n=1000)[100:] for gi in g]) for vi in v])
    acc = np.stack([_ring(300, 400 * vi, n=1000)[100:] for vi in v])
    lib = HfamLibrary(v, g, cur, 10000.0, 3.0, desired_accel_m_s2=acc, source="test.npz")
    plot_library(lib, tmp_path / "lib.png")
    (rec,) = checked
    assert rec["overlaps"] == [] and rec["units"] == [] and rec["texts"] == []
    d = pd.read_csv(tmp_path / "lib.plot.csv")
    np.testing.assert_allclose(d["current 0.08 m/s grip 3 N (A)"], cur[1, 1])


def test_library_figure_of_five_grips_keeps_its_labels_apart(tmp_path, checked):
    """The demo's library (five grips across a page): one x label, not five overlapping ones; the title names
    the library once ("HFAM library library.npz" before)."""
    from stimuli.cli_show import plot_library
    from stimuli.library import HfamLibrary
    v, g = np.array([0.03, 0.1, 0.2, 0.3]), np.array([0.5, 1.0, 2.0, 3.0, 4.0])
    cur = np.stack([np.stack([_ring(200, vi * gi, n=1100)[100:] for gi in g]) for vi in v])
    acc = np.stack([_ring(300, 400 * vi, n=1100)[100:] for vi in v])
    lib = HfamLibrary(v, g, cur, 10000.0, 3.0, desired_accel_m_s2=acc, source="/tmp/cache/library.npz")
    plot_library(lib, tmp_path / "lib.png")
    (rec,) = checked
    assert rec["texts"] == [] and rec["overlaps"] == [] and rec["units"] == []
    title = rec["fig"].get_suptitle()
    assert title.lower().count("library") == 1, title


def test_text_problems_sees_overlapping_and_clipped_labels():
    """The check itself: two panels' long x labels that run into each other, and a title off the figure."""
    with figstyle.style() as plt:
        fig, axes = plt.subplots(1, 4, figsize=(3.0, 1.5))
        for ax in axes:
            ax.set_xlabel("a rather long time axis label (ms)")
        problems = figstyle.text_problems(fig)
        assert any("overlaps" in p for p in problems)
        fig2, ax2 = plt.subplots(figsize=(2.0, 1.5), layout="constrained")
        ax2.set_title("a title far too long for a two-inch figure, so it runs past both edges")
        assert figstyle.text_problems(fig2, tight=False) == [
            "text 'a title far too long for a two-inch figure, so it runs past both edges' is clipped by the "
            "figure's edge"]
        assert figstyle.text_problems(fig2, tight=True) == []
        plt.close("all")


def test_bode_plot_wraps_phase_masks_low_coherence_and_marks_resonance(tmp_path, checked):
    from devices.identify.etfe import Etfe
    from devices.identify.figures import bode_plot, resonance_and_3db, wrap_phase_deg
    from devices.model import ZpkModel
    wn, zeta = 2 * np.pi * 80.0, 0.1
    model = ZpkModel(np.array([0.0, 0.0]), np.array([-zeta * wn + 1j * wn * np.sqrt(1 - zeta ** 2),
                                                     -zeta * wn - 1j * wn * np.sqrt(1 - zeta ** 2)]), 30.0,
                     delay_s=2e-3, band_hz=(5.0, 1000.0), grip_N=2.0)
    f = np.geomspace(5, 1000, 400)
    H = model.frequency_response(f) * np.exp(-2j * np.pi * 3.0)     # three whole turns off: must be shifted
    coh = np.where((f > 300) & (f < 400), 0.2, 0.95)
    curve = Etfe(f, H, H, coh, "accel_m_s2", 3, 2.0, "grip 2 N")
    bode_plot([curve], [model], tmp_path / "bode.png", title="test")
    (rec,) = checked
    assert rec["overlaps"] == [] and rec["units"] == []
    d = pd.read_csv(tmp_path / "bode.plot.csv")
    etfe = d[d["kind"] == "etfe"]
    assert -180 < etfe["phase_deg"].dropna().iloc[0] <= 180            # wrapped at the low-frequency end
    assert etfe.loc[~etfe["trusted"].astype(bool), "phase_deg"].isna().all()   # low coherence: no phase
    assert (~etfe["trusted"].astype(bool)).sum() == int(((f > 300) & (f < 400)).sum())
    ph = wrap_phase_deg(H)
    assert np.nanmax(np.abs(np.diff(ph))) < 30                          # no wrap jumps inside the curve
    f_pk, pk, f3 = resonance_and_3db(f, model.frequency_response(f))
    assert f_pk == pytest.approx(80.0, rel=0.05) and f3 > f_pk
    # a position response (x/i ~ accel / (2 pi f)^2) is largest at the band's low edge: its resonance is still
    # the interior peak near 80 Hz, not 5 Hz
    hx = model.frequency_response(f) / (2j * np.pi * f) ** 2 * (5.0 / f) ** 2
    f_x, pk_x, _ = resonance_and_3db(f, hx)
    assert np.argmax(np.abs(hx)) == 0                                   # largest at the low edge ...
    assert f_x == pytest.approx(80.0, rel=0.1)                         # ... the resonance marked at its peak
    assert np.isnan(resonance_and_3db(f, 1.0 / (1j * f))[0])           # no interior peak: no marker
    marks = d[d["kind"].isin(["resonance", "minus_3db"])]
    assert list(marks["kind"]) == ["resonance", "minus_3db"]
    assert marks["f_hz"].iloc[0] == pytest.approx(f_pk) and marks["magnitude_db"].iloc[1] == pytest.approx(pk - 3)
    # the model is drawn on the curve's branch: its phase meets the data's at the band's start
    mod = d[d["kind"] == "model"]
    assert abs(mod["phase_deg"].iloc[0] - etfe["phase_deg"].iloc[0]) < 5


def test_linearity_and_validation_figures(tmp_path, checked):
    """`devices linearity` and `devices validate --plot` in the project style: PNG + SVG + CSV, no text overlapping
    or cut off (the linearity conclusion ran off the figure), legends beside the data, units on every axis."""
    from devices.identify.etfe import Etfe
    from devices.identify.linearity import linearity_figure
    from devices.identify.validate_td import time_domain_figure
    f = np.geomspace(5, 1000, 300)
    H = 30.0 * (2j * np.pi * f) ** 2 / ((2j * np.pi * f) ** 2 + 2 * 0.1 * 500 * 2j * np.pi * f + 500.0 ** 2)
    curves = [Etfe(f, H * s, H * s, np.full(f.size, 0.95), "accel_m_s2", 3, 2.0, f"{a:g} A, grip 2 N")
              for a, s in ((0.5, 1.0), (1.0, 1.05), (2.0, 1.2))]
    conclusion = ("the device is not linear: the ETFE at 2 A differs from the one at 0.5 A by more than the "
                  "trial-to-trial spread over 40-200 Hz; identify at the amplitude the rendering uses, or use "
                  "the successive-isolation model, which holds the amplitude dependence")
    report = {"band_hz": (20.0, 500.0), "curves": curves, "device": "sim", "conclusion": conclusion}
    png = linearity_figure(report, tmp_path / "linearity.png")
    fs, n = 10000.0, 400
    wins = [(0, n), (n, 2 * n), (2 * n, 3 * n)]
    meas = np.concatenate([_ring(120, 20, n=n, pre=0.0) for _ in wins])
    res = {"windows": wins, "fs_hz": fs, "grip_N": 2.0, "current_A": np.concatenate([_ring(120, 1, n=n, pre=0.0)] * 3),
           "measured": meas, "models": {"zpk model": {"predicted": 0.9 * meas, "nrmse_per_transient": [0.1] * 3}}}
    time_domain_figure(res, tmp_path / "td.png", title="model_set.json on sim")
    assert len(checked) == 2
    for rec in checked:
        assert rec["texts"] == [] and rec["overlaps"] == [] and rec["units"] == [], rec
    lin = checked[0]["fig"]
    assert "identify at the amplitude the rendering uses" in lin.get_suptitle().replace("\n", " ")
    assert png == str(tmp_path / "linearity.png")
    for stem in ("linearity", "td"):
        assert all((tmp_path / f"{stem}.{ext}").stat().st_size > 1000 for ext in ("png", "svg", "plot.csv"))
    d = pd.read_csv(tmp_path / "td.plot.csv")
    np.testing.assert_allclose(d["measured_m_s2"], meas)


def test_teleoperation_figures(tmp_path, checked):
    """Figures 5.10, 5.11 and 4.5 of teleoperation in the project style; Figure 5.11 draws each condition's
    unstable taps on its own row (they piled up at 320 ms), and its CSV holds every row."""
    import types

    from devices.sim import teleop_kernel as K
    from renderer.teleop.commands import figure_510, figure_511
    from renderer.teleop.hfam import figure_45
    conds = ["pf", "pf+cimm", "pp", "pp+cimm"]
    rows = [{"condition": c, "lambda": lam, "settling_s": 0.05 + 0.02 * lam + 0.01 * k, "stable": lam < 2 + 0.5 * k}
            for k, c in enumerate(conds) for lam in (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0)]
    figure_511(rows, conds, tmp_path / "figure_5_11.png")
    n, fs = 3000, 2000.0
    tr = np.zeros((n, max(v for k, v in vars(K).items() if k.startswith("O_") and isinstance(v, int)) + 1))
    tr[:, K.O_T] = np.arange(n) / fs
    tr[1000:, K.O_FE] = 1.0
    tr[:, K.O_FF] = np.where(np.arange(n) >= 1000, 2.0, 0.0)
    tr[:, K.O_XC] = 1e-3 * np.sin(np.arange(n) / 50)
    tr[:, K.O_XM], tr[:, K.O_XHAT] = tr[:, K.O_XC] * 0.9, tr[:, K.O_XC] * 0.1
    figure_510(types.SimpleNamespace(traces=tr, fault=False, fs_hz=fs), tmp_path / "figure_5_10.png",
               "pf+cimm, lambda = 1, mu = 1")
    x = _ring(200, 30, n=4000)
    figure_45(x, 0.8 * np.roll(x, 20), 10000.0, 20, tmp_path / "figure_4_5.png", title="HFAM teleoperation")
    assert len(checked) == 3
    for rec in checked:
        assert rec["texts"] == [] and rec["overlaps"] == [] and rec["units"] == [], rec
    top = checked[0]["fig"].axes[0]
    ys = sorted({float(y) for ln in top.lines for y in ln.get_ydata()})
    assert ys == [0.0, 1.0, 2.0, 3.0]                      # one row per condition with unstable taps
    assert len(pd.read_csv(tmp_path / "figure_5_11.plot.csv")) == len(rows)
    for stem in ("figure_5_11", "figure_5_10", "figure_4_5"):
        assert all((tmp_path / f"{stem}.{ext}").stat().st_size > 500 for ext in ("png", "svg", "plot.csv"))


def test_penetration_figure_whiskers_show_on_every_bar(tmp_path, checked):
    """Every bar's whisker is drawn above the bars in black and every bar is light enough to show it (the real
    sample's black bar hid its black whisker)."""
    from matplotlib.colors import to_rgba

    from renderer.demo.figures import penetration_figure
    pen = {"real_wood": [0.001, 0.0015, 0.002], "hfam_firm": [0.002, 0.0025, 0.003], "wall_firm": [0.003, 0.0032]}
    labels = {"real_wood": "real wood on foam", "hfam_firm": "HFAM over firm", "wall_firm": "firm wall"}
    penetration_figure(pen, labels, tmp_path / "fig_penetration.png")
    (rec,) = checked
    assert rec["texts"] == [] and rec["units"] == []
    ax = rec["fig"].axes[0]
    bars = [p for p in ax.patches]
    (err,) = ax.containers[1:] or [None]
    whiskers = err.lines[2][0]
    assert whiskers.get_zorder() > max(b.get_zorder() for b in bars)
    assert all(tuple(c) == (0.0, 0.0, 0.0, 1.0) for c in whiskers.get_colors())
    assert all(to_rgba(b.get_facecolor())[3] <= 0.5 for b in bars)
    np.testing.assert_allclose([s[1][0] - s[0][0] for s in whiskers.get_segments()],
                               [2e3 * np.std(pen[n]) for n in labels])


def test_the_committed_gallery_is_current():
    """docs/gallery was drawn by today's figure code: `make gallery` records the digest of every source that
    draws its figures (figstyle.gallery.FIGURE_SOURCES) beside it; a change to one of them without `make
    gallery` fails here (the gallery had gone stale: `make gallery` rewrote fig_hfam_grid). Cheap: no figure is
    drawn."""
    from pathlib import Path

    from figstyle import gallery
    root = Path(__file__).resolve().parents[2]
    recorded = (root / "docs" / "gallery" / gallery.SOURCES_FILE).read_text(encoding="utf-8")
    assert recorded == gallery.sources_digest(root), (
        "docs/gallery is stale: a figure's drawing code changed since it was generated; run `make gallery` "
        "and commit docs/gallery")
