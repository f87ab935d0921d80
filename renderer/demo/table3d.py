"""Figure 4.19's samples on a virtual table, tapped by the simulated person from several directions (3-DOF sim).

``python -m renderer.demo.table3d --out DIR`` runs :data:`TAPS` on ``examples/samples_table.toml`` with the
3-D renderer on ``sim:3d`` (three taps each at 0.08, 0.1 and 0.12 m/s, 2 N grip) and draws ``table3d.png`` /
``.svg`` with the plotted numbers in ``table3d.plot.csv`` and one row per contact in ``table3d_events.csv``:
the endpoint's paths and the contacts in 3-D above the blocks, and for each tap its depth behind the
contacted surface and its force along the contact normal, aligned at contact.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np

import figstyle
from devices.sim import Sim3Device, TapTrajectory

from ..config import load_config
from ..loop3 import ServoLoop3, surface_point_above
from ..scene3 import pack_scene

SCENE = Path(__file__).resolve().parents[2] / "examples" / "samples_table.toml"
SPEEDS_M_S = (0.08, 0.1, 0.12)
#: (object, tap direction, label): straight down, 30 degrees off vertical, and into a block's side
TAPS = (("pulse_firm", (0.0, 0.0, -1.0), "pulse, firm: from above"),
        ("sinusoid_firm", (-0.5, 0.0, -math.sqrt(0.75)), "sinusoid, firm: 30 deg off vertical"),
        ("soft", (0.0, 0.0, -1.0), "soft wall: from above"),
        ("very_firm", (1.0, 0.0, 0.0), "very firm: into its side"))


def run_taps(scene_path=SCENE, seed: int = 0) -> list[dict]:
    """The demo's runs: per entry of :data:`TAPS` the run's result and where it tapped."""
    cfg = load_config(scene_path)
    out = []
    for name, direction, label in TAPS:
        dev = Sim3Device(seed=seed)
        packed = pack_scene(cfg.effective_scene, cfg.stiffness_N_m, dev.info.specs())
        j = packed.names.index(name)
        lo, hi = packed.bounds[j]
        if direction[2] < -0.5:
            # tap the top, the line through the block's centre offset against the tap's horizontal travel
            point, _, _ = surface_point_above(packed, name)
        else:
            # into the face the tap meets: its centre
            point = (lo[0] if direction[0] > 0 else hi[0], 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2]))
        plan = TapTrajectory(list(SPEEDS_M_S), n_taps=len(SPEEDS_M_S), approach_height_m=0.008)
        dev.set_user(plan, grip_N=2.0, target_m=point, direction=direction)
        res = ServoLoop3(dev, cfg).run(duration_s=plan.duration_s)
        out.append({"object": name, "label": label, "direction": direction, "target": point, "result": res})
    return out


def figure_data(runs: list[dict]) -> dict:
    """Per tap: the path (mm) and, aligned at each contact (-5..40 ms), depth (mm) and normal force (N)."""
    t_rel = np.arange(-50, 400) * 1e-4
    data = {"t_ms": 1000 * t_rel, "runs": []}
    for r in runs:
        res = r["result"]
        log = res.log
        n = np.stack([log["normal_x"], log["normal_y"], log["normal_z"]])
        f = np.stack([log["force_x_N"], log["force_y_N"], log["force_z_N"]])
        fn = np.sum(n * f, axis=0)
        depth = np.where(log["contact_object"] >= 0, log["penetration_m"], 0.0)
        traces = []
        for ev in res.events:
            idx = ev.tick + np.arange(-50, 400)
            idx = idx[(idx >= 0) & (idx < len(depth))]
            traces.append((1000 * depth[idx], fn[idx], ev))
        stride = 20
        data["runs"].append({"label": r["label"], "object": r["object"],
                             "path_mm": 1000 * np.stack([log["x_m"], log["y_m"], log["z_m"]])[:, ::stride],
                             "traces": traces, "events": res.events})
    return data


def plot(data: dict, scene_path=SCENE):
    """The demo's figure: 3-D paths over the blocks, depth and normal force per tap aligned at contact."""
    cfg = load_config(scene_path)
    packed = pack_scene(cfg.effective_scene, cfg.stiffness_N_m)
    colors = [figstyle.color(c) for c in ("pulse_firm", "sinusoid_firm", "soft", "very_firm")]
    with figstyle.style() as plt:
        fig = plt.figure(figsize=figstyle.figsize("page", height_in=5.0), layout="constrained")
        grid = fig.add_gridspec(2, 2, width_ratios=[1.1, 1.0])
        ax3 = fig.add_subplot(grid[:, 0], projection="3d")
        for j, b in enumerate(packed.bounds):
            if b is None:
                continue
            (x0, y0, z0), (x1, y1, z1) = 1000 * b[0], 1000 * b[1]
            xs, ys = [x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0]
            ax3.plot(xs, ys, [z1] * 5, color="0.7", lw=0.6)
            ax3.text(0.5 * (x0 + x1), 0.5 * (y0 + y1), z1 + 1.0, packed.names[j], fontsize=5, ha="center", color="0.4")
        for r, col in zip(data["runs"], colors):
            p = r["path_mm"]
            ax3.plot(p[0], p[1], p[2], color=col, lw=0.8, label=r["label"])
            ev = r["events"]
            ax3.scatter([1000 * e.x_m for e in ev], [1000 * e.y_m for e in ev], [1000 * e.z_m for e in ev],
                        color=col, s=6)
        ax3.set_xlabel("x (mm)")
        ax3.set_ylabel("y (mm)")
        ax3.set_zlabel("z (mm)")
        ax3.set_box_aspect(None, zoom=0.82)   # room for the z label beside the traces
        ax3.legend(loc="upper left", frameon=False, fontsize=6)
        axd = fig.add_subplot(grid[0, 1])
        axf = fig.add_subplot(grid[1, 1], sharex=axd)
        for r, col in zip(data["runs"], colors):
            for k, (d, f, ev) in enumerate(r["traces"]):
                t = data["t_ms"][:len(d)]
                axd.plot(t, d, color=col, lw=0.7, alpha=0.5 + 0.5 * k / max(1, len(r["traces"]) - 1))
                axf.plot(t, f, color=col, lw=0.7, alpha=0.5 + 0.5 * k / max(1, len(r["traces"]) - 1))
        axd.set_ylabel("depth behind surface (mm)")
        axf.set_ylabel("force along normal (N)")
        axf.set_xlabel("time from contact (ms)")
        fig.suptitle("Figure 4.19's samples on a table, tapped at 0.08-0.12 m/s from several directions (3-DOF sim)")
    return fig


