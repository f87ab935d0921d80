"""``python -m study run``: run a blind realism session (thesis section 4.5.3) or a psychophysics session.

Sim rehearsal, unattended, in seconds::

    python -m study run --device sim --participant simulated --subject S01 --seed 1 --out DATA

A person with the views (subject page and token-protected operator page)::

    python -m study run --device serial:/dev/ttyACM0 --participant keyboard --subject P07 \\
        --age 24 --gender female --handedness right --experience few --out DATA

Continue a killed or aborted session exactly where it stopped::

    python -m study run ... --subject P07 --out DATA --resume

The body; the parser is :mod:`study.cli_run_parser`. Every experiment kind runs the one session path
(:mod:`study.session.run`); the protocol file's ``[experiment]`` table names the kind.
"""

from __future__ import annotations

from .ratings.kind import Ratings
from .session.kind import KindAt
from .session.run import run_session

#: the experiment kinds ``run`` knows: the rating study (the default, no ``[experiment]`` table) and the kinds an
#: ``[experiment]`` table names (study.session.kind.ExperimentKind.names). The others are named by their module
#: and imported only for a session of theirs: they need psychophysics and scipy.special, a rating session not
KINDS = (Ratings,
         KindAt(("real-virtual-2afc", "discrimination", "detection"), "study.forcedchoice.kind", "ForcedChoice"),
         KindAt(("adjustment",), "study.adjustment.kind", "Adjustment"),
         KindAt(("magnitude",), "study.magnitude.kind", "Magnitude"))


def run_command(args) -> int:
    """Run (or resume) one session; returns the exit code (:func:`study.session.run.run_session`)."""
    return run_session(args, KINDS)
