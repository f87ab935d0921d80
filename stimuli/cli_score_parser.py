"""``python -m stimuli score-hfam``: how well the HFAM libraries reproduce the real tap on the sim.

The parser (light: imported for ``--help``); the body is :mod:`stimuli.cli_score`.
"""

from __future__ import annotations

from pathlib import Path

from plumbing.cliargs import float_list, with_examples
from plumbing.dispatch import Body

from .hfam.settings import (DEFAULT_TRANSIENT_LIMIT_A, GRIPS_N, ISSUE_UNSEEN_SPEEDS_M_S, LINKAGES,
                            OPEN_LOOP_SPEEDS_M_S, UNSEEN_GRIPS_N)


def _csv(values) -> str:
    return ",".join(f"{v:g}" for v in values)


def register(subparsers) -> None:
    """Add the ``score-hfam`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m stimuli`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "score-hfam",
        help="score the open-loop and refined HFAM libraries against the real tap on the sim",
        description=(
            "Score the HFAM pipeline's libraries on the sim device (docs/hfam_library.md, 'Scoring'): the open-loop "
            "library (record, smooth, invert, high-pass, taper; no playback refinement) over --speeds-m-s x "
            "--grips-N; the refined library only at conditions it was never refined on (speeds between its "
            "velocities, grips between its levels, and a second simulated person); cells whose current reached "
            "the amplifier limit flagged saturated and left out (section 4.4.3); and the same grid with a raised "
            "transient-only limit under the motor's thermal model. Prints the tables and writes scores.csv, "
            "claims.json and scores.txt into --out."
        ),
    )
    p.add_argument("--out", required=True, type=Path, help="folder to write (scores.csv, claims.json, scores.txt)")
    p.add_argument("--force", action="store_true", help="replace earlier scores in --out")
    p.add_argument("--pipeline", type=Path, default=None,
                   help="an HFAM pipeline folder to score (with library.npz, identify/, recordings.csv: a "
                        "'python -m renderer demo' cache entry or an earlier --out/pipeline); default: run the "
                        "pipeline on the sim into --out/pipeline (~30 s)")
    p.add_argument("--speeds-m-s", type=float_list, default=OPEN_LOOP_SPEEDS_M_S,
                   help=f"open-loop grid speeds, m/s, 0.02-2 (default {_csv(OPEN_LOOP_SPEEDS_M_S)})")
    p.add_argument("--grips-N", type=float_list, default=GRIPS_N,
                   help=f"open-loop and saturation grid grips, N, within the sim's 0-10 N grip range "
                        f"(default {_csv(GRIPS_N)})")
    p.add_argument("--unseen-speeds-m-s", type=float_list, default=None,
                   help="speeds the refined library is scored at, m/s, 0.02-2 (refused if near its own velocities; "
                        "default: "
                        f"the middle of its two velocities around each of {_csv(ISSUE_UNSEEN_SPEEDS_M_S)})")
    p.add_argument("--unseen-grips-N", type=float_list, default=UNSEEN_GRIPS_N,
                   help=f"grips the refined library is scored at, N, within the sim's 0-10 N grip range "
                        f"(default {_csv(UNSEEN_GRIPS_N)})")
    p.add_argument("--transient-limit-A", type=float, default=DEFAULT_TRANSIENT_LIMIT_A,
                   help="the raised transient-only current limit of the thermal option, A (default %(default)s; "
                        "between the device's peak current and what a 100 ms transient may hold under its "
                        "thermal model)")
    p.add_argument("--linkage", choices=LINKAGES, default=None,
                   help="the sim device the pipeline and every tap run on: 'linear' (sim:onedof, the section 4.4.3 "
                        "one-dof testbed: Table 3.1 with its linkage a linear spring at the small-signal stiffness, "
                        "no amplitude-dependent resonance) or 'hysteretic' (sim:joystick, the Table 3.1 joystick, "
                        "section 3.5.3's linkage). Default: linear, or with --pipeline the device that folder was "
                        "run on (refused if it differs)")
    with_examples(p, "python -m stimuli score-hfam --out out/hfam_scores",
                  "python -m stimuli score-hfam --out out/hfam_joystick --linkage hysteretic",
                  "python -m stimuli score-hfam --out out/hfam_scores --force --speeds-m-s 0.05,0.1,0.15 --grips-N 1,2,3",
                  "python -m stimuli score-hfam --out out/s2 --pipeline out/hfam_scores/pipeline --transient-limit-A 6")
    p.set_defaults(func=Body("stimuli.cli_score", "run"))
