"""``python -m figstyle.gallery [--out docs/gallery] [--readme-figures docs/img]``: regenerate the figure gallery.

Runs the project's own commands in subprocesses (so this leaf package imports none of the
others): a simulated realism study of the thesis's size -- sixteen subjects, each a ``python -m study run``
session of the simulated participant on the one-dof sim (seven who never used a haptic device, seven a few
times, two regularly: section 4.5.4) -- analysed by ``python -m analysis report`` (whose ``ranking.json`` holds
Figure 4.17's ordering and section 4.5.4's saturations), and the simulated demo (``python -m renderer demo``
on ``sim:onedof``, which also draws the identification's Bode plot and the HFAM library). Copies every figure
(PNG, SVG, .plot.csv) into ``OUT/study`` and ``OUT/demo`` and writes ``OUT/README.md`` with the captions.
``--readme-figures DIR`` also writes the README's two figures there: the demo's penetration figure and Figure
5.11 from ``python -m renderer teleop-sweep`` in Figure 5.11's condition. ``make artefacts``
(``plumbing.artefacts``) runs this and stamps the result.
"""

from __future__ import annotations

import argparse
import hashlib
import json
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


#: the study's subjects' prior experience, as section 4.5.4 reports the sixteen: "Seven of the subjects had never
#: used a haptic device before. Seven had used such systems a few times, and two reported using haptic interfaces
#: on a regular basis."
EXPERIENCE_16 = ("none",) * 7 + ("few",) * 7 + ("regular",) * 2


