"""The project's one figure style: sizes, fonts, a colour-blind-safe palette, saving and checks.

A leaf package: it imports nothing from ``devices``, ``renderer``, ``stimuli``, ``study`` or
``analysis``, so every one of them may use it without adding an arrow between them
(docs/figures.md). The style itself is data beside this file:

* ``project.mplstyle``: fonts, line widths, grid, save options (a matplotlib style file);
* ``palette.json``: one fixed colour, line style and marker per sample/rendering (the same
  in every figure), the colour maps of the p-value and effect-size matrices.

Every figure is saved with :func:`save` as PNG and SVG with the plotted numbers beside it as
CSV (``NAME.png``, ``NAME.svg``, ``NAME.csv``), so a reader can redraw it.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import json
import os
import re
import tempfile
from functools import lru_cache
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
from matplotlib.layout_engine import PlaceHolderLayoutEngine
from matplotlib.legend import Legend
from matplotlib.transforms import Bbox

from plumbing.fileio import current_umask
from plumbing.textsafe import csv_cell, csv_header, safe_frame

HERE = Path(__file__).resolve().parent
STYLE_PATH = HERE / "project.mplstyle"
PALETTE_PATH = HERE / "palette.json"

# figure widths in inches: one column of a two-column paper (89 mm), a full page width
# (183 mm), and a 16:9 slide
WIDTH_IN = {"column": 3.5, "page": 7.2, "slide": 10.0}
# font scale of the slide size relative to the paper sizes
SLIDE_FONT_SCALE = 1.6
FORMATS = ("png", "svg")


@lru_cache(maxsize=1)
def palette() -> dict:
    """The parsed ``palette.json`` (``samples``, ``aliases``, ``series``, colour maps)."""
    return json.loads(PALETTE_PATH.read_text(encoding="utf-8"))


def sample_style(name: str) -> dict:
    """Colour, line style, marker and label of a sample or rendering, fixed across all figures.

    Parameters
    ----------
    name : str
        A sample of the study catalog (``wood``, ``hfam_firm`` ...) or a demo rendering; unknown
        names get a stable colour from the ``series`` list (chosen by a hash of the name).

    Returns
    -------
    dict
        ``color`` (hex), ``linestyle``, ``marker``, ``label`` (readable name).
    """
    pal = palette()
    key = pal["aliases"].get(name, name)
    if key in pal["samples"]:
        return dict(pal["samples"][key])
    series = pal["series"]
    i = int(hashlib.sha1(name.encode("utf-8")).hexdigest(), 16) % len(series)
    return {"color": series[i], "linestyle": "-", "marker": "o", "label": name.replace("_", " ")}


def color(name: str) -> str:
    """Hex colour of a sample or rendering (:func:`sample_style`)."""
    return sample_style(name)["color"]


def figsize(width: str = "column", aspect: float = 0.62, height_in: float | None = None) -> tuple[float, float]:
    """Figure size in inches for ``width`` = ``column`` (3.5 in) | ``page`` (7.2 in) | ``slide`` (10 in).

    ``height_in`` overrides ``aspect`` (height / width).
    """
    if width not in WIDTH_IN:
        raise ValueError(f"figure width must be one of {', '.join(WIDTH_IN)}, not {width!r}")
    w = WIDTH_IN[width]
    return (w, height_in if height_in is not None else w * aspect)


@contextlib.contextmanager
def style(size: str = "paper"):
    """Context manager applying the project style (``size`` = ``paper`` or ``slide``: larger fonts).

    Selects matplotlib's Agg backend when no backend was chosen yet (figures are written to
    files; nothing is shown).
    """
    if "MPLBACKEND" not in os.environ:
        matplotlib.use("Agg")  # pyplot chooses its backend on the first figure: still free to be set here
    extra = {}
    if size == "slide":
        base = matplotlib.rc_params_from_file(str(STYLE_PATH), use_default_template=False)
        extra = {k: float(base[k]) * SLIDE_FONT_SCALE for k in
                 ("font.size", "axes.titlesize", "axes.labelsize", "xtick.labelsize", "ytick.labelsize",
                  "legend.fontsize", "figure.titlesize")}
    elif size != "paper":
        raise ValueError(f"style size must be paper or slide, not {size!r}")
    with plt.style.context([str(STYLE_PATH), extra]):
        yield plt


def _write_csv(path: Path, data) -> None:
    """Write ``data`` (DataFrame, dict of equal-length columns, or (header, rows)) as CSV; text cells (sample
    names, conditions) are written so a spreadsheet never runs them (:mod:`plumbing.textsafe`)."""
    if hasattr(data, "to_csv"):
        safe_frame(data).to_csv(path, index=False, float_format="%.9g")
        return
    if isinstance(data, dict):
        header = list(data)
        cols = [list(v) if hasattr(v, "__len__") and not isinstance(v, str) else [v] for v in data.values()]
        n = max((len(c) for c in cols), default=0)
        rows = [[c[i] if i < len(c) else "" for c in cols] for i in range(n)]
    else:
        header, rows = data
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(csv_header(header))
        for r in rows:
            w.writerow([repr(float(v)) if isinstance(v, float) else csv_cell(v) for v in r])


#: suffix of a figure's data file: ``<stem>.plot.csv``, never ``<stem>.csv`` (a figure named after a
#: library ``wood.npz`` must not replace the tap recording ``wood.csv`` it was built from)
DATA_SUFFIX = ".plot.csv"


def _stem(path) -> Path:
    path = Path(path)
    if path.name.endswith(DATA_SUFFIX):
        return path.with_name(path.name[:-len(DATA_SUFFIX)])
    return path.with_suffix("") if path.suffix in (".png", ".svg", ".pdf", ".csv") else path


def outputs(path, formats=FORMATS, data: bool = True) -> list[Path]:
    """The files :func:`save` writes for ``path``: ``<stem>.<fmt>`` per format, then ``<stem>.plot.csv``."""
    stem = _stem(path)
    return [stem.with_name(stem.name + "." + fmt) for fmt in formats] + (
        [stem.with_name(stem.name + DATA_SUFFIX)] if data else [])


def check_outputs(path, formats=FORMATS, data: bool = True, force: bool = False, flag: str = "--force") -> list[Path]:
    """Refuse (``ValueError`` naming every one) if any file :func:`save` would write exists, unless ``force``;
    a folder or a file in place of the parent folder is refused always. Returns the files."""
    if Path(path).is_dir():  # "--out results/" meant a folder: the files would land beside it, named after it
        raise ValueError(f"{path} is a folder; a figure is written as files ({Path(path).name}.png, ...): give a "
                         "file name, e.g. " + str(Path(path) / "figure.png"))
    targets = outputs(path, formats, data)
    for t in targets:
        if t.is_dir():
            raise ValueError(f"{t} is a folder; a figure is written as files: choose another file name")
    for parent in targets[0].parents:  # all of them live in one folder (figstyle imports nothing of plumbing.fileio)
        if parent.exists() and not parent.is_dir():
            raise ValueError(f"cannot write {targets[0]}: {parent} is a file, not a folder")
    found = [str(t) for t in targets if t.exists()]
    if found and not force:
        raise ValueError(f"{', '.join(found)} exist{'s' if len(found) == 1 else ''}; not overwriting "
                         f"{'it' if len(found) == 1 else 'them'}: choose another file name or pass {flag} to replace "
                         f"{'it' if len(found) == 1 else 'them'}")
    return targets


def save(fig, path, data=None, formats=FORMATS, close: bool = True, force: bool = False) -> dict:
    """Save ``fig`` as ``<stem>.png`` and ``<stem>.svg`` and its data as ``<stem>.plot.csv``.

    Every file it would write is checked first (:func:`check_outputs`): if one exists and ``force``
    is false nothing is written and ``ValueError`` names the existing files.

    Files are written under unique temporary names beside their targets (``.<name>.<random>.tmp``,
    created exclusively: two runs never share one) and renamed, so a crash never leaves half a figure;
    a failed write removes its temporary file. PNG and SVG carry no date, so the same figure gives the
    same bytes (a committed gallery only changes when a figure does).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : str or Path
        Target; its suffix is ignored (``fig_x.png`` and ``fig_x`` both give ``fig_x.png/.svg/.plot.csv``).
    data : DataFrame, dict of columns, (header, rows) or None
        The plotted numbers in SI-derived units named in the column headers.
    formats : tuple of str
        Image formats (``png``, ``svg``, ``pdf``).
    close : bool
        Close the figure afterwards.
    force : bool
        Replace existing files (the caller checked them, e.g. its own output folder, or ``--force``).

    Returns
    -------
    dict
        Format (``png``, ``svg``, ``csv``) -> Path written.
    """

    targets = check_outputs(path, formats, data is not None, force)
    stem = _stem(path)
    stem.parent.mkdir(parents=True, exist_ok=True)
    out = {}
    meta = {"png": {"Software": None}, "svg": {"Date": None, "Creator": None}, "pdf": {"CreationDate": None}}
    with plt.style.context(str(STYLE_PATH)):     # the save options (dpi, tight box, SVG text) apply here
        box = None
        for fmt in formats:
            target = stem.with_name(stem.name + "." + fmt)
            with _temporary(target) as tmp:
                if box is None:
                    with _tight_box_kept(fig) as kept:
                        fig.savefig(tmp, format=fmt, metadata=meta.get(fmt))
                    box = kept.get("box")
                else:
                    with _layout_kept(fig):
                        fig.savefig(tmp, format=fmt, metadata=meta.get(fmt), bbox_inches=box)
            out[fmt] = target
    if data is not None:
        target = targets[-1]
        with _temporary(target) as tmp:
            _write_csv(tmp, data)
        out["csv"] = target
    if close:
        plt.close(fig)
    return out


def _layout_inactive(fig) -> bool:
    """True if no layout engine lays ``fig`` out when it is drawn: none, or a layout computed once and kept
    (``set_layout_engine("none")`` after it ran leaves a placeholder that does nothing)."""
    engine = fig.get_layout_engine()
    return engine is None or isinstance(engine, PlaceHolderLayoutEngine)


@contextlib.contextmanager
def _tight_box_kept(fig):
    """Keep the padded tight bounding box (inches) the next ``savefig`` computes, for the figure's other formats.

    With ``savefig.bbox: tight`` each ``savefig`` lays the figure out once more only to measure it; that pass
    was half of a figure's drawing time. The first format (PNG) measures it as always, with the renderer at
    the saved resolution; the other formats reuse that box. It differs from an SVG's own measurement only by the
    renderers' text metrics (about a point), less than the box's pad (``savefig.pad_inches``), so nothing is cut. ``matplotlib`` computes the box by calling the figure's
    ``get_tightbbox`` and pads it by ``savefig.pad_inches``; where a ``matplotlib`` computes it otherwise,
    nothing is kept and every format measures its own box, as before.

    Before it measures, ``savefig`` draws the figure once without rendering, for a layout engine to lay it
    out. A figure of flat axes that no engine lays out gains nothing from that draw (the measurement places
    titles, tick and axis labels, legends and aspect-locked axes itself, and the rendering draw after it does
    again), so it is skipped: the same box and the same image for a third less work. Figures with other axes
    (3-D: their projection is set by a draw) are drawn first as before.
    """
    kept: dict = {}
    measure = fig.get_tightbbox
    draw = fig.draw
    skip_first_draw = (matplotlib.rcParams["savefig.bbox"] == "tight" and _layout_inactive(fig)
                       and all(ax.name == "rectilinear" for ax in fig.get_axes()))

    def keep(*args, **kwargs):
        kept["measured"] = True
        box = measure(*args, **kwargs)
        pad = matplotlib.rcParams["savefig.pad_inches"]
        if "box" not in kept and matplotlib.rcParams["savefig.bbox"] == "tight" and not isinstance(pad, str):
            kept["box"] = Bbox(box.get_points()).padded(pad)
        return box

    def draw_after_measuring(*args, **kwargs):
        if skip_first_draw and "measured" not in kept:
            return None          # the draw before the measurement: nothing to lay out
        return draw(*args, **kwargs)

    fig.get_tightbbox = keep
    fig.draw = draw_after_measuring
    try:
        yield kept
    finally:
        del fig.get_tightbbox          # the class's methods again
        del fig.draw


@contextlib.contextmanager
def _layout_kept(fig):
    """Leave out ``savefig``'s draw before the rendering when no layout engine is at work (:func:`_layout_inactive`).

    ``savefig`` draws a figure that has a layout engine once without rendering, for the engine to lay it out,
    even when the engine is the placeholder of a layout computed once and kept (nothing to lay out): with the
    box given (the first format's), that draw was a third of every further format's work. The figure is then
    saved as one without an engine, and gets its placeholder back afterwards.
    """
    engine = fig.get_layout_engine()
    if not isinstance(engine, PlaceHolderLayoutEngine):
        yield
        return
    fig._layout_engine = None      # matplotlib's own attribute: set_layout_engine(None) may pick one from rc
    try:
        yield
    finally:
        fig._layout_engine = engine


@contextlib.contextmanager
def _temporary(target: Path):
    """A unique temporary file beside ``target`` (``.<name>.<random>.tmp``, made exclusively), renamed over
    ``target`` when the block ends, removed when it fails: two writers of one figure never collide and a
    failure leaves nothing behind."""
    fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~current_umask())   # an ordinary file's mode, not mkstemp's 0600
        tmp.replace(target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


CONTAINERS = ("Figure", "SubFigure", "Axes", "XAxis", "YAxis", "Tick", "XTick", "YTick")


def _legends(fig) -> list:
    return [a for a in fig.findobj(Legend)]


def legend_overlaps(fig) -> list[str]:
    """Every visible artist whose drawn bounding box overlaps a legend's (empty list: none).

    Draws the figure (without writing it) and compares each legend's window extent with the
    extents of all other visible artists of the figure (axes, lines, patches, texts, images,
    collections, tick labels, other legends), excluding the legend's own children and the
    figure background.
    """

    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    problems = []
    legends = _legends(fig)
    for leg in legends:
        lb = leg.get_window_extent(renderer)
        own = {id(a) for a in leg.findobj()}
        for art in fig.findobj():
            if id(art) in own or art is fig or art is fig.patch or not art.get_visible():
                continue
            if type(art).__name__ in CONTAINERS:    # their extents are the union of their children's
                continue
            ax = getattr(art, "axes", None)
            if ax is not None and art is ax.patch and not (ax.axison and ax.get_frame_on()):
                continue                              # the background of a panel turned off is not drawn
            if hasattr(art, "get_text") and not art.get_text():
                continue
            try:
                ab = art.get_window_extent(renderer)
            except (TypeError, RuntimeError, NotImplementedError, AttributeError):
                continue
            if ab is None or not all(map(lambda v: v == v and abs(v) != float("inf"), ab.extents)):
                continue
            if ab.width <= 0.5 and ab.height <= 0.5:
                continue
            inter = Bbox.intersection(lb, ab)
            if inter is not None and inter.width > 0.5 and inter.height > 0.5:
                problems.append(f"legend {_legend_name(leg)!r} overlaps {type(art).__name__} "
                                f"{_artist_name(art)!r}")
    return problems


def _drawn_texts(fig) -> list:
    """The figure's visible, non-empty texts as drawn: titles, axis and tick labels (only the ticks inside the
    view), annotations and figure texts; legends' own texts are left to :func:`legend_overlaps`."""
    from matplotlib.legend import Legend
    from matplotlib.text import Text

    in_legend = {id(a) for leg in fig.findobj(Legend) for a in leg.findobj()}
    ticks_all, ticks_drawn = set(), set()
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                ticks_all.update((id(tick.label1), id(tick.label2)))
            if not (axis.get_visible() and ax.axison):
                continue
            # matplotlib keeps tick labels beyond the view limits (not drawn): only those inside count
            lo, hi = sorted(axis.get_view_interval())
            span = abs(hi - lo) * 1e-9
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                loc = tick.get_loc()
                if loc is not None and lo - span <= loc <= hi + span and tick.get_visible():
                    ticks_drawn.update(id(lb) for lb in (tick.label1, tick.label2) if lb.get_visible())
    out = []
    for t in fig.findobj(Text):
        if id(t) in in_legend or not t.get_visible() or not t.get_text().strip():
            continue
        if id(t) in ticks_all and id(t) not in ticks_drawn:
            continue
        if t.axes is not None and not t.axes.get_visible():
            continue
        out.append(t)
    return out


