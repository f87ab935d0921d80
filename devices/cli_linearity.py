"""``python -m devices linearity``: is the device linear and time-invariant? (thesis sec. 3.4.3)"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

from plumbing.fileio import atomic_write_text
from plumbing.outdir import output_folder

from .identify.linearity import default_conditions, format_linearity, linearity_figure, linearity_report
from .registry import check_device_spec, make_device


#: what ``linearity`` writes into ``--out`` (the folder's other files are kept)
PRODUCTS = ("linearity.txt", "linearity.json", "linearity.png", "linearity.svg", "linearity.plot.csv")


def run_linearity(args) -> int:
    """Run ``linearity`` (see the parser's description); returns the exit code."""

    check_device_spec(args.device)
    if args.trials < 2:
        raise ValueError("--trials must be >= 2 (coherence across trials)")
    # --out is checked and locked before measuring (a file, a study's data, an earlier report without
    # --force: refused), the report written beside it and swapped in whole (plumbing.outdir): an interrupted
    # run leaves an earlier report as it was; the folder's other files are the user's and are kept
    folder = (output_folder(args.out, args.force, products=PRODUCTS, results="a linearity report",
                            command="devices linearity").open() if args.out else None)
    with folder if folder is not None else contextlib.nullcontext():
        dev = make_device(args.device, seed=args.seed) if args.device.startswith("sim") else make_device(args.device)
        with dev:
            conds = default_conditions(dev.info, args.amplitudes, args.grips, args.positions)
            report = linearity_report(dev, conds, tuple(args.band), args.trials,
                                      log=lambda m: print(m, flush=True))
        text = format_linearity(report)
        print(text, end="")
        if folder is not None:
            atomic_write_text(folder.path / "linearity.txt", text)
            data = {k: v for k, v in report.items() if k != "curves"}
            atomic_write_text(folder.path / "linearity.json", json.dumps(data, indent=2, default=float) + "\n")
            linearity_figure(report, folder.path / "linearity.png")
    if folder is not None:
        out = Path(args.out)
        print(f"wrote {out / 'linearity.png'}, linearity.svg, linearity.plot.csv, linearity.txt, linearity.json")
    return 0