def _experience(k: int, n: int) -> str:
    """Subject ``k`` of ``n``'s experience: the thesis's 7/7/2 mix, scaled to ``n``."""
    return EXPERIENCE_16[min(len(EXPERIENCE_16) - 1, (k * len(EXPERIENCE_16)) // max(n, 1))]


def _run_sessions(py: str, data: Path, subjects: int, seed: int, root: Path, workers: int = 2) -> None:
    """One simulated session per subject (``python -m study run``), ``workers`` at a time."""
    cmds = [[py, "-m", "study", "run", "--participant", "simulated", "--subject", f"S{k + 1:02d}", "--seed",
             str(seed + k + 1), "--experience", _experience(k, subjects), "--out", str(data), "--quiet"]
            for k in range(subjects)]
    pending, running = list(cmds), []
    while pending or running:
        while pending and len(running) < workers:
            cmd = pending.pop(0)
            print("$ " + " ".join(cmd[1:]), flush=True)
            running.append((cmd, subprocess.Popen(cmd, cwd=root, text=True, stdout=subprocess.PIPE,
                                                  stderr=subprocess.PIPE)))
        cmd, proc = running.pop(0)
        so, se = proc.communicate()
        if proc.returncode != 0:
            sys.stderr.write(so[-2000:] + se[-4000:])
            raise SystemExit(f"error: {' '.join(cmd[1:4])} failed with exit code {proc.returncode}")


def build(out: Path, subjects: int = 16, seed: int = 0, formats=("png", "svg", "plot.csv"),
          readme_figures: Path | None = None) -> Path:
    """Regenerate the gallery into ``out``; returns the path of its README.md.

    Parameters
    ----------
    out : Path
        Gallery folder (``study/`` and ``demo/`` inside are replaced).
    subjects, seed : int
        Size of the simulated study and the seed of its first session (subject k runs with ``seed + k``).
    formats : tuple of str
        File kinds copied per figure.
    readme_figures : Path or None
        Also write the README's figures (``demo_penetration.png``, ``teleop_figure_5_11.png``) into this folder.
    """
    root = Path(__file__).resolve().parents[1]
    out = Path(out).resolve()
    py = sys.executable
    with tempfile.TemporaryDirectory(prefix="gallery-") as tmp:
        tmp = Path(tmp)
        _run_sessions(py, tmp / "data", subjects, seed, root)
        _run([py, "-m", "analysis", "report", str(tmp / "data"), "--out", str(tmp / "report")], root)
        _run([py, "-m", "renderer", "demo", "--device", "sim:onedof", "--out", str(tmp / "demo"), "--scope", "none",
              "--cache-dir", str(tmp / "cache")], root)
        _run([py, "-m", "renderer.demo.table3d", "--out", str(tmp / "table3d")], root)
        for sub in ("study", "demo", "dof3"):
            shutil.rmtree(out / sub, ignore_errors=True)
            (out / sub).mkdir(parents=True)
        captions = _study_captions(tmp / "report" / "report.md")
        checks = json.loads((tmp / "report" / "ranking.json").read_text(encoding="utf-8"))
        shutil.copyfile(tmp / "report" / "ranking.json", out / "study" / "ranking.json")
        md = ["# Figure gallery", "",
              "Generated by `make gallery` (`python -m figstyle.gallery`) from a simulated realism study "
              f"({subjects} subjects, seeds {seed + 1}-{seed + subjects}: `python -m study run --participant "
              "simulated` on the one-dof sim, with the synthetic rater, which is not a model of human perception) "
              "and the simulated demo (`python -m renderer demo --device sim:onedof`). Every figure is drawn in the "
              "project style (`figstyle`, docs/figures.md) and saved as PNG and SVG with the plotted numbers as CSV "
              "beside it (CSVs over 400 kB are left out of the committed gallery; the commands write them).", "",
              "## Realism study (thesis section 4.5)", "",
              "The study's ranking against the thesis's (`study/ranking.json`, from `python -m analysis report`):", ""]
        md += [f"- {line}" for line in _ranking_md(checks)] + [""]
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
        if readme_figures is not None:
            img = Path(readme_figures).resolve()
            img.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(tmp / "demo" / "fig_penetration.png", img / "demo_penetration.png")
            _run([py, "-m", "renderer", "teleop-sweep", "--lambda", "1,1.5,2,2.5,3,3.5,4,4.5,5,6", "--conditions",
                  "pf,pf+cimm", "--backlash-mm", "0.1", "--lambda-by-speed", "--cimm-model", "linear-linkage",
                  "--taps", "2", "--out", str(tmp / "fig511")], root)
            shutil.copyfile(tmp / "fig511" / "figure_5_11.png", img / "teleop_figure_5_11.png")
    readme = out / "README.md"
    readme.write_text("\n".join(md) + "\n", encoding="utf-8")
    (out / SOURCES_FILE).write_text(sources_digest(root), encoding="utf-8")
    return readme


def _ranking_md(checks: dict) -> list[str]:
    """The ranking lines of the gallery's README from ``ranking.json`` (``analysis.ranking``)."""
    lines = ["mean ratings, best first: " + ", ".join(f"{s} {m:.2f}" for s, m in checks["order"])]
    for key, words in (("real_wood_first", "real wood rated highest"),
                       ("hfam_first_virtual", "HFAM first among the virtual samples"),
                       ("proportional_near_foam", "proportional walls comparable to foam, below every event-based sample"),
                       ("saturations", "about six saturations per subject, mostly real wood and event-based")):
        c = checks[key]
        lines.append(f"{'met' if c['met'] else 'not met'}: {words} ({c['text']})")
    return lines


def main(argv=None) -> int:
    """Command line of :func:`build`."""
    p = argparse.ArgumentParser(prog="python -m figstyle.gallery", description=__doc__.splitlines()[0])
    p.add_argument("--out", default="docs/gallery", help="gallery folder (default docs/gallery)")
    p.add_argument("--subjects", type=int, default=16, help="simulated subjects (default 16, the thesis's)")
    p.add_argument("--seed", type=int, default=0, help="subject k's session runs with seed SEED + k (default 0)")
    p.add_argument("--readme-figures", default=None, metavar="DIR",
                   help="also write the README's figures into DIR (docs/img)")
    args = p.parse_args(argv)
    os.environ.setdefault("MPLBACKEND", "Agg")
    print(f"wrote {build(Path(args.out), args.subjects, args.seed, readme_figures=args.readme_figures)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
