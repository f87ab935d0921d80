"""``python -m figstyle.gallery [--out docs/gallery]``: regenerate the figure gallery of the docs.

Runs the project's own commands in subprocesses (so this leaf package imports none of the
others): a synthetic study (``python -m analysis synthetic``) analysed by ``python -m analysis
report``, and the simulated demo (``python -m renderer demo --device sim``, which also draws the
identification's Bode plot and the HFAM library). Copies every figure (PNG, SVG, .plot.csv) into
``OUT/study`` and ``OUT/demo`` and writes ``OUT/README.md`` with the captions.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

# captions of the demo figures (the study's come from its report.md)
DEMO_CAPTIONS = {
    "fig_contact": "Handle acceleration at contact on the simulated device at one incoming velocity and grip: "
                   "proportional wall, pulse, decaying sinusoid and HFAM over the firm wall, each against the "
                   "real wood-on-foam recording (dashed grey). Same scale in every panel, so magnitudes compare "
                   "directly; the dotted line marks contact (thesis Figures 4.11/4.20).",
    "fig_hfam_grid": "HFAM over the firm wall at three velocities (rows) and three grips (columns) against the "
                     "real recording (dashed), with the current transients on the right (thesis Figure 4.13). "
                     "Look at how the grip-interpolated transient keeps the shape across grips where the "
                     "medium-grip transient (dotted) does not.",
    "fig_library": "The HFAM library (thesis Figure 4.8): target accelerations per incoming velocity (top) and the "
                   "current transients per grip level that reproduce them (bottom).",
    "fig_bode": "Identification of the simulated device (thesis Figures 3.8/3.12): ETFE per grip (solid; faint "
                "where the coherence is low) with the fitted models (dashed), resonance (▲) and the -3 dB point "
                "above it (▽) marked; phase unwrapped from the low-frequency end in ±180°.",
}
# the code that draws the gallery's figures: their digest is written beside the gallery (SOURCES_FILE) and the
# suite checks it (tests/integration/test_figure_style.py), so a change to how a figure is drawn without
# `make gallery` fails the tests instead of leaving the committed gallery stale
FIGURE_SOURCES = ("figstyle/__init__.py", "figstyle/project.mplstyle", "figstyle/palette.json", "figstyle/gallery.py",
                  "analysis/figures.py", "renderer/demo/figures.py", "stimuli/cli_show.py",
                  "devices/identify/figures.py", "renderer/demo/table3d.py")
#: the 3-D demo's caption (``python -m renderer.demo.table3d``)
TABLE3D_CAPTION = ("Figure 4.19's virtual samples side by side on a virtual table (examples/samples_table.toml), "
                   "tapped by the simulated person on the 3-DOF sim at 0.08, 0.1 and 0.12 m/s: from above (pulse over "
                   "the firm wall, the soft wall), 30 degrees off vertical (decaying sinusoid over the firm wall) and "
                   "into the side of the very firm block. Left: the endpoint's paths and the contacts over the blocks' "
                   "tops. Right: per tap the endpoint's depth behind the contacted surface and the force along the "
                   "contact normal, aligned at contact; look at the transients (the pulse's step, the sinusoid's "
                   "first cycle) acting along the normal whatever the tap's direction, and at the soft wall letting "
                   "the tap in three times deeper.")
SOURCES_FILE = "sources.sha256"


def sources_digest(root: Path) -> str:
    """``sha256  path`` per file of :data:`FIGURE_SOURCES` under ``root`` (the repository), one line each, as
    ``sha256sum`` prints them (line endings normalised, so a checkout's CRLF does not count as a change)."""
    lines = []
    for rel in FIGURE_SOURCES:
        data = (Path(root) / rel).read_bytes().replace(b"\r\n", b"\n")
        lines.append(f"{hashlib.sha256(data).hexdigest()}  {rel}")
    return "\n".join(lines) + "\n"


STUDY_ORDER = ("fig_4_17_ratings", "fig_4_18_pvalues", "fig_4_19_penetration", "fig_4_20_accelerations")


def _run(cmd: list[str], cwd: Path) -> None:
    print("$ " + " ".join(cmd[1:] if cmd[0] == sys.executable else cmd), flush=True)
    proc = subprocess.run(cmd, cwd=cwd, text=True, capture_output=True)
    if proc.returncode != 0:
        sys.stderr.write(proc.stdout[-2000:] + proc.stderr[-4000:])
        raise SystemExit(f"error: {' '.join(cmd[1:4])} failed with exit code {proc.returncode}")


def _study_captions(report_md: Path) -> dict:
    lines = report_md.read_text(encoding="utf-8").splitlines()
    out = {}
    for i, line in enumerate(lines):
        m = re.match(r"!\[[^\]]*\]\(([^)]+)\.png\)", line)
        if m and i + 2 < len(lines) and lines[i + 2].startswith("*"):
            out[m.group(1)] = lines[i + 2].strip("*")
    return out


# CSVs larger than this stay out of the committed gallery (the command writes them next to each figure)
MAX_CSV_BYTES = 400_000


def _copy(src_dir: Path, stem: str, dst_dir: Path, formats) -> list[str]:
    names = []
    for ext in formats:
        src = src_dir / f"{stem}.{ext}"
        if src.exists() and not (ext.endswith("csv") and src.stat().st_size > MAX_CSV_BYTES):
            shutil.copyfile(src, dst_dir / src.name)
            names.append(src.name)
    return names


def build(out: Path, subjects: int = 16, seed: int = 0, formats=("png", "svg", "plot.csv")) -> Path:
    """Regenerate the gallery into ``out``; returns the path of its README.md.

    Parameters
    ----------
    out : Path
        Gallery folder (``study/`` and ``demo/`` inside are replaced).
    subjects, seed : int
        Size and seed of the synthetic study (its session seeds follow from ``seed``).
    formats : tuple of str
        File kinds copied per figure.
    """
    root = Path(__file__).resolve().parents[1]
    out = Path(out).resolve()
    py = sys.executable
    with tempfile.TemporaryDirectory(prefix="gallery-") as tmp:
        tmp = Path(tmp)
        _run([py, "-m", "analysis", "synthetic", str(tmp / "data"), "--subjects", str(subjects), "--seed",
              str(seed), "--traces", "2"], root)
        _run([py, "-m", "analysis", "report", str(tmp / "data"), "--out", str(tmp / "report")], root)
        _run([py, "-m", "renderer", "demo", "--device", "sim", "--out", str(tmp / "demo"), "--scope", "none"], root)
        _run([py, "-m", "renderer.demo.table3d", "--out", str(tmp / "table3d")], root)
        for sub in ("study", "demo", "dof3"):
            shutil.rmtree(out / sub, ignore_errors=True)
            (out / sub).mkdir(parents=True)
        captions = _study_captions(tmp / "report" / "report.md")
        md = ["# Figure gallery", "",
              "Generated by `make gallery` (`python -m figstyle.gallery`) from a synthetic study "
              f"({subjects} subjects, seed {seed}; `python -m analysis synthetic`, not a model of human "
              "perception) and the simulated demo (`python -m renderer demo --device sim`). Every figure is "
              "drawn in the project style (`figstyle`, docs/figures.md) and saved as PNG and SVG with the "
              "plotted numbers as CSV beside it (CSVs over 400 kB are left out of the committed gallery; "
              "the commands write them).", "", "## Realism study (thesis section 4.5)", ""]
        for stem in STUDY_ORDER:
            files = _copy(tmp / "report", stem, out / "study", formats)
            if not files:
                continue
            md += [f"![{captions.get(stem, stem).split(':')[0]}](study/{stem}.png)", "",
                   captions.get(stem, ""), "",
                   "Files: " + ", ".join(f"[{n.rsplit('.', 1)[1].upper()}](study/{n})" for n in files), ""]
        md += ["## Simulated demo (thesis sections 3.3, 4.4)", ""]
        for stem, caption in DEMO_CAPTIONS.items():
            files = _copy(tmp / "demo", stem, out / "demo", formats)
            if not files:
                continue
            md += [f"![{stem}](demo/{stem}.png)", "", caption, "",
                   "Files: " + ", ".join(f"[{n.rsplit('.', 1)[1].upper()}](demo/{n})" for n in files), ""]
        md += ["## Three degrees of freedom (docs/renderer.md, \"3-D rendering\")", ""]
        files = _copy(tmp / "table3d", "table3d", out / "dof3", formats)
        md += ["![table3d](dof3/table3d.png)", "", TABLE3D_CAPTION, "",
               "Files: " + ", ".join(f"[{n.rsplit('.', 1)[1].upper()}](dof3/{n})" for n in files), ""]
    readme = out / "README.md"
    readme.write_text("\n".join(md) + "\n", encoding="utf-8")
    (out / SOURCES_FILE).write_text(sources_digest(root), encoding="utf-8")
    return readme


def main(argv=None) -> int:
    """Command line of :func:`build`."""
    p = argparse.ArgumentParser(prog="python -m figstyle.gallery", description=__doc__.splitlines()[0])
    p.add_argument("--out", default="docs/gallery", help="gallery folder (default docs/gallery)")
    p.add_argument("--subjects", type=int, default=16, help="synthetic subjects (default 16)")
    p.add_argument("--seed", type=int, default=0, help="seed of the synthetic study (default 0)")
    args = p.parse_args(argv)
    os.environ.setdefault("MPLBACKEND", "Agg")
    print(f"wrote {build(Path(args.out), args.subjects, args.seed)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
