"""The figure of one ``renderer run``: position against the wall, forces, acceleration and the contact events.

A user sees what happened in a run beside its ``events.csv`` / ``log.npz``. Drawn in the
command's own process after the run is saved (never in the servo process), in the project style (figstyle,
docs/figures.md), as ``run.png`` / ``run.svg`` and the plotted numbers as ``run.plot.csv``. A long log is
reduced to a min/max envelope per bucket (:func:`envelope`), so every peak (an impact's acceleration spike, a
transient's first cycle) stays in the figure and the CSV stays small.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import figstyle

#: at most this many buckets (two points each) per channel in the figure and its CSV
MAX_BUCKETS = 1500


def envelope(t: np.ndarray, y: np.ndarray, buckets: int = MAX_BUCKETS) -> tuple[np.ndarray, np.ndarray]:
    """A min/max envelope of ``y(t)``: per bucket of consecutive samples its minimum and maximum, in the order
    they occurred, placed at the bucket's first and last sample times.

    Parameters
    ----------
    t, y : ndarray, shape (n,)
        Sample times (s) and values.
    buckets : int
        Number of buckets; a log no longer than ``2 * buckets`` is returned unchanged.

    Returns
    -------
    (t_out, y_out) : ndarrays of equal length (<= 2 buckets)
    """
    n = len(y)
    if n <= 2 * buckets:
        return np.asarray(t, float), np.asarray(y, float)
    per = int(np.ceil(n / buckets))
    m = (n // per) * per
    yy = np.asarray(y[:m], float).reshape(-1, per)
    tt = np.asarray(t[:m], float).reshape(-1, per)
    rows = np.arange(len(yy))
    imin, imax = np.nanargmin(yy, axis=1), np.nanargmax(yy, axis=1)
    first, second = np.minimum(imin, imax), np.maximum(imin, imax)
    # the bucket's first and last sample times (the same for every channel of a log, so one time column
    # serves them all), carrying its two extremes in the order they occurred
    t_out = np.column_stack([tt[:, 0], tt[:, -1]]).ravel()
    y_out = np.column_stack([yy[rows, first], yy[rows, second]]).ravel()
    return t_out, y_out


def run_figure_data(result) -> dict:
    """The numbers the run's figure plots (SI units, named in the keys).

    Parameters
    ----------
    result : renderer.RunResult
        A finished (or partial) run.

    Returns
    -------
    dict
        ``t_s``, ``position_mm``, ``force_N`` (the commanded force after saturation: ``current_A`` x the
        device's ``rho k_t / h``, eq. 3.17), ``force_prop_N``, ``force_transient_N``, ``accel_m_s2`` (each
        the envelope of :func:`envelope`, sampled at the position's bucket times), ``wall_mm`` (the wall's
        height), ``event_t_s``, ``event_v_m_s``, ``title``, ``on_device`` (the board rendered the wall and the
        transient: their forces are NaN, not zero, since the board does not report them).
    """
    log = result.log
    t = np.asarray(log["t_s"], float)
    dev = result.device or {}
    try:
        kf = float(dev["gear_ratio"]) * float(dev["torque_constant_Nm_A"]) / float(dev["handle_length_m"])
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        kf = float("nan")
    cfg = result.config or {}
    scene = cfg.get("scene") or {}
    objects = scene.get("objects") if isinstance(scene, dict) else None
    wall = cfg.get("wall_height_m", 0.0)
    if objects and isinstance(objects[0], dict) and "height_m" in objects[0]:
        wall = objects[0]["height_m"]
    out = {}
    channels = {"position_mm": 1000.0 * np.asarray(log["position_m"], float),
                "force_N": kf * np.asarray(log["current_A"], float),
                "force_prop_N": np.asarray(log["force_prop_N"], float),
                "force_transient_N": np.asarray(log["force_transient_N"], float),
                "accel_m_s2": np.asarray(log["accel_m_s2"], float)}
    # on-device rendering: the board computes the wall and the transient and sends only what it commanded (the
    # current); the host's log holds zeros for the parts, which must not be drawn as forces of zero
    on_device = bool((result.timing or {}).get("on_device"))
    for name, y in channels.items():
        te, ye = envelope(t, y) if len(t) else (t, y)
        out.setdefault("t_s", te)
        out[name] = ye
    if on_device:
        out["force_prop_N"] = np.full(len(out["t_s"]), np.nan)
        out["force_transient_N"] = np.full(len(out["t_s"]), np.nan)
    out["on_device"] = on_device
    out["wall_mm"] = 1000.0 * float(wall)
    out["event_t_s"] = np.array([e.t_s for e in result.events], float)
    out["event_v_m_s"] = np.array([e.incoming_velocity_m_s for e in result.events], float)
    k = cfg.get("stiffness_N_m")
    out["title"] = (f"renderer run: wall {'' if k is None else f'k = {float(k):g} N/m, '}transient "
                    f"{result.transient}, {len(result.events)} contact events, stop: {result.stop_reason}")
    return out


def plot_run(data: dict):
    """Draw :func:`run_figure_data`'s numbers: position and wall, forces, acceleration; events marked.

    Returns
    -------
    matplotlib.figure.Figure
    """
    with figstyle.style() as plt:
        fig, axes = plt.subplots(3, 1, figsize=figstyle.figsize("page", height_in=5.2), sharex=True,
                                 layout="constrained")
        t = data["t_s"]
        ax = axes[0]
        ax.plot(t, data["position_mm"], color=figstyle.color("firm"), lw=0.8, label="handle position")
        ax.axhline(data["wall_mm"], color="0.3", lw=1.0, ls="--", label="wall surface")
        ax.set_ylabel("position (mm)")
        ax = axes[1]
        ax.plot(t, data["force_N"], color="black", lw=0.8, label="commanded force (after saturation)")
        if data.get("on_device"):
            ax.text(0.01, 0.97, "wall and transient forces computed on the board (not reported to the host):\n"
                    "the line is the total force it commanded", transform=ax.transAxes, va="top", ha="left",
                    fontsize="small", color="0.3")
        else:
            ax.plot(t, data["force_prop_N"], color=figstyle.color("firm"), lw=0.6, ls="--",
                    label="wall (proportional) force")
            ax.plot(t, data["force_transient_N"], color=figstyle.color("pulse_firm"), lw=0.6,
                    label="transient force")
        ax.set_ylabel("force (N)")
        ax = axes[2]
        ax.plot(t, data["accel_m_s2"], color=figstyle.color("hfam_firm"), lw=0.6, label="measured acceleration")
        ax.set_ylabel("acceleration (m/s²)")
        ax.set_xlabel("device time (s)")
        for j, ax in enumerate(axes):
            if len(data["event_t_s"]):  # one collection per axes (40 separate lines cost seconds of layout)
                ax.vlines(data["event_t_s"], 0.0, 1.0, transform=ax.get_xaxis_transform(), colors="0.55", lw=0.6,
                          linestyles=":", label="contact event" if j == 0 else None)
            ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, frameon=False)
        fig.suptitle(data["title"])
    return fig


def save_run_figure(result, out_dir) -> dict:
    """Draw the run's figure into ``out_dir`` (``run.png``, ``run.svg``, ``run.plot.csv``); returns the paths.

    The run's folder was checked (``--out``/``--force``) before the run: the files are replaced.
    """
    data = run_figure_data(result)
    fig = plot_run(data)
    table = {k: data[k] for k in ("t_s", "position_mm", "force_N", "force_prop_N", "force_transient_N",
                                  "accel_m_s2")}
    return figstyle.save(fig, Path(out_dir) / "run.png", table, force=True)
