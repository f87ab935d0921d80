"""``figstyle.save`` measures a figure's tight box once: the PNG is byte for byte what ``savefig`` alone writes,
and the SVG reuses the PNG's box, which differs from the one it would measure for itself by the renderers' text
metrics: less than the box's 0.03-inch pad, so nothing is cut off.
"""

import re

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import figstyle  # noqa: E402

PNG_META = {"Software": None}
SVG_META = {"Date": None, "Creator": None}


def _figure():
    """Text at every edge: titles, labels, a legend, a suptitle and a note hanging past the right edge."""
    fig, axes = plt.subplots(2, 3, figsize=(7.2, 4))
    t = np.linspace(0.0, 1.0, 200)
    for i, ax in enumerate(axes.flat):
        ax.plot(t, np.sin((10 + i) * t), label=f"tap {i}")
        ax.set_xlabel("velocity (m/s)")
        ax.set_ylabel("acceleration (m/s$^2$)")
        ax.set_title(rf"grip {i + 1} N, $\alpha$")
        ax.legend(loc="best")
    fig.suptitle("Transients against speed")
    fig.text(0.99, 0.01, "a note past the edge", ha="left")
    return fig


def _view_box(svg: str) -> list[float]:
    return [float(v) for v in re.search(r'viewBox="([^"]*)"', svg).group(1).split()]


def test_png_is_savefigs_and_svg_within_the_pad(tmp_path):
    fig = _figure()
    out = figstyle.save(fig, tmp_path / "saved", close=False)
    assert "get_tightbbox" not in vars(fig)          # the figure's own method again
    with plt.style.context(str(figstyle.STYLE_PATH)):
        fig.savefig(tmp_path / "alone.png", metadata=PNG_META)
        fig.savefig(tmp_path / "alone.svg", metadata=SVG_META)
        pad_pt = 72 * matplotlib.rcParams["savefig.pad_inches"]
    plt.close(fig)
    assert out["png"].read_bytes() == (tmp_path / "alone.png").read_bytes()
    shared, alone = _view_box(out["svg"].read_text()), _view_box((tmp_path / "alone.svg").read_text())
    assert shared[:2] == alone[:2] == [0.0, 0.0]
    # points (1/72 inch): the boxes differ by the renderers' text metrics only (here 1.1 pt of the width)
    assert abs(shared[2] - alone[2]) < pad_pt and abs(shared[3] - alone[3]) < pad_pt
    assert shared[2] > 7.2 * 72 * 0.85                # the whole width, not a cut-off part


def test_one_measurement_for_both_formats(tmp_path, monkeypatch):
    calls = []
    measure = matplotlib.figure.Figure.get_tightbbox

    def counted(self, *args, **kwargs):
        calls.append(type(args[0] if args else kwargs.get("renderer")).__name__)
        return measure(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "get_tightbbox", counted)
    figstyle.save(_figure(), tmp_path / "once")
    assert calls == ["RendererAgg"]
    assert (tmp_path / "once.png").stat().st_size > 20_000 and (tmp_path / "once.svg").stat().st_size > 20_000


def test_a_kept_layout_saves_as_savefig_does(tmp_path):
    """A figure whose constrained layout was computed once and kept (analysis.figures): figstyle.save leaves out
    savefig's draws before measuring and before the SVG, and writes the bytes savefig writes with them."""
    fig = _figure()
    fig.set_layout_engine("constrained")
    fig.get_layout_engine().execute(fig)
    fig.set_layout_engine("none")
    out = figstyle.save(fig, tmp_path / "saved", close=False)
    with plt.style.context(str(figstyle.STYLE_PATH)):
        calls = []
        measure = fig.get_tightbbox

        def kept(*args, **kwargs):
            got = measure(*args, **kwargs)
            calls.append(got)
            return got

        fig.get_tightbbox = kept
        fig.savefig(tmp_path / "alone.png", metadata=PNG_META)
        del fig.get_tightbbox
        # the SVG with the PNG's box, drawn by savefig with its draw before the rendering
        fig.savefig(tmp_path / "alone.svg", metadata=SVG_META,
                    bbox_inches=calls[0].padded(matplotlib.rcParams["savefig.pad_inches"]))
    plt.close(fig)
    assert out["png"].read_bytes() == (tmp_path / "alone.png").read_bytes()
    assert out["svg"].read_bytes() == (tmp_path / "alone.svg").read_bytes()
    assert fig.get_layout_engine() is not None        # the placeholder is back