def save(out_dir) -> dict:
    """Run the demo and write ``table3d.png/.svg/.plot.csv`` and ``table3d_events.csv`` into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    runs = run_taps()
    data = figure_data(runs)
    table = {"t_ms": data["t_ms"]}
    for r in data["runs"]:
        for k, (d, f, _) in enumerate(r["traces"]):
            pad = len(data["t_ms"]) - len(d)
            table[f"{r['object']}_tap{k + 1}_depth_mm"] = np.pad(d, (0, pad), constant_values=np.nan)
            table[f"{r['object']}_tap{k + 1}_force_normal_N"] = np.pad(f, (0, pad), constant_values=np.nan)
    paths = figstyle.save(plot(data), out_dir / "table3d.png", table, force=True)
    with open(out_dir / "table3d_events.csv", "w", newline="", encoding="utf-8") as fh:
        wr = csv.writer(fh)
        wr.writerow(["object", "direction", "incoming_velocity_m_s", "max_penetration_m", "transient", "normal_x",
                     "normal_y", "normal_z"])
        for r in runs:
            for e in r["result"].events:
                wr.writerow([e.object, " ".join(f"{c:.3f}" for c in r["direction"]), f"{e.incoming_velocity_m_s:.4f}",
                             f"{e.max_penetration_m:.6f}", e.transient, f"{e.normal_x:.3f}", f"{e.normal_y:.3f}",
                             f"{e.normal_z:.3f}"])
    return paths


def main(argv=None) -> int:
    """``python -m renderer.demo.table3d --out DIR``."""
    p = argparse.ArgumentParser(prog="python -m renderer.demo.table3d", description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="output folder")
    args = p.parse_args(argv)
    save(args.out)
    print(f"saved {args.out}/table3d.png, table3d.svg, table3d.plot.csv, table3d_events.csv")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
