"""The figure of a 3-D run: the endpoint's path, the proxy and the contacts in 3-D, and the normal-direction traces.

Drawn after the run is saved, in the command's process, through the project style (figstyle); the plotted
numbers are saved beside it (``run.plot.csv``), the log reduced to a min/max envelope
(``renderer.run_figure.envelope``) so every peak stays.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import figstyle

from .run_figure import MAX_BUCKETS, envelope


def run3_figure_data(result) -> dict:
    """The numbers the figure plots (SI units in the keys; mm for positions).

    ``t_s``; the envelopes of ``depth_mm`` (the endpoint's depth behind the contacted surface, > 0 inside),
    ``force_normal_N`` (the commanded force's component along the contact normal), ``force_transient_N``,
    ``accel_m_s2``; the path (``path_x_mm``, ... every ``stride``-th sample), the proxy in contact
    (``proxy_*_mm``), the contacts (``contact_*_mm``, ``event_t_s``, ``event_v_n_m_s``, ``event_object``).
    """
    log = result.log
    t = np.asarray(log["t_s"], float)
    n = np.stack([log["normal_x"], log["normal_y"], log["normal_z"]])
    f = np.stack([log["force_x_N"], log["force_y_N"], log["force_z_N"]])
    out = {}
    channels = {"depth_mm": 1000.0 * np.where(log["contact_object"] >= 0, log["penetration_m"], np.nan),
                "force_normal_N": np.sum(n * f, axis=0), "force_transient_N": np.asarray(log["force_transient_N"]),
                "accel_m_s2": np.asarray(log["accel_m_s2"])}
    for name, y in channels.items():
        te, ye = envelope(t, np.nan_to_num(y, nan=0.0)) if len(t) else (t, y)
        out.setdefault("t_s", te)
        out[name] = ye
    stride = max(1, len(t) // (2 * MAX_BUCKETS))
    for ax, key in (("x", "x_m"), ("y", "y_m"), ("z", "z_m")):
        out[f"path_{ax}_mm"] = 1000.0 * np.asarray(log[key])[::stride]
        inside = log["contact_object"][::stride] >= 0
        out[f"proxy_{ax}_mm"] = np.where(inside, 1000.0 * np.asarray(log[f"proxy_{ax}_m"])[::stride], np.nan)
    out["contact_x_mm"] = np.array([1000 * e.x_m for e in result.events])
    out["contact_y_mm"] = np.array([1000 * e.y_m for e in result.events])
    out["contact_z_mm"] = np.array([1000 * e.z_m for e in result.events])
    out["event_t_s"] = np.array([e.t_s for e in result.events])
    out["event_v_n_m_s"] = np.array([e.incoming_velocity_m_s for e in result.events])
    out["event_object"] = [e.object for e in result.events]
    out["title"] = (f"3-D run: {len(result.events)} contacts on {', '.join(sorted(set(out['event_object']))) or 'nothing'}"
                    f", transient {result.transient}, stop: {result.stop_reason}")
    return out


def plot_run3(data: dict):
    """Draw :func:`run3_figure_data`: the 3-D view beside the normal-direction traces. Returns the Figure."""
    with figstyle.style() as plt:
        fig = plt.figure(figsize=figstyle.figsize("page", height_in=5.2), layout="constrained")
        grid = fig.add_gridspec(3, 2, width_ratios=[1.0, 1.3])
        ax3 = fig.add_subplot(grid[:, 0], projection="3d")
        ax3.plot(data["path_x_mm"], data["path_y_mm"], data["path_z_mm"], color="0.55", lw=0.6, label="endpoint")
        ax3.plot(data["proxy_x_mm"], data["proxy_y_mm"], data["proxy_z_mm"], color=figstyle.color("firm"), lw=1.2,
                 label="proxy in contact")
        if len(data["contact_x_mm"]):
            ax3.scatter(data["contact_x_mm"], data["contact_y_mm"], data["contact_z_mm"], color="black", s=8,
                        label="contact events")
        ax3.set_xlabel("x (mm)")
        ax3.set_ylabel("y (mm)")
        ax3.set_zlabel("z (mm)")
        ax3.set_box_aspect(None, zoom=0.82)   # room for the z label beside the traces
        ax3.legend(loc="upper left", frameon=False)
        t = data["t_s"]
        rows = (("depth_mm", "depth behind surface (mm)", "firm"), ("force_normal_N", "force along normal (N)",
                "pulse_firm"), ("accel_m_s2", "acceleration (m/s²)", "hfam_firm"))
        axes = []
        for r, (key, label, col) in enumerate(rows):
            ax = fig.add_subplot(grid[r, 1], sharex=axes[0] if axes else None)
            ax.plot(t, data[key], color=figstyle.color(col), lw=0.7)
            if key == "force_normal_N":
                ax.plot(t, data["force_transient_N"], color="0.4", lw=0.5, ls="--", label="transient")
                ax.legend(loc="upper right", frameon=False)
            ax.set_ylabel(label)
            if len(data["event_t_s"]):
                ax.vlines(data["event_t_s"], 0.0, 1.0, transform=ax.get_xaxis_transform(), colors="0.6", lw=0.5,
                          linestyles=":")
            axes.append(ax)
        axes[-1].set_xlabel("device time (s)")
        fig.suptitle(data["title"])
    return fig


def save_run3_figure(result, out_dir) -> dict:
    """Draw the 3-D run's figure into ``out_dir`` (``run.png``, ``run.svg``, ``run.plot.csv``)."""
    data = run3_figure_data(result)
    fig = plot_run3(data)
    table = {k: data[k] for k in ("t_s", "depth_mm", "force_normal_N", "force_transient_N", "accel_m_s2")}
    return figstyle.save(fig, Path(out_dir) / "run.png", table, force=True)
