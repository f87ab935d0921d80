"""``python -m stimuli score-hfam``: the body (see :mod:`stimuli.cli_score_parser`)."""

from __future__ import annotations

import csv
import dataclasses
import json

from devices.limits import check_grips, check_tap_speeds
from plumbing.outdir import output_folder
from plumbing.validation import require_number

from .hfam import scoring
from .hfam.pipeline import Progress, build_pipeline
from .hfam.settings import PipelineSettings
from .library import HfamLibrary

#: what the command writes into --out (other files there are the user's)
PRODUCTS = ("scores.csv", "claims.json", "scores.txt", "pipeline")


def _check(args) -> None:
    """Refuse bad grids before any work (ValueError names the option and the value).

    Speeds: tap speeds of a hand (:func:`devices.limits.check_tap_speeds`: refused above 2 m/s, warned above the
    rated 0.5 m/s) and at least :data:`stimuli.hfam.scoring.MIN_SPEED_M_S` (slower, the sim's tap does not reach
    the sample). Grips: within the sim's grip sensor range (:func:`devices.limits.check_grips`).
    """
    info = scoring.SimDevice().info   # both linkages have the same grip sensor
    for flag, key in (("--speeds-m-s", "speeds_m_s"), ("--grips-N", "grips_N"), ("--unseen-grips-N", "unseen_grips_N"),
                      ("--unseen-speeds-m-s", "unseen_speeds_m_s")):
        vals = getattr(args, key)
        if vals is None:
            continue
        if not vals:
            raise ValueError(f"{flag}: give at least one number")
        for v in vals:
            require_number(flag, v, minimum=0.0, strict=True)
        if key.endswith("grips_N"):
            check_grips(info, vals, flag)
            continue
        check_tap_speeds(vals, flag)
        slow = [v for v in vals if v < scoring.MIN_SPEED_M_S]
        if slow:
            raise ValueError(f"{flag} {', '.join(f'{v:g}' for v in slow)} m/s: slower than the slowest tap the "
                             f"scoring plays, {scoring.MIN_SPEED_M_S:g} m/s (below it the sim's tap stops before "
                             "it reaches the sample)")
    require_number("--transient-limit-A", args.transient_limit_A, minimum=0.0, strict=True)
    scoring.raised_limit_device_factory(args.transient_limit_A)     # within the thermal model, or refused
    if args.pipeline is not None and args.pipeline.resolve().is_relative_to(args.out.resolve()):
        raise ValueError(f"--pipeline {args.pipeline} is inside --out {args.out}, which this run replaces; "
                         "copy it elsewhere or choose another --out")


def _linkage(args) -> str:
    """The device variant to score on: ``--linkage`` (default hysteretic), or the ``--pipeline`` folder's own
    (ValueError if ``--linkage`` names another: its library was built on that folder's device)."""
    if args.pipeline is None:
        return args.linkage or "linear"
    found = scoring.pipeline_linkage(args.pipeline)
    if args.linkage is not None and args.linkage != found:
        raise ValueError(f"--linkage {args.linkage}: the pipeline folder {args.pipeline} was run on the {found} "
                         f"device; score it without --linkage, or run a new pipeline (no --pipeline)")
    return found


def run(args) -> int:
    """Run the pipeline (or read ``--pipeline``), score it, print and write the tables; returns the exit code."""
    _check(args)
    linkage = _linkage(args)
    if args.pipeline is not None:
        # the folder's refined library is at hand: unseen speeds or grips it was refined on are refused before the
        # open-loop libraries are rebuilt (score_pipeline checks them as it scores, for a pipeline run here)
        scoring.generalisation_conditions(HfamLibrary.load(args.pipeline / "library.npz"),
                                          args.unseen_speeds_m_s or (), args.unseen_grips_N)
    folder = output_folder(args.out, args.force, products=PRODUCTS, results="earlier scores").open()
    with folder:
        pipe = args.pipeline
        settings = PipelineSettings()
        if pipe is None:
            pipe = folder.path / "pipeline"
            pipe.mkdir()
            settings = dataclasses.replace(settings, device=scoring.pipeline_device(pipe, linkage))
            build_pipeline(pipe, settings, Progress(3))
        libs = scoring.pipeline_libraries(pipe, settings, args.transient_limit_A)
        scores = scoring.score_pipeline(*libs[:3], libs[3], speeds_m_s=args.speeds_m_s, grips_N=args.grips_N,
                                        unseen_speeds_m_s=args.unseen_speeds_m_s, unseen_grips_N=args.unseen_grips_N,
                                        transient_limit_A=args.transient_limit_A,
                                        settings=scoring.ScoreSettings(linkage=linkage))
        text = scoring.format_scores(scores)
        rows = scoring.score_rows(scores)
        with open(folder.path / "scores.csv", "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
        (folder.path / "claims.json").write_text(json.dumps(scoring.hfam_claims(scores), indent=2) + "\n")
        (folder.path / "scores.txt").write_text(text + "\n")
    print(text)
    print(f"\nwrote {args.out}/scores.csv, claims.json, scores.txt" + ("" if args.pipeline else ", pipeline/"))
    return 0
