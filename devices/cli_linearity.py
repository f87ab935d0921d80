"""``python -m devices linearity``: is the device linear and time-invariant? (thesis sec. 3.4.3)"""

from __future__ import annotations

import json
from pathlib import Path

from plumbing.fileio import atomic_write_text, check_output_dir

from .identify.linearity import default_conditions, format_linearity, linearity_figure, linearity_report
from .registry import check_device_spec, make_device


def run_linearity(args) -> int:
    """Run ``linearity`` (see the parser's description); returns the exit code."""

    check_device_spec(args.device)
    if args.trials < 2:
        raise ValueError("--trials must be >= 2 (coherence across trials)")
    out = Path(args.out) if args.out else None
    if out is not None:
        check_output_dir(out)   # a file, or a path below one: refused before measuring
    if out is not None and (out / "linearity.json").exists() and not args.force:
        raise ValueError(f"--out {out} already holds a linearity report; choose another folder or pass --force")
    dev = make_device(args.device, seed=args.seed) if args.device.startswith("sim") else make_device(args.device)
    with dev:
        conds = default_conditions(dev.info, args.amplitudes, args.grips, args.positions)
        report = linearity_report(dev, conds, tuple(args.band), args.trials,
                                  log=lambda m: print(m, flush=True))
    text = format_linearity(report)
    print(text, end="")
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(out / "linearity.txt", text)
        data = {k: v for k, v in report.items() if k != "curves"}
        atomic_write_text(out / "linearity.json", json.dumps(data, indent=2, default=float) + "\n")
        print(f"wrote {linearity_figure(report, out / 'linearity.png')}, linearity.txt, linearity.json")
    return 0