def text_problems(fig, tight: bool | None = None, tolerance_px: float = 1.0) -> list[str]:
    """Texts that overlap each other or run off the figure (empty list: every label readable).

    Draws the figure (without writing it) and compares the window extents (``Text.get_window_extent``, pixels)
    of every drawn text (:func:`_drawn_texts`): two that share more than ``tolerance_px`` in both directions
    overlap (e.g. the x labels of narrow neighbouring panels, or crowded tick labels); a text outside the
    figure's box is clipped when the figure is saved without a tight box (``tight``: default from
    ``savefig.bbox``; with ``tight`` the saved box grows to hold it).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    tight : bool or None
        Whether the figure will be saved with a tight bounding box.
    tolerance_px : float
        Overlap (px, both directions) below which two boxes only touch.

    Returns
    -------
    list of str
        One line per problem, naming the texts.
    """
    import matplotlib as mpl
    from matplotlib.transforms import Bbox

    if tight is None:
        tight = mpl.rcParams["savefig.bbox"] == "tight"
    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    boxes = [(t, t.get_window_extent(renderer)) for t in _drawn_texts(fig)]
    problems = []
    for i, (a, ba) in enumerate(boxes):
        for b, bb in boxes[i + 1:]:
            inter = Bbox.intersection(ba, bb)
            if inter is not None and inter.width > tolerance_px and inter.height > tolerance_px:
                problems.append(f"text {a.get_text()!r} overlaps text {b.get_text()!r}")
    if not tight:
        fb = fig.bbox
        for t, bb in boxes:
            if (bb.x0 < fb.x0 - tolerance_px or bb.y0 < fb.y0 - tolerance_px or bb.x1 > fb.x1 + tolerance_px
                    or bb.y1 > fb.y1 + tolerance_px):
                problems.append(f"text {t.get_text()!r} is clipped by the figure's edge")
    return problems


