"""``python -m analysis <command>``: analyse a study folder, or write a synthetic one."""

from __future__ import annotations

from plumbing.dispatch import Command, run_as_script
from plumbing.dispatch import main as dispatch

#: the commands, listed without importing them; each names its parser module (``register(subparsers)``, light),
#: whose parser names the body that runs (plumbing.dispatch.Body).
#: One BLAS thread (every command's default, plumbing.dispatch): the analysis' matrix products are small (vectors of attempts, 12 x 12 covariances); a second
#: BLAS thread waiting for a busy core cost up to a scheduler slice (~8 ms) per call, 0.6 s per report on a loaded
#: two-core machine
COMMANDS = (
    Command("report", "analysis.cli_report_parser", "analyse a study folder: tables, figures, report.md/.html"),
    Command("plan", "analysis.cli_plan_parser",
            "number of subjects for the next study (difference and equivalence tests)"),
    Command("psychometric", "analysis.cli_psychometric_parser",
            "psychometric fits (threshold, slope, lapse, PSE, JND) of forced-choice data"),
    Command("adjustment", "analysis.cli_adjustment_parser",
            "method of adjustment: PSE, spread (JND estimate) and constant error"),
    Command("magnitude", "analysis.cli_magnitude_parser", "magnitude estimation: Stevens' power law per subject and pooled"),
    Command("export-bids", "analysis.cli_export_bids_parser",
            "write the study as a BIDS dataset (beh events, motion traces, participants)"),
    Command("synthetic", "analysis.cli_synthetic_parser", "write a synthetic study folder in the study's data format"),
)


def main(argv=None) -> int:
    """Run ``python -m analysis`` with ``argv`` (default: the command line); returns the exit code."""
    return dispatch("python -m analysis", __doc__.splitlines()[0], COMMANDS, argv)


def run() -> None:
    """Entry point of ``python -m analysis`` and of the ``hfam-analysis`` console script: exit with main()'s code."""
    run_as_script(main)


if __name__ == "__main__":
    run()
