"""A study folder as a BIDS dataset (Brain Imaging Data Structure 1.10: ``beh`` and ``motion`` data), for sharing
the data in the format its field expects (``python -m analysis export-bids``).

Written:

* ``dataset_description.json`` (name, BIDS version, ``GeneratedBy``: this program and its version), ``README``;
* ``participants.tsv`` and ``participants.json``: ``participant_id`` (``sub-`` and the subject id without its
  ``_`` and ``-``, BIDS labels being alphanumeric), age, gender, handedness, prior haptic experience;
* per subject ``beh/sub-<label>_task-<task>_events.tsv``: one row per trials.csv row, with ``onset`` (s from the
  session's start), ``duration`` (s) and ``trial_type`` (the sample or condition) first, then every column of the
  trials.csv as recorded; the task is the experiment's kind (``realism`` for the rating study). One sidecar per
  task at the dataset's root, ``task-<task>_events.json``, describes every column (description, unit, levels;
  inherited by every subject's file);
* the device's traces as ``motion`` (``motion/sub-<label>_task-<task>_tracksys-haptic_run-<k>_motion.tsv``, one
  run per trace file in trials order, with ``_channels.tsv`` and ``_motion.json``): the handle's time,
  position (``POS``), acceleration (``ACCEL``), and as ``MISC`` channels the forces, current and grip, low-pass
  filtered and decimated to ``motion_rate_hz`` (``scipy.signal.resample_poly``, anti-aliased); the subject's
  ``sub-<label>_scans.tsv`` maps each run to its trial, attempt and trace file. BIDS motion data are positions and their derivatives of tracked
  points; the forces and the motor current are not motion channels, so they are MISC, as the specification
  allows.

The dataset is checked in the tests with the BIDS schema validator (``bids-validator-deno``).
"""

from __future__ import annotations

import datetime as dt
import json
import math
import re
from pathlib import Path

import numpy as np
from scipy.signal import resample_poly

from plumbing import provenance
from plumbing.fileio import atomic_write_text
from plumbing.npzfile import load_npz
from plumbing.studyfiles import (ADJUSTMENT, FORCED_CHOICE, MAGNITUDE, RATING, SESSION_JSON, TRACES_DIR, TRIALS_CSV,
                                 parse_trials, read_session_json, trace_name)

BIDS_VERSION = "1.10.0"
#: each experiment kind: its trials.csv format, its BIDS task label, its trial_type column
TASKS = {None: (RATING, "realism", "sample"), "real-virtual-2afc": (FORCED_CHOICE, "realvirtual", "condition"),
         "discrimination": (FORCED_CHOICE, "discrimination", "condition"),
         "detection": (FORCED_CHOICE, "detection", "condition"), "adjustment": (ADJUSTMENT, "adjustment", "condition"),
         "magnitude": (MAGNITUDE, "magnitude", "condition")}
#: the columns holding ';'-joined lists of numbers (text in BIDS)
LIST_COLUMNS = ("incoming_velocities_m_s", "penetration_depths_m", "values")
HANDEDNESS = {"right": "right", "left": "left", "ambidextrous": "ambidextrous", "unspecified": "n/a"}
#: the traces' channels in motion files: (name, trace key, BIDS type, component, unit, description)
MOTION_CHANNELS = (
    ("latency", "t_s", "LATENCY", "n/a", "s", "device time of the sample"),
    ("handle_position", "position_m", "POS", "z", "m", "handle position, positive up, zero at the surface"),
    ("handle_acceleration", "accel_m_s2", "ACCEL", "z", "m/s^2", "handle acceleration (accelerometer)"),
    ("force_wall", "force_prop_N", "MISC", "n/a", "N", "commanded proportional (virtual wall) force"),
    ("force_transient", "force_transient_N", "MISC", "n/a", "N", "commanded transient force"),
    ("motor_current", "current_A", "MISC", "n/a", "A", "commanded motor current"),
    ("grip_force", "grip_N", "MISC", "n/a", "N", "grip force on the handle"),
)

