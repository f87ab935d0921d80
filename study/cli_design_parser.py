"""``python -m study design``: condition orders for every participant (Latin square or Williams design).

The parser (light: imported for ``--help``); the body is :mod:`study.cli_design`.
"""

from __future__ import annotations

from plumbing.cliargs import with_examples
from plumbing.dispatch import Body

DESIGNS = ("williams", "latin")


def register(subparsers) -> None:
    """Add the ``design`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m study`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "design", help="counterbalanced condition orders for the participant list (Williams or Latin square)",
        description="Assign every participant on the list an order of the conditions before the sessions: a "
                    "Williams design (default: each condition once at each position and each condition "
                    "immediately preceded by every other equally often; 2n orders for an odd number n of "
                    "conditions) or a Latin square (position only). Writes design.csv (what a protocol's "
                    "[experiment] design = \"design.csv\" reads), design.md (the table to print) and design.json "
                    "(the design, its balance counts, the seed) into --out.")
    p.add_argument("--participants", required=True, metavar="FILE",
                   help="participant ids, one per line, or a CSV/TSV with a column participant (or participant_id)")
    p.add_argument("--conditions", required=True, metavar="A,B,C",
                   help="the conditions' names, comma-separated (as the protocol names them)")
    p.add_argument("--design", choices=DESIGNS, default="williams", help="williams (default) or latin")
    p.add_argument("--seed", type=int, default=0, help="seed of the random mapping of conditions and sequences")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (new, or --force)")
    p.add_argument("--force", action="store_true", help="replace an earlier design in --out")
    with_examples(p, "hfam-study design --participants participants.txt --conditions soft,firm,hard --out DESIGN",
                  "hfam-study design --participants participants.tsv --conditions A,B,C,D --design latin --seed 3 "
                  "--out DESIGN")
    p.set_defaults(func=Body("study.cli_design", "run"))
