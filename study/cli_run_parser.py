"""``python -m study run``: run a blind realism session (thesis section 4.5.3).

Sim rehearsal, unattended, in seconds::

    python -m study run --device sim --participant simulated --subject S01 --seed 1 --out DATA

A person with the views (subject page and token-protected operator page)::

    python -m study run --device serial:/dev/ttyACM0 --participant keyboard --subject P07 \
        --age 24 --gender female --handedness right --experience few --out DATA

Continue a killed or aborted session exactly where it stopped::

    python -m study run ... --subject P07 --out DATA --resume

The parser (light: imported for ``--help``); the body is :mod:`study.cli_run`.
"""

from __future__ import annotations


from plumbing.cliargs import add_renamed, with_examples
from plumbing.dispatch import Body

from plumbing.studyfiles import EXPERIENCE, GENDERS, HANDEDNESS


def register(subparsers) -> None:
    """Add the ``run`` command (the blind realism session).

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``python -m study`` sub-command parsers.
    """
    p = subparsers.add_parser("run", help="run a blind realism or psychophysics session (sim rehearsal or real subjects)",
                              description="Run a blind realism session (thesis section 4.5.3) or a psychophysics session "
                                          "(a protocol with an [experiment] table: real-vs-virtual 2AFC, stiffness "
                                          "discrimination, detection; docs/study.md): a simulated participant "
                                          "rehearses it unattended in seconds; a person gets the views (a subject page "
                                          "and a token-protected operator page). --resume continues a killed or "
                                          "aborted session exactly where it stopped.")
    p.add_argument("--device", default=None, help="device string: sim, sim:lti, sim:<file>, serial:<port>, "
                                                 "hid:<vid>:<pid> (default: sim:onedof, the one-dof testbed of the thesis's study "
                                                 "chapter, or the resumed session's)")
    p.add_argument("--participant", choices=("simulated", "keyboard"), default=None,
                   help="simulated (sim devices only: simulated hand and synthetic rater) or keyboard (a person "
                        "using the subject view; with a sim device the simulated hand still taps); default: "
                        "simulated, or the resumed session's")
    p.add_argument("--subject", required=True, help="subject id (letters, digits, _ and -)")
    p.add_argument("--out", required=True, help="data folder; the session goes to OUT/<subject>/")
    p.add_argument("--seed", type=int, default=None, help="randomization seed (default: random, stored)")
    p.add_argument("--resume", action="store_true", help="continue an unfinished session of this subject")
    p.add_argument("--catalog", default=None, help="sample catalog TOML (default: the 12 samples of Table 4.1)")
    p.add_argument("--library-dir", default=None, help="directory for relative HFAM library paths")
    p.add_argument("--samples", default=None, help="comma-separated subset of catalog sample names")
    p.add_argument("--repetitions", type=int, default=None, help="testing presentations per sample (default 3)")
    add_renamed(p, "--tap-window-s", "--tap-window", type=float, default=None, dest="tap_window_s",
                   help="tapping time from the first impact, s (default 5)")
    p.add_argument("--protocol", default=None, help="TOML/JSON file with protocol settings (docs/study.md)")
    p.add_argument("--participant-config", default=None, help="TOML/JSON simulated-participant settings")
    p.add_argument("--age", type=int, default=None)
    p.add_argument("--gender", choices=GENDERS, default=None)
    p.add_argument("--handedness", choices=HANDEDNESS, default=None)
    p.add_argument("--experience", choices=EXPERIENCE, default=None,
                   help="prior haptic experience: none (never), few (a few times), regular")
    p.add_argument("--audio", choices=("auto", "on", "off"), default="auto",
                   help="masking audio: auto = on for hardware (required: refuses to start without an output "
                        "device), off for sim; on = also in sim; off = also on hardware (bench tests without a "
                        "subject; recorded in session.json)")
    p.add_argument("--audio-device", default=None, help="PortAudio output device (name or index)")
    add_renamed(p, "--masking-level-dbfs", "--masking-level", type=float, default=None, dest="masking_level_dbfs",
                   help="white-noise RMS level in dBFS (default -20)")
    add_renamed(p, "--cue-level-db", "--cue-level", type=float, default=None, dest="cue_level_db",
                   help="spoken cues' active RMS level in dB re the noise (default 0)")
    p.add_argument("--servo-process", choices=("auto", "on", "off"), default="auto",
                   help="run device, servo loop and homing in a child process so UI and audio threads never delay "
                        "them (auto: on for hardware, off for sim)")
    p.add_argument("--realtime", action="store_true",
                   help="pace a sim device's tapping windows to wall-clock time (hardware is always paced)")
    p.add_argument("--accept-timing", action="store_true",
                   help="start a hardware session even if the servo timing check before it fails (recorded in "
                        "session.json; docs/study.md 'Servo timing')")
    p.add_argument("--lsl", action="store_true",
                   help="publish the device's state and every event (attempt, tap cue, contact, question, answer) as "
                        "Lab Streaming Layer streams (docs/study.md); without pylsl the session runs without them "
                        "and says so")
    p.add_argument("--lsl-rate-hz", type=float, default=1000.0, help="the state stream's rate, Hz (default 1000)")
    p.add_argument("--lsl-wait-s", type=float, default=0.0,
                   help="wait up to this long for a recorder (LabRecorder, an inlet) on every stream before the "
                        "first attempt (default 0: start at once)")
    p.add_argument("--serve", action="store_true", help="serve the views also for a simulated participant")
    p.add_argument("--host", default="127.0.0.1", help="bind address of the views (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=0, help="port of the views (default: any free port)")
    p.add_argument("--token", default=None, help="operator token (default: random, printed)")
    p.add_argument("--quiet", action="store_true", help="print only the summary")
    with_examples(p, 'hfam-study run --device sim --participant simulated --subject S01 --seed 1 --out DATA', 'hfam-study run --device serial:/dev/ttyACM0 --participant keyboard --subject P07 --age 24 --gender female \\', '    --handedness right --experience few --out DATA', 'hfam-study run --device serial:/dev/ttyACM0 --participant keyboard --subject P07 --out DATA --resume')
    p.set_defaults(func=Body('study.cli_run', 'run_command'))