#: descriptions and units of the trials.csv columns, for the events sidecars (a column without one is described
#: by its name)
COLUMN_INFO = {
    "subject": ("subject id as recorded", None), "phase": ("phase of the rating study", None),
    "trial": ("trial number (within the phase)", None), "attempt": ("attempt of the trial (1, 2, ... as run)", None),
    "sample": ("catalog sample presented", None), "kind": ("real sample or virtual rendering", None),
    "rating": ("realism rating 1 (not at all) to 7 (exactly like the real wood)", None),
    "rejected": ("the subject rejected the attempt", None), "saturated": ("the amplifier limit was hit", None),
    "overpowered": ("the subject tapped while the stylus was homed", None), "valid": ("the attempt counts", None),
    "n_taps": ("taps detected in the window", None),
    "incoming_velocity_mean_m_s": ("mean incoming velocity of the taps", "m/s"),
    "penetration_mean_m": ("mean penetration of the taps", "m"),
    "incoming_velocities_m_s": ("incoming velocity of each tap, ';'-separated", "m/s"),
    "penetration_depths_m": ("penetration of each tap, ';'-separated", "m"),
    "started_at": ("UTC time of the tap cue (ISO 8601)", None),
    "duration_s": ("device time from the tap cue to the end of the attempt", "s"),
    "ends_familiarization": ("familiarization ended after this window", None),
    "condition": ("condition (rendering, varied sample, reference, or block's sample)", None),
    "staircase": ("adaptive staircase's label (empty for constant stimuli)", None),
    "intensity": ("stimulus intensity as fitted (physical or log10 of it)", None),
    "intensity_physical": ("stimulus intensity in physical units (experiment.intensity_unit)", None),
    "correct": ("1 if the target interval was chosen", None), "is_catch": ("1 for a catch trial", None),
    "response": ("the subject's key", None), "target_interval": ("interval holding the target (1 or 2)", None),
    "block": ("position of the condition's block in the session (1-based)", None),
    "sequence": ("counterbalancing design's sequence (n/a without a design)", None),
    "reference_sample": ("reference presented", None), "reference_value": ("reference's value of vary", None),
    "comparison_sample": ("comparison's catalog sample", None), "vary": ("the parameter varied", None),
    "start_value": ("comparison's value at the trial's start", None),
    "start_side": ("the start lay above or below the reference", None),
    "final_value": ("comparison's value when the subject ended the trial (the match)", None),
    "matched": ("1 if the subject reported a match", None), "n_steps": ("adjustments made", None),
    "n_comparisons": ("comparison presentations", None), "n_references": ("reference presentations", None),
    "values": ("comparison's values presented, ';'-separated", None),
    "sim_percept_reference": ("simulated participant's reference percept (n/a for a person)", None),
    "level": ("stimulus's value of vary", None), "modulus": ("the standard's value of vary (n/a: free modulus)", None),
    "modulus_number": ("number given to the standard", None), "modulus_shown": ("1 if the standard came first", None),
    "number": ("the subject's magnitude estimate", None), "sim_percept": ("simulated participant's percept", None),
}
for _k in ("1", "2"):
    COLUMN_INFO.update({f"sample_{_k}": (f"sample presented in interval {_k}", None),
                        f"n_taps_{_k}": (f"taps in interval {_k}", None),
                        f"incoming_velocity_mean_{_k}_m_s": (f"mean incoming velocity, interval {_k}", "m/s"),
                        f"penetration_mean_{_k}_m": (f"mean penetration, interval {_k}", "m"),
                        f"sim_percept_{_k}": (f"simulated participant's percept, interval {_k}", None)})


def bids_label(subject: str) -> str:
    """A BIDS label of a subject id: its letters and digits (``S_01`` -> ``S01``)."""
    return re.sub(r"[^0-9A-Za-z]", "", subject)