def _legend_name(leg) -> str:
    texts = [t.get_text() for t in leg.get_texts()]
    return ", ".join(texts[:3]) + (" ..." if len(texts) > 3 else "")


def _artist_name(art) -> str:
    if hasattr(art, "get_text"):
        return art.get_text()
    label = art.get_label() if hasattr(art, "get_label") else ""
    return label or ""


def unlabelled_axes(fig) -> list[str]:
    """Axis labels that lack a unit in parentheses, e.g. ``time (ms)`` (empty list: all have one).

    Only axes with visible numeric tick labels count; a categorical axis (sample names) and an
    empty label of a shared axis are not checked. Dimensionless quantities name their scale,
    e.g. ``rating (1–7)`` or ``Cohen's d_z (1)``.
    """

    fig.draw_without_rendering()
    bad = []
    for ax in fig.axes:
        for axis, name in ((ax.xaxis, "x"), (ax.yaxis, "y")):
            label = axis.get_label().get_text()
            if not axis.get_visible() or not label:
                continue
            ticks = [t.get_text() for t in axis.get_ticklabels() if t.get_visible() and t.get_text()]
            numeric = ticks and all(re.fullmatch(r"[−\-+0-9.,eE×^$\\{}a-z ]*", t) for t in ticks)
            if numeric and not re.search(r"\(.+\)", label):
                bad.append(f"{ax.get_title() or 'axes'} {name}: {label!r}")
    return bad
