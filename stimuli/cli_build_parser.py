"""``python -m stimuli build-library``: build an HFAM current library from recorded taps and device models.

The parser (light: imported for ``--help``); the body is :mod:`stimuli.cli_build`.
"""

from __future__ import annotations

from pathlib import Path

from plumbing.cliargs import add_renamed, with_examples
from plumbing.dispatch import Body

from .hfam.settings import BuildSettings


def register(subparsers) -> None:
    """Add the ``build-library`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m stimuli`` sub-command parsers.
    """
    p = subparsers.add_parser(
        "build-library",
        help="build an HFAM transient library (section 4.4.1)",
        description=(
            "Build an HFAM current library [velocity x grip x time] from recorded real taps and one "
            "current->acceleration model per grip level, verify it through the forward models and save it "
            "(format: docs/hfam_library.md)."
        ),
    )
    p.add_argument("--recordings", required=True, type=Path,
                   help="tap recording CSV (tap, incoming_velocity_m_s, t_s, accel_m_s2) from 'python -m devices record'")
    p.add_argument("--model", required=True, action="append", type=Path, dest="models",
                   help="device model JSON (docs/models.md), one per grip level; repeat the option. A model set "
                        "from 'python -m devices identify' (its model_set.json or directory) adds all its "
                        "acceleration models")
    p.add_argument("--out", required=True, type=Path, help="library file to write (.npz)")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    p.add_argument("--device", default="sim",
                   help="device string whose force constant, peak current and servo rate the library is for "
                        "(default sim; 'none' to give --force-per-amp and --peak-current-A instead)")
    add_renamed(p, "--force-per-amp-N-A", "--force-per-amp", dest="force_per_amp", type=float, default=None, help="force constant in N/A (overrides the device's)")
    p.add_argument("--peak-current-A", type=float, default=None, help="peak current limit in A (overrides the device's)")
    p.add_argument("--scale-to-limit", action="store_true",
                   help="scale transients above the peak current down to it instead of stopping")
    d = BuildSettings()
    p.add_argument("--n-velocities", type=int, default=d.n_velocities, help="velocities to pick (default %(default)s)")
    p.add_argument("--taps", type=str, default=None, help="comma-separated tap ids to use instead of automatic selection")
    p.add_argument("--duration-s", type=float, default=d.duration_s, help="transient length (default %(default)s s)")
    p.add_argument("--smooth-hz", type=float, default=d.smooth_hz, help="zero-phase smoothing cut-off, <= 1000 (default %(default)s Hz)")
    p.add_argument("--highpass-hz", type=float, default=d.highpass_hz, help="high-pass cut-off (default %(default)s Hz)")
    p.add_argument("--added-zero-hz", type=float, default=d.added_zero_hz, help="added zeros' frequency (default %(default)s Hz)")
    p.add_argument("--added-zero-zeta", type=float, default=d.added_zero_zeta, help="added zeros' damping (default %(default)s)")
    p.add_argument("--taper-s", type=float, default=d.taper_s, help="end taper length (default %(default)s s)")
    p.add_argument("--onset-delay-s", type=float, default=d.onset_delay_s, help="accepted onset delay (default %(default)s s)")
    p.add_argument("--gain", type=float, default=d.gain, help="gain on all currents (default %(default)s)")
    p.add_argument("--max-pre-impact-ratio", type=float, default=d.max_pre_impact_ratio,
                   help="drop taps whose pre-impact peak exceeds this fraction of the impact peak (default %(default)s)")
    p.add_argument("--min-neighbour-corr", type=float, default=d.min_neighbour_corr,
                   help="drop taps correlating less than this with their velocity neighbours (default %(default)s)")
    p.add_argument("--refine", type=int, default=0, metavar="N",
                   help="refine every transient N times by playback and correction on a simulated --device "
                        "(sim only; prints the error per iteration; on hardware the same procedure needs "
                        "repeated taps by a person; default 0: off)")
    p.add_argument("--refine-wall", type=float, default=680.0,
                   help="wall stiffness the transients are refined over, N/m (default %(default)s)")
    p.add_argument("--refine-gain", type=float, default=0.3,
                   help="learning gain of each refinement correction, (0, 1] (default %(default)s)")
    p.add_argument("--refine-max-lag", type=float, default=0.001, metavar="S",
                   help="align the measured response to the target within +/- S seconds before taking the "
                        "refinement error (the device's own delay is not a shape error; default %(default)s)")
    p.add_argument("--refine-recordings", type=int, default=4, metavar="N",
                   help="after --refine, N line-searched passes towards the unsmoothed recordings (transients at "
                        "the current limit take a constrained least-squares step; 0: off; default %(default)s)")
    p.add_argument("--max-extrapolation", type=float, default=d.max_extrapolation,
                   help="cap of v_in/v_max above the velocity range at run time (default %(default)s)")
    with_examples(p, 'hfam-stimuli build-library --recordings REC.csv --model ident/ --scale-to-limit --out LIB.npz')
    p.set_defaults(func=Body('stimuli.cli_build', 'run'))