def _cell(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, list):
        return ";".join(repr(float(x)) for x in v) if v else "n/a"
    if isinstance(v, float):
        return repr(v)
    text = str(v).replace("\t", " ").replace("\n", " ")
    return text if text != "" else "n/a"


def _tsv(header, rows) -> str:
    return "\t".join(header) + "\n" + "".join("\t".join(_cell(v) for v in r) + "\n" for r in rows)


def _time(text: str) -> dt.datetime:
    return dt.datetime.fromisoformat(text.replace("Z", "+00:00"))


def read_subject(folder: Path) -> dict:
    """One subject folder: its session.json, its rows (typed by the kind's format) and its task."""
    session = read_session_json(folder / SESSION_JSON)
    exp = session.get("experiment")
    kind = exp.get("kind") if isinstance(exp, dict) else None
    if kind not in TASKS:
        raise ValueError(f"{folder / SESSION_JSON}: experiment kind {kind!r} cannot be exported")
    fmt, task, trial_type = TASKS[kind]
    path = folder / TRIALS_CSV
    rows, header = parse_trials(fmt, path.read_bytes(), path, subject=session.get("subject"))
    return {"folder": folder, "session": session, "rows": rows, "header": header, "task": task,
            "trial_type": trial_type, "kind": kind}


def events_table(subj: dict) -> tuple[list, list]:
    """``(header, rows)`` of a subject's events.tsv: onset, duration, trial_type, then trials.csv's columns."""
    start = _time(subj["session"]["started_at"])
    header = ["onset", "duration", "trial_type", *subj["header"]]
    rows = []
    for r in subj["rows"]:
        onset = (_time(r["started_at"]) - start).total_seconds() if r.get("started_at") else math.nan
        rows.append([max(onset, 0.0), r.get("duration_s"), r[subj["trial_type"]], *(r[c] for c in subj["header"])])
    rows.sort(key=lambda row: row[0] if math.isfinite(row[0]) else math.inf)
    return header, rows


def events_sidecar(header: list, session: dict) -> dict:
    """The events sidecar: every column with its description, unit and (for the choices) levels."""
    exp = session.get("experiment") or {}
    out = {"onset": {"Description": "time of the trial's tap cue from the session's start", "Units": "s"},
           "duration": {"Description": "device time from the tap cue to the end of the trial (answer included)",
                        "Units": "s"},
           "trial_type": {"Description": "sample or condition presented"}}
    unit = exp.get("unit") or exp.get("intensity_unit")
    for col in header[3:]:
        desc, u = COLUMN_INFO.get(col, (col.replace("_", " "), None))
        entry = {"Description": desc}
        if u is None and unit and col in ("reference_value", "start_value", "final_value", "values", "level",
                                          "modulus", "intensity_physical"):
            u = unit
        if u and col in LIST_COLUMNS:   # text (';'-joined numbers): a unit would declare the column numeric
            entry["Description"] = f"{desc} ({u})"
        elif u:
            entry["Units"] = u
        if col == "start_side":
            entry["Levels"] = {"above": "started above the reference", "below": "started below"}
        out[col] = entry
    return out


def motion_runs(subj: dict) -> list[tuple[str, int, int, Path]]:
    """``(phase, trial, attempt, path)`` of every trace file of a subject, in the order of the trials."""
    traces = subj["folder"] / TRACES_DIR
    if not traces.is_dir():
        return []
    found = []
    for p in sorted(traces.glob("*.npz")):
        m = re.match(r"(.+)_t(\d{3,})_a(\d{2,})\.npz$", p.name)
        if m and p.name == trace_name(m.group(1), int(m.group(2)), int(m.group(3))):
            found.append((m.group(1), int(m.group(2)), int(m.group(3)), p))
    return sorted(found, key=lambda f: (f[1], f[2], f[3].stat().st_mtime_ns, f[0]))


