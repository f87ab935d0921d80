"""``python -m stimuli show``: plot an HFAM library like thesis Figure 4.8."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib import colormaps

import figstyle

from .library import HfamLibrary


def summary(lib: HfamLibrary) -> str:
    """Human-readable description of a library."""
    lines = [
        f"{lib.source}: {len(lib.velocities_m_s)} velocities x {len(lib.grips_N)} grip level(s) x "
        f"{lib.n_samples} samples at {lib.fs_hz:g} Hz ({lib.duration_s * 1e3:.0f} ms)",
        "  velocities m/s: " + ", ".join(f"{v:.4g}" for v in lib.velocities_m_s),
        "  grips N: " + ", ".join(f"{g:.3g}" for g in lib.grips_N),
        f"  force constant {lib.force_per_amp_N_A:.4g} N/A, peak |current| {np.max(np.abs(lib.currents_A)):.3f} A, "
        f"gain {lib.gain:g}, extrapolation cap {lib.max_extrapolation:g}",
    ]
    meta = lib.metadata
    if meta.get("software_version"):
        lines.append(f"  built {meta.get('created_utc', '?')} by {meta['software_version']}")
    ver = meta.get("verification") or []
    if ver:
        worst = max(ver, key=lambda r: r["nrmse"])
        lines.append(f"  verification: worst NRMSE {worst['nrmse']:.3f} (corr {worst['corr']:.3f}) at "
                     f"{worst['v_in_m_s']:.4g} m/s, grip {worst['grip_N']:g} N")
    return "\n".join(lines)


def library_title(lib: HfamLibrary) -> str:
    """The library figure's title: the library's name once ("HFAM library library.npz" read badly).

    A file named after what it is (``library.npz``, ``hfam_library.npz``) adds nothing to "HFAM library"; any
    other name (``wood_on_foam_sim.npz``) is given in quotes.
    """
    stem = Path(str(lib.source or "")).stem
    plain = stem.lower().replace("-", "_").replace("hfam", "").strip("_ ") in ("", "library", "lib")
    name = "" if plain else f" \u201c{stem}\u201d"
    return f"HFAM library{name} (cf. thesis Fig. 4.8)"


def plot_library(lib: HfamLibrary, out: Path, force: bool = False) -> Path:
    """Figure 4.8: desired accelerations (top row) and current transients (bottom row), one column per grip.

    Saved in the project style as ``out`` (PNG) plus SVG and ``<stem>.plot.csv`` of every plotted trace
    (figstyle); the demo's library figure is this same plot. Refuses (``ValueError``) before drawing if
    any of the three exists, unless ``force``.

    Parameters
    ----------
    lib : HfamLibrary
    out : Path
        PNG to write.

    Returns
    -------
    Path
        The PNG.
    """

    figstyle.check_outputs(out, force=force)   # before drawing: the PNG, SVG and .plot.csv
    n_g = len(lib.grips_N)
    t_ms = (np.arange(lib.n_samples) + 1) / lib.fs_hz * 1e3
    data = {"t_ms": t_ms}
    with figstyle.style() as plt:

        fig, axes = plt.subplots(2, n_g, figsize=figstyle.figsize("page", height_in=4.6), sharex=True,
                                 squeeze=False, layout="constrained")
        colors = colormaps[figstyle.palette()["sequential"]](np.linspace(0.0, 0.9, len(lib.velocities_m_s)))
        for j, grip in enumerate(lib.grips_N):
            ax_a, ax_i = axes[0, j], axes[1, j]
            for i, v in enumerate(lib.velocities_m_s):
                label = f"{v:.3g} m/s"
                if lib.desired_accel_m_s2 is not None and j == 0:
                    ax_a.plot(t_ms, lib.desired_accel_m_s2[i], color=colors[i], lw=0.8, label=label)
                    data[f"accel {v:.4g} m/s (m/s^2)"] = lib.desired_accel_m_s2[i]
                elif lib.desired_accel_m_s2 is not None:
                    ax_a.plot(t_ms, lib.desired_accel_m_s2[i], color=colors[i], lw=0.8)
                ax_i.plot(t_ms, lib.currents_A[i, j], color=colors[i], lw=0.8)
                data[f"current {v:.4g} m/s grip {grip:g} N (A)"] = lib.currents_A[i, j]
            ax_a.set_title(f"grip {grip:g} N", loc="left")
            if j == 0:
                ax_a.set_ylabel("desired acceleration (m/s²)")
                ax_i.set_ylabel("current (A)")
            if lib.desired_accel_m_s2 is None:
                ax_a.text(0.5, 0.5, "no accelerations stored", ha="center", transform=ax_a.transAxes)
        if lib.desired_accel_m_s2 is not None:
            fig.legend(handles=axes[0, 0].lines, loc="outside right upper", title="incoming velocity")
        # one x label for the row: a label per column ran into its neighbours with five grips on a page
        fig.supxlabel("time after impact (ms)", fontsize=plt.rcParams["axes.labelsize"])
        fig.suptitle(library_title(lib))
        paths = figstyle.save(fig, out, data, force=force)
    return paths["png"]


def run(args) -> int:
    """The ``show`` command: print a library's summary and plot it (like Figure 4.8) to a PNG; returns the exit code."""
    lib = HfamLibrary.load(args.library)
    print(summary(lib))
    out = args.out if args.out is not None else args.library.with_suffix(".png")
    png = plot_library(lib, out, force=args.force)   # refuses an existing PNG, SVG or .plot.csv unless --force
    print(f"wrote {png}")
    return 0
