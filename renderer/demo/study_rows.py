"""Figure 4.17's ordering and section 4.5.4's saturations as ``fidelity.csv`` rows, from the simulated study.

The docs' gallery holds a simulated 16-subject realism study (the thesis's size: ``python -m study run`` with the
simulated participant on the one-dof sim, analysed by ``python -m analysis report``; rebuilt by ``make artefacts``,
``plumbing.artefacts``). Its report writes ``ranking.json`` (``analysis.ranking``): the yes/no of each of the
thesis's sentences on the ranking and the saturations. Running sixteen sessions takes minutes, so the demo reads
that study instead of running one, and only while the gallery's stamp says it was made by the code as it is now;
otherwise the rows are "not measured" with the reason.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from plumbing.artefacts import ROOT, check

from .fidelity import Claim

#: where the gallery keeps the simulated study's checks
RANKING_JSON = ROOT / "docs" / "gallery" / "study" / "ranking.json"
GALLERY = "gallery"

_ROWS = {
    "study_real_wood_first": ("4.5.5, Figure 4.17", "Not surprisingly, the most highly rated sample was real wood",
                              "real wood has the highest mean rating", "real_wood_first"),
    "study_hfam_first_virtual": ("4.5.5, Figure 4.17", "Wood was followed interestingly by the wood on foam and the six "
                                 "transient-overlaid virtual surfaces, with acceleration matching rated most highly",
                                 "an HFAM sample has the highest mean rating among the virtual samples",
                                 "hfam_first_virtual"),
    "study_proportional_near_foam": ("4.5.5, Figure 4.17", "The ratings given to the three proportional controllers "
                                     "were comparable to those assigned to foam, significantly lower than those given "
                                     "to the event-based samples.", "every proportional wall within 1 rating point of "
                                     "foam and below every event-based sample", "proportional_near_foam"),
    "study_saturations": ("4.5.4", "Users exceeded the system's force capability an average of six times during the "
                          "testing phase, with a standard deviation of 8.5. Saturations occurred most frequently for "
                          "the real wood and the event-based virtual samples.",
                          "saturations per subject within the thesis mean's 95 % interval (1.75-10.25), more than half "
                          "on real wood and event-based samples", "saturations"),
}


def study_claims(path: Path = RANKING_JSON) -> list[Claim]:
    """The four rows of the simulated study (``study_real_wood_first``, ``study_hfam_first_virtual``,
    ``study_proportional_near_foam``, ``study_saturations``); "not measured" (NaN, not holding, the reason) when the
    gallery's study is missing or older than the code (its stamp, :func:`plumbing.artefacts.check`)."""
    why = ""
    checks = None
    stale = check([GALLERY]).get(GALLERY)
    if stale:
        why = "the gallery's simulated study is not the current code's (" + "; ".join(stale) + "); make artefacts"
    else:
        try:
            checks = json.loads(Path(path).read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            why = f"{path}: {exc}"
    out = []
    for cid, (section, thesis, target, key) in _ROWS.items():
        if checks is None or key not in checks:
            out.append(Claim(cid, section, thesis, target, math.nan, f"not measured: {why or 'no ' + key}", False))
            continue
        c = checks[key]
        if key == "saturations":
            measured = float(checks["saturations_per_subject"][0])
        else:
            measured = 1.0 if c["met"] else 0.0
        n = checks.get("saturations_per_subject", [0, 0, 0])[2]
        out.append(Claim(cid, section, thesis, target, measured,
                         f"simulated study, {n} subjects (docs/gallery): {c['text']}", bool(c["met"])))
    return out