def decimated(trace: dict, fs_hz: float, rate_hz: float, where) -> tuple[np.ndarray, float, list]:
    """A trace's motion channels at ``rate_hz`` (the servo rate over a whole number): ``(values (n, channels),
    rate, channels)``; a channel the trace lacks is left out (older or other software's traces), its time from
    ``fs_hz`` when it has no ``t_s``.

    Raises
    ------
    ValueError
        No channel of :data:`MOTION_CHANNELS` besides the time (naming ``where``).
    """
    q = max(1, int(round(fs_hz / rate_hz)))
    chans = [c for c in MOTION_CHANNELS[1:] if c[1] in trace]
    if not chans:
        raise ValueError(f"{where}: none of the traces' channels ({', '.join(c[1] for c in MOTION_CHANNELS[1:])})")
    n = len(np.asarray(trace[chans[0][1]]))
    t = np.asarray(trace["t_s"], dtype=float) if "t_s" in trace else np.arange(n) / fs_hz
    cols = [t[::q]]
    for _, key, *_ in chans:
        x = np.asarray(trace[key], dtype=float)
        cols.append(x[::q] if q == 1 else resample_poly(x, 1, q)[:len(x[::q])])
    m = min(len(c) for c in cols)
    return np.column_stack([c[:m] for c in cols]), fs_hz / q, [MOTION_CHANNELS[0], *chans]


def export(data, out: Path, motion_rate_hz: float | None = 1000.0, name: str | None = None) -> dict:
    """Write the BIDS dataset of the study folder ``data`` into ``out`` (an empty staging folder); returns what
    was written (subjects, tasks, files)."""
    data = Path(data)
    folders = [data] if (data / SESSION_JSON).is_file() else sorted(
        p for p in data.iterdir() if p.is_dir() and (p / SESSION_JSON).is_file())
    if not folders:
        raise ValueError(f"{data}: no subject folder (DATA/<subject>/{SESSION_JSON}) in it")
    subjects = [read_subject(f) for f in folders]
    labels = {}
    for s in subjects:
        label = bids_label(s["session"]["subject"])
        if not label:
            raise ValueError(f"{s['folder']}: subject id {s['session']['subject']!r} has no letter or digit for a "
                             "BIDS label")
        if label in labels:
            raise ValueError(f"subjects {labels[label]!r} and {s['session']['subject']!r} both become sub-{label} "
                             "(BIDS labels are letters and digits only); rename one")
        labels[label] = s["session"]["subject"]
        s["label"] = label
    version = provenance.software_versions().get("hfam-haptics")
    atomic_write_text(out / "dataset_description.json", json.dumps({
        "Name": name or f"Haptic study {data.resolve().name}", "BIDSVersion": BIDS_VERSION, "DatasetType": "raw",
        "GeneratedBy": [{"Name": "hfam-haptics", "Description": "python -m analysis export-bids",
                         **({"Version": str(version)} if version else {})}]}, indent=2) + "\n")
    tasks = sorted({s["task"] for s in subjects})
    atomic_write_text(out / "README", f"Haptic study exported from {data.resolve().name} by python -m analysis "
                                      f"export-bids.\n\nTasks: {', '.join(tasks)}. Behaviour in beh/ (one events file "
                                      "per subject and task, described by task-<task>_events.json); the haptic "
                                      "device's traces in motion/ (one run per presentation, runs.tsv maps runs to "
                                      "trials).\n")
    prow = []
    for s in subjects:
        ss = s["session"]
        prow.append([f"sub-{s['label']}", ss.get("age"), {"unspecified": None}.get(ss.get("gender"), ss.get("gender")),
                     HANDEDNESS.get(ss.get("handedness"), None), ss.get("experience"), ss["subject"]])
    atomic_write_text(out / "participants.tsv", _tsv(["participant_id", "age", "gender", "handedness", "experience",
                                                      "subject_id"], prow))
    atomic_write_text(out / "participants.json", json.dumps({
        "age": {"Description": "age of the participant", "Units": "year"},
        "gender": {"Description": "gender as the participant stated it", "Levels": {
            "female": "female", "male": "male", "other": "other"}},
        "handedness": {"Description": "handedness", "Levels": {"left": "left", "right": "right",
                                                               "ambidextrous": "ambidextrous"}},
        "experience": {"Description": "prior experience with haptic devices", "Levels": {
            "none": "never", "few": "a few times", "regular": "regularly"}},
        "subject_id": {"Description": "the subject id in the study's data folder"}}, indent=2) + "\n")
    sidecars, files = {}, 0
    for s in subjects:
        sub, task = f"sub-{s['label']}", s["task"]
        header, rows = events_table(s)
        beh = out / sub / "beh"
        beh.mkdir(parents=True, exist_ok=True)
        atomic_write_text(beh / f"{sub}_task-{task}_events.tsv", _tsv(header, rows))
        files += 1
        car = sidecars.setdefault(task, {"TaskName": task})
        car.update(events_sidecar(header, s["session"]))
        if motion_rate_hz:
            files += _motion(s, out / sub / "motion", sub, task, motion_rate_hz)
    for task, car in sidecars.items():
        atomic_write_text(out / f"task-{task}_events.json", json.dumps(car, indent=2) + "\n")
    return {"subjects": len(subjects), "tasks": tasks, "files": files}


