"""Study settings: protocol parameters and subject information, validated at the boundary.

Protocol defaults follow thesis section 4.5.3: familiarization on the real
wood sample, each sample once in the demonstration, three times in testing,
five seconds of tapping from the first impact. A TOML or JSON file may
override any :class:`ProtocolConfig` field (``--protocol FILE``); unknown keys
are refused with the key and file named.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from plumbing.fileio import read_text_utf8
from plumbing.studyfiles import EXPERIENCE, GENDERS, HANDEDNESS
from plumbing.validation import (dataclass_from_layers, load_dataclass_file, require_int, require_number,
                                 require_positive)
from .store import check_subject_id

#: upper bounds of the protocol's numbers, so that a session's time, memory and traces stay bounded
#: (``repetitions = 1e6`` planned millions of trials; a servo log is preallocated for the longest window)
#: and the homing target stays within the handle's reach (the renderer's position limit is 0.25 m).
#: The thesis's values (section 4.5.3) are far inside them: 3 repetitions, 5 s windows, 1 cm.
MAX_REPETITIONS = 100
MAX_FAMILIARIZATION_WINDOWS = 1000
#: the most attempts of one trial (``max_attempts``): beyond it a trial is recorded as not renderable
MAX_ATTEMPTS_LIMIT = 100
PROTOCOL_LIMITS = {"tap_window_s": 60.0, "familiarization_window_s": 60.0, "first_tap_timeout_s": 600.0,
                   "homing_after_s": 60.0, "homing_before_max_s": 60.0, "home_height_m": 0.1,
                   "audio_fs_hz": 192000.0, "servo_watchdog_s": 1.0, "timing_check_s": 300.0}


@dataclass(frozen=True)
class ProtocolConfig:
    """Protocol parameters (units in names).

    Attributes
    ----------
    repetitions : int
        Testing presentations per sample (section 4.5.3: 3).
    tap_window_s : float
        Tapping time from the first impact (5 s).
    first_tap_timeout_s : float
        Time allowed for the first impact after the cue; none -> the attempt is invalid ("no_tap").
    home_height_m : float
        Homing target above the sample surface.
    homing_after_s : float
        Homing time after the window in which a tap counts as overpowering
        (keyboard sessions keep homing until the rating arrives, and count those taps too).
    homing_before_max_s : float
        Longest pre-trial homing while waiting for the stylus to settle.
    homing_kp_N_m, homing_kd_N_s_m : float
        The homing PD's gains (``renderer.homing.HomingConfig``: 300 N/m, 3 N s/m). Lower them on a device
        whose homing stops as ``unstable`` (a light handle, or a host whose servo is late under load;
        docs/study.md, "Homing controller").
    familiarization_sample : str
        Catalog name of the real sample for familiarization ("" skips the phase).
    familiarization_window_s : float
        Length of one recorded familiarization window.
    familiarization_max_windows : int
        Safety cap on familiarization windows.
    max_attempts : int
        Attempts of one trial (1-100, default 10): a trial whose every attempt was invalid (saturated,
        overpowered, no tap, rejected) that many times is recorded as not renderable (``not_renderable`` in
        schedule.jsonl, no row) and the session goes on; a stimulus the device cannot render (a level far above
        the amplifier's limit) so never loops for ever (docs/study.md, "Attempts and trials that cannot be
        rendered").
    masking_level_dbfs : float
        White-noise RMS level re digital full scale.
    cue_level_db : float
        Active RMS level of the spoken cues (or fallback chimes) relative to the
        noise RMS, dB (0: as loud as the noise; a cue that would clip is refused).
    audio_fs_hz : float
    servo_watchdog_s : float
        The renderer's watchdog bound (``RendererConfig.watchdog_overrun_s``): a servo period
        longer than nominal by more than this zeroes the output and stops the session.
    timing_check_s : float
        Length of the servo timing check before a hardware session (``renderer timing-check`` through the
        device, motor off; docs/study.md "Servo timing").
    timing_p99_us, timing_p999_us, timing_max_period_ms, timing_link_rtt_p99_ms, timing_link_gap_ms : float
        The check's thresholds (``renderer.timing_verdict.TimingThresholds``): period error p99 and p99.9
        (us), longest period (ms), the link's p99 round trip and longest gap (ms). A session does not start
        on a failing check unless ``--accept-timing`` is given (recorded).
    """

    repetitions: int = 3
    tap_window_s: float = 5.0
    first_tap_timeout_s: float = 10.0
    home_height_m: float = 0.01
    homing_after_s: float = 1.0
    homing_before_max_s: float = 0.5
    homing_kp_N_m: float = 300.0
    homing_kd_N_s_m: float = 3.0
    familiarization_sample: str = "wood"
    familiarization_window_s: float = 5.0
    familiarization_max_windows: int = 60
    max_attempts: int = 10
    masking_level_dbfs: float = -20.0
    cue_level_db: float = 0.0
    audio_fs_hz: float = 44100.0
    servo_watchdog_s: float = 0.02
    timing_check_s: float = 3.0
    timing_p99_us: float = 20.0
    timing_p999_us: float = 50.0
    timing_max_period_ms: float = 1.0
    timing_link_rtt_p99_ms: float = 2.0
    timing_link_gap_ms: float = 10.0

    def __post_init__(self) -> None:
        require_int("repetitions", self.repetitions, minimum=1, maximum=MAX_REPETITIONS)
        require_positive(self, "tap_window_s", "first_tap_timeout_s", "home_height_m", "homing_after_s",
                         "homing_before_max_s", "homing_kp_N_m", "familiarization_window_s", "audio_fs_hz", "servo_watchdog_s",
                         "timing_check_s", "timing_p99_us", "timing_p999_us", "timing_max_period_ms",
                         "timing_link_rtt_p99_ms", "timing_link_gap_ms")
        require_number("homing_kd_N_s_m", self.homing_kd_N_s_m, minimum=0.0)
        for name, limit in PROTOCOL_LIMITS.items():  # time, memory and reach bounded
            require_number(name, getattr(self, name), maximum=limit)
        require_int("familiarization_max_windows", self.familiarization_max_windows, minimum=1,
                    maximum=MAX_FAMILIARIZATION_WINDOWS)
        require_int("max_attempts", self.max_attempts, minimum=1, maximum=MAX_ATTEMPTS_LIMIT)
        if not (isinstance(self.masking_level_dbfs, (int, float)) and not isinstance(self.masking_level_dbfs, bool)
                and math.isfinite(self.masking_level_dbfs) and -100.0 <= self.masking_level_dbfs <= -3.0):
            raise ValueError(f"masking_level_dbfs must be between -100 and -3 dBFS, got {self.masking_level_dbfs!r}")
        if not (isinstance(self.cue_level_db, (int, float)) and math.isfinite(self.cue_level_db)
                and -30.0 <= self.cue_level_db <= 30.0):
            raise ValueError(f"cue_level_db must be between -30 and +30 dB re the noise, got {self.cue_level_db!r}")

    def to_dict(self) -> dict:
        """The protocol as plain data (recorded in session.json)."""
        return asdict(self)


def load_protocol(path, where: str = "command line", **overrides) -> ProtocolConfig:
    """Load a :class:`ProtocolConfig` from TOML/JSON; ``overrides`` (not None) win; ``where`` names their
    source in messages when there is no file."""
    return load_dataclass_file(path, ProtocolConfig, "protocol", overrides, where)


def read_protocol_file(path) -> tuple[dict, object]:
    """The settings of ``--protocol FILE`` (TOML or JSON) and its ``[experiment]`` table, apart.

    Returns
    -------
    (dict, object)
        The protocol's keys (:class:`ProtocolConfig`'s; checked by :func:`protocol_from`) and the
        ``[experiment]`` table as written (None when the file has none, or without a file): an experiment
        kind's settings (:meth:`study.session.kind.ExperimentKind.configure`).

    Raises
    ------
    FileNotFoundError, ValueError
        Naming the file: missing, not a regular file, not UTF-8, not TOML/JSON, not a table.
    """
    if path is None:
        return {}, None
    p = Path(path)
    if p.exists() and not p.is_file():  # e.g. --protocol /dev/null: it is there, but holds no settings
        raise ValueError(f"protocol file {p} is not a regular file ({'a folder' if p.is_dir() else 'a device or pipe'}"
                         "); give a TOML or JSON file")
    if not p.is_file():
        raise FileNotFoundError(f"protocol file {p} not found")
    text = read_text_utf8(p, "protocol file")
    try:
        data = tomllib.loads(text) if p.suffix == ".toml" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{p}: cannot parse ({exc})") from None
    except RecursionError:   # e.g. a JSON array nested 10^5 deep: one line, not a traceback
        raise ValueError(f"{p}: cannot parse (nested too deeply: tables and lists go at most a few hundred "
                         "levels deep)") from None
    if not isinstance(data, dict):
        raise ValueError(f"{p}: a protocol file must hold a table/object of settings, got {type(data).__name__}")
    table = data.pop("experiment", None)
    return data, table


def protocol_from(data: dict, path, where: str = "command line", **overrides) -> ProtocolConfig:
    """:class:`ProtocolConfig` from a protocol file's keys (:func:`read_protocol_file`), ``overrides`` (not
    None) winning; errors name the file (``path``) or ``where``."""
    return dataclass_from_layers(ProtocolConfig, data, overrides, "protocol", str(path) if path is not None else where,
                                 where)


@dataclass(frozen=True)
class SubjectInfo:
    """Collected before the session (section 4.5.3)."""

    subject: str
    age: int | None
    gender: str
    handedness: str
    experience: str

    def __post_init__(self) -> None:
        check_subject_id(self.subject)
        if self.age is not None and not (isinstance(self.age, int) and 5 <= self.age <= 120):
            raise ValueError(f"age must be an integer 5-120, got {self.age!r}")
        if self.gender not in GENDERS:
            raise ValueError(f"gender must be one of {list(GENDERS)}, got {self.gender!r}")
        if self.handedness not in HANDEDNESS:
            raise ValueError(f"handedness must be one of {list(HANDEDNESS)}, got {self.handedness!r}")
        if self.experience not in EXPERIENCE:
            raise ValueError(f"experience must be one of {list(EXPERIENCE)} (never / a few times / regularly), "
                             f"got {self.experience!r}")


def experiment_config(cls, data, where: str):
    """An experiment kind's ``[experiment]`` settings: the frozen dataclass ``cls`` built from the table ``data``.

    Unknown keys and bad values are one error naming ``where`` and the key; a relative ``design`` path (a
    counterbalanced design file) is taken from the protocol file's folder, as the file that names it.
    """
    if not isinstance(data, dict):
        raise ValueError(f"{where}: [experiment] must be a table of settings, got {type(data).__name__}")
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"{where}: unknown [experiment] key(s) {unknown}; valid keys: {sorted(known)}")
    data = dict(data)
    design = data.get("design")
    if isinstance(design, str) and design and not Path(design).is_absolute() and Path(where).is_file():
        data["design"] = str((Path(where).parent / design).resolve())
    try:
        return cls(**data)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: [experiment] {exc}") from None
