"""``python -m analysis export-bids DATA --out DIR``: the study as a BIDS dataset (``beh`` events with sidecars,
device traces as ``motion``, ``participants.tsv``, ``dataset_description.json``).

The parser (light: imported for ``--help``); the body is :mod:`analysis.cli_export_bids`.
"""

from __future__ import annotations

from plumbing.cliargs import with_examples
from plumbing.dispatch import Body


def register(subparsers) -> None:
    """Add the ``export-bids`` command."""
    p = subparsers.add_parser(
        "export-bids", help="write the study as a BIDS dataset (beh events, motion traces, participants)",
        description="Write the study folder DATA (any experiment kinds) as a BIDS dataset into --out: "
                    "dataset_description.json, README, participants.tsv/.json, per subject beh/ events (one row per "
                    "trial with onset, duration, trial_type and every recorded column; task-<task>_events.json "
                    "describes each column and unit) and the device's traces as motion/ runs (position and "
                    "acceleration, forces, current and grip as MISC channels) at --motion-rate-hz. The folder is "
                    "written beside and swapped in whole.")
    p.add_argument("data", metavar="DATA", help="study data folder (or one subject's folder)")
    p.add_argument("--out", required=True, metavar="DIR", help="the BIDS dataset's folder (new, or --force)")
    p.add_argument("--force", action="store_true", help="replace an earlier export in --out")
    p.add_argument("--motion-rate-hz", type=float, default=1000.0,
                   help="sampling rate of the motion files (the servo rate divided by a whole number; default 1000)")
    p.add_argument("--no-motion", action="store_true", help="behaviour only, no device traces")
    p.add_argument("--name", default=None, help="the dataset's name (default: from DATA's folder)")
    with_examples(p, "hfam-analysis export-bids DATA --out BIDS", "hfam-analysis export-bids DATA --out BIDS --no-motion")
    p.set_defaults(func=Body("analysis.cli_export_bids", "run"))