def _motion(s: dict, folder: Path, sub: str, task: str, rate_hz: float) -> int:
    runs = motion_runs(s)
    if not runs:
        return 0
    folder.mkdir(parents=True, exist_ok=True)
    device = s["session"].get("device", {})
    info = device.get("info", {}) if isinstance(device, dict) else {}
    index = []
    for k, (phase, trial, attempt, path) in enumerate(runs, start=1):
        trace = dict(load_npz(path, "trace"))
        if "fs_hz" not in trace:
            raise ValueError(f"{path}: a trace without fs_hz (the servo's rate)")
        values, fs, chans = decimated(trace, float(trace["fs_hz"]), rate_hz, path)
        stem = f"{sub}_task-{task}_tracksys-haptic_run-{k}"
        atomic_write_text(folder / f"{stem}_motion.tsv",
                          "".join("\t".join(repr(float(v)) for v in row) + "\n" for row in values))
        atomic_write_text(folder / f"{stem}_channels.tsv", _tsv(
            ["name", "component", "type", "tracked_point", "units", "description"],
            [[n, c, t, "handle", u, d] for n, _, t, c, u, d in chans]))
        atomic_write_text(folder / f"{stem}_motion.json", json.dumps({
            "TaskName": task, "SamplingFrequency": fs, "TrackingSystemName": "haptic device",
            "Manufacturer": str(info.get("name") or device.get("spec", "n/a")) if isinstance(device, dict) else "n/a",
            "MotionChannelCount": len(chans), "TrackedPointsCount": 1,
            "RecordingDuration": float(values[-1, 0] - values[0, 0]) if len(values) else 0.0,
            "RecordingType": "epoched",
            "SamplingFrequencyEffective": fs}, indent=2) + "\n")
        index.append([k, phase, trial, attempt, path.name])
    atomic_write_text(folder.parent / f"{sub}_scans.tsv", _tsv(
        ["filename", "presentation", "trial", "attempt", "trace_file"],
        [[f"motion/{sub}_task-{task}_tracksys-haptic_run-{k}_motion.tsv", *rest] for k, *rest in index]))
    atomic_write_text(folder.parent / f"{sub}_scans.json", json.dumps({
        "presentation": {"Description": "what the run presented (the trace's name: interval1, reference01, ...)"},
        "trial": {"Description": "the trial of the trials.csv row"}, "attempt": {"Description": "its attempt"},
        "trace_file": {"Description": "the trace file in the study's data folder (traces/)"}}, indent=2) + "\n")
    return 3 * len(runs)
