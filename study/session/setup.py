"""A study session's folder opened or resumed: every check before a session starts, then its record.

:func:`plan_session` settles the subject, device, participant, protocol, experiment kind, seed and catalog
(a resumed session must continue exactly as it started); :func:`start_session` writes a new
``session.json`` and the kind's plan, or checks and logs the resumption. Used by
:mod:`study.session.run`, for every experiment kind.
"""

from __future__ import annotations

import hashlib
import secrets
from dataclasses import dataclass, replace
from pathlib import Path

from devices.registry import check_device_spec
from devices.sim import SAMPLES
from plumbing import provenance
from stimuli import load_catalog

from .config import ProtocolConfig, SubjectInfo, load_protocol, protocol_from, read_protocol_file
from .store import SessionStore, check_subject_id, utc_now


@dataclass
class SessionPlan:
    """What :func:`plan_session` settled for a session (new, or resumed from ``previous``)."""

    subject: str
    store: SessionStore
    previous: dict | None
    is_sim: bool
    protocol: ProtocolConfig
    seed: int
    info: SubjectInfo
    library_dir: str | None
    catalog_file: str | None
    catalog: list
    kind: type = None          # the experiment kind's class (study.session.kind.ExperimentKind)
    config: object = None      # its settings (ExperimentKind.configure), None for the default kind
    device_info: dict | None = None   # the opened device's description (set once it is open)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _catalog_entries(catalog) -> list[dict]:
    out = []
    for s in catalog:
        entry = {"name": s.name, "label": s.label, "kind": s.kind, "stiffness_N_m": s.stiffness_N_m,
                 "transient": s.transient, "params": dict(s.params), "real_sample": s.real_sample}
        if s.library is not None:
            entry["library"] = str(s.library)
            entry["library_sha256"] = _sha256(Path(s.library))
        out.append(entry)
    return out


def load_study_catalog(catalog_path, library_dir, samples_arg, is_sim: bool, familiarization_sample: str):
    """Load the catalog, pick ``--samples`` and check everything a session needs (before it starts)."""
    catalog = load_catalog(catalog_path, library_dir=library_dir)
    names = [s.name for s in catalog]
    if samples_arg:
        wanted = [x.strip() for x in samples_arg.split(",") if x.strip()]
        unknown = [x for x in wanted if x not in names]
        if unknown:
            raise ValueError(f"--samples: unknown sample(s) {unknown}; the catalog has {names}")
        catalog = [s for s in catalog if s.name in wanted]
    if is_sim:

        for s in catalog:
            if s.kind == "real" and s.real_sample not in SAMPLES:
                raise ValueError(f"catalog sample {s.name!r}: unknown sim sample real_sample={s.real_sample!r}; "
                                 f"the sim device has {sorted(SAMPLES)}")
    for s in catalog:
        if s.transient == "hfam":
            path = Path(library_dir) / s.library_ref if library_dir and s.library_ref and not Path(
                s.library_ref).is_absolute() else s.library
            if path is None or not Path(path).is_file():
                raise FileNotFoundError(f"catalog sample {s.name!r}: HFAM library file missing: {path}")
    if familiarization_sample:
        fam = [s for s in catalog if s.name == familiarization_sample]
        if not fam:
            raise ValueError(f"familiarization_sample {familiarization_sample!r} is not among the session's "
                             f"samples ({[s.name for s in catalog]}); "
                             "set familiarization_sample = \"\" in --protocol to skip familiarization")
        if fam[0].kind != "real":
            raise ValueError(f"familiarization_sample {familiarization_sample!r} must be a real sample")
    return catalog


def _check_same_catalog(before: list[dict], now: list[dict], where) -> None:
    """A resumed session must present exactly the same samples (names, parameters, library contents)."""
    keys = ("name", "kind", "stiffness_N_m", "transient", "params", "real_sample", "library_sha256")
    for a, b in zip(before, now):
        diff = [k for k in keys if a.get(k) != b.get(k)]
        if diff:
            raise ValueError(f"--resume: sample {a['name']!r} changed since the session started ({where}): "
                             f"{', '.join(diff)} differ; restore the original catalog/library files")
    if len(before) != len(now):
        raise ValueError(f"--resume: the catalog changed since the session started ({where}): "
                         f"{[c['name'] for c in before]} -> {[c['name'] for c in now]}")


def software_versions() -> dict:
    """Python, every result-affecting dependency, the project's version and git commit (plumbing.provenance)."""
    return provenance.software_versions()


def _jsonable(obj):
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    return obj


def _check_resumed_session(previous: dict, where) -> None:
    """The parts of a resumed ``session.json`` that resuming reads: present and of the right type, or one
    ValueError naming the file and the key (a hand-edited or damaged file, not a raw KeyError/TypeError)."""
    def bad(key: str, want: str) -> ValueError:
        if key.split(".")[0] not in previous:
            return ValueError(f"{where}: session.json has no {key!r} key; it is damaged or not written by this "
                              "program")
        value = previous
        for part in key.split("."):
            value = value.get(part) if isinstance(value, dict) else None
        return ValueError(f"{where}: {key} must be {want}, got {value!r}")

    if not isinstance(previous.get("device"), dict):
        raise bad("device", "an object with the device string under \"spec\"")
    if not isinstance(previous["device"].get("spec"), str):
        raise bad("device.spec", "a device string such as \"sim\"")
    if not isinstance(previous.get("participant"), str):
        raise bad("participant", "a string (\"simulated\" or \"keyboard\")")
    if not isinstance(previous.get("protocol"), dict):
        raise bad("protocol", "an object of protocol settings")
    if isinstance(previous.get("seed"), bool) or not isinstance(previous.get("seed"), int):
        raise bad("seed", "an integer")
    for key in ("age", "gender", "handedness", "experience"):
        if key not in previous:
            raise bad(key, "present")
    catalog = previous.get("catalog")
    if not isinstance(catalog, list) or not all(isinstance(c, dict) and isinstance(c.get("name"), str)
                                                for c in catalog):
        raise bad("catalog", "a list of sample objects, each with a \"name\"")
    for key in ("library_dir", "catalog_file"):
        if previous.get(key) is not None and not isinstance(previous[key], str):
            raise bad(key, "a path string or null")
    for key in ("resumed_at", "audio_resumed"):
        if key in previous and not isinstance(previous[key], list):
            raise bad(key, "a list")


def choose_kind(kinds, table, where: str):
    """The experiment kind a protocol's ``[experiment]`` table names (no table: the default kind).

    Parameters
    ----------
    kinds : sequence of type or study.session.kind.KindAt
        The experiment kinds (:class:`study.session.kind.ExperimentKind` classes, or where they are); the
        default one has no ``names``.
    table : object
        The ``[experiment]`` table as written, or None.
    where : str
        The table's source, for messages.

    Returns
    -------
    type
        The kind's class (imported now if ``kinds`` named it by its module).
    """
    if table is None:
        return next(k for k in kinds if not k.names).load()
    if not isinstance(table, dict):
        raise ValueError(f"{where}: [experiment] must be a table of settings, got {type(table).__name__}")
    names = [name for k in kinds for name in k.names]
    for k in kinds:
        if table.get("kind") in k.names:
            return k.load()
    raise ValueError(f"{where}: [experiment] kind must be one of {names}, got {table.get('kind', '')!r}")


def plan_session(args, kinds) -> SessionPlan:
    """Open the session folder, new or resumed, and settle everything a session needs before it starts.

    Checks, in order: the subject id and folder (an existing subject needs ``--resume``), a resumed session's
    device kind, participant and seed, the device string, the participant, the protocol and its experiment
    kind (one of ``kinds``), the subject's details, the catalog (and, on resume, that its samples did not
    change). Fills ``args.device`` and ``args.participant`` with the defaults or the resumed session's values.

    Returns
    -------
    SessionPlan
    """
    subject = check_subject_id(args.subject)
    store = SessionStore(args.out, subject, resume=args.resume)
    store.check()  # unwritable folder, existing subject without --resume: refused before anything starts
    previous = store.load_session() if args.resume else None
    if previous is not None:
        _check_resumed_session(previous, store.session_path)
        was_sim = previous["device"]["spec"].split(":", 1)[0] == "sim"
        args.device = args.device or previous["device"]["spec"]
        if (args.device.split(":", 1)[0] == "sim") != was_sim:
            raise ValueError(f"--resume: the session ran on {previous['device']['spec']!r}; it cannot continue on "
                             f"{args.device!r} (sim and hardware data must not mix)")
        args.participant = args.participant or previous["participant"]
        if args.participant != previous["participant"]:
            raise ValueError(f"--resume: the session ran with --participant {previous['participant']}, "
                             f"not {args.participant}")
    # the realism study is chapter 4's: by default on the section 4.4.3 one-dof testbed (devices.sim.presets)
    args.device = args.device or "sim:onedof"
    check_device_spec(args.device)  # a typo in the device string is reported before audio or participant checks
    args.participant = args.participant or "simulated"
    is_sim = args.device.split(":", 1)[0] == "sim"
    if args.participant == "simulated" and not is_sim:
        raise ValueError(f"--participant simulated needs a sim device (--device sim), not {args.device!r}; "
                         "use --participant keyboard for a person")

    protocol_overrides = {"repetitions": args.repetitions, "tap_window_s": args.tap_window_s,
                          "masking_level_dbfs": args.masking_level_dbfs, "cue_level_db": args.cue_level_db}
    if previous is not None:
        # the settings come from session.json, not from the command line
        protocol = load_protocol(None, where=f"{store.session_path}: protocol", **previous["protocol"])
        kind, config = _resumed_kind(kinds, previous, store.session_path)
        if args.seed is not None and args.seed != previous["seed"]:
            raise ValueError(f"--seed {args.seed} differs from the session's seed {previous['seed']} "
                             f"({store.session_path}); omit --seed when resuming")
        seed = int(previous["seed"])
        try:
            info = SubjectInfo(subject, previous["age"], previous["gender"], previous["handedness"],
                               previous["experience"])
        except ValueError as exc:
            raise ValueError(f"{store.session_path}: {exc}") from None
    else:
        data, table = read_protocol_file(args.protocol)
        where = str(Path(args.protocol)) if args.protocol is not None else "command line"
        kind = choose_kind(kinds, table, where)
        config = kind.configure(table, where)
        protocol = protocol_from(data, args.protocol, **protocol_overrides)
        if not kind.familiarization:  # e.g. psychophysics sessions: no familiarization or demonstration (docs/study.md)
            protocol = replace(protocol, familiarization_sample="")
        if table is not None and args.samples:
            raise ValueError(f"--samples: a psychophysics session presents the samples its protocol's [experiment] "
                             f"names ({args.protocol}); omit --samples")
        seed = args.seed if args.seed is not None else secrets.randbelow(2 ** 31)
        if args.participant == "keyboard" and None in (args.age, args.gender, args.handedness, args.experience):
            raise ValueError("a session with a person needs --age, --gender, --handedness and --experience "
                             "(section 4.5.3: collected before the session)")
        info = SubjectInfo(subject, args.age, args.gender or "unspecified", args.handedness or "unspecified",
                           args.experience or "few")

    # stored absolute, so a resume from another working directory finds the same files
    library_dir = (str(Path(args.library_dir).resolve()) if args.library_dir else None) if previous is None \
        else previous.get("library_dir")
    catalog_file = (str(Path(args.catalog).resolve()) if args.catalog else None) if previous is None \
        else previous.get("catalog_file")
    subset = args.samples if previous is None else ",".join(s["name"] for s in previous["catalog"])

    def load(chosen: bool) -> list:
        """The catalog, checked; ``chosen``: the samples ``--samples`` picks (or the resumed session's), with the
        familiarization sample among them."""
        if chosen:
            return load_study_catalog(catalog_file, library_dir, subset, is_sim, protocol.familiarization_sample)
        return load_study_catalog(catalog_file, library_dir, None, is_sim, "")

    where = args.protocol if previous is None else f"{store.session_path}: experiment"
    catalog = kind.samples(config, load, where)
    if previous is not None:
        _check_same_catalog(previous["catalog"], _catalog_entries(catalog), store.session_path)

    store.rows = kind.rows
    return SessionPlan(subject, store, previous, is_sim, protocol, seed, info, library_dir, catalog_file, catalog,
                       kind, config)


def _resumed_kind(kinds, previous: dict, where):
    """The experiment kind and its settings of a resumed session (``session.json["experiment"]["config"]``; a
    session without ``experiment`` is of the default kind)."""
    if "experiment" not in previous:
        return choose_kind(kinds, None, where), None
    exp = previous["experiment"]
    if not isinstance(exp, dict) or not isinstance(exp.get("config"), dict):
        raise ValueError(f"{where}: experiment must be an object with the [experiment] settings under \"config\"")
    kind = choose_kind(kinds, exp["config"], f"{where}: experiment.config")
    return kind, kind.configure(exp["config"], f"{where}: experiment.config")


def start_session(plan: SessionPlan, args, experiment, device_info: dict, servo_process: bool, sim_participant,
                  audio_info: dict, real_saturation_detection) -> tuple[list, list]:
    """Write a new session's ``session.json`` and plan, or check and log the resumption of a previous one.

    Parameters
    ----------
    plan : SessionPlan
    args : argparse.Namespace
        The ``run`` command's arguments.
    experiment : study.session.kind.ExperimentKind
        The session's kind: its ``plan()`` gives ``session.json``'s own entries and schedule.jsonl's plan.
    device_info, audio_info : dict
        Recorded in session.json.
    servo_process : bool
        Whether the servo loop runs in its own process.
    sim_participant : study.session.participants.SimulatedParticipant or None
    real_saturation_detection : str
        How saturation on a real sample is detected (recorded).

    Returns
    -------
    rows : list of dict
        The rows already on disk (empty for a new session), every one checked: a damaged file is refused,
        naming the line.
    events : list of dict
        schedule.jsonl's events before this resumption (empty for a new session).

    A resumed session's kind has restored itself (:meth:`study.session.kind.ExperimentKind.restore`: its checks
    of the rows and files, and what a kill lost written again) before anything of the resumption is written.
    """
    store, previous, subject, info = plan.store, plan.previous, plan.subject, plan.info
    protocol, seed, catalog = plan.protocol, plan.seed, plan.catalog
    catalog_file, library_dir, isolate = plan.catalog_file, plan.library_dir, servo_process
    if previous is None:
        session = {
            "subject": subject, "age": info.age, "gender": info.gender, "handedness": info.handedness,
            "experience": info.experience, "seed": seed, "repetitions": protocol.repetitions,
            "catalog": _catalog_entries(catalog), "catalog_file": catalog_file, "library_dir": library_dir,
            "protocol": protocol.to_dict(), "device": {"spec": args.device, "info": _jsonable(device_info),
                       "servo_process": isolate},
            "participant": args.participant,
            "simulated_participant": sim_participant.describe() if sim_participant else None,
            "participant_config_file": (str(Path(args.participant_config).resolve())
                                        if args.participant_config else None),
            "audio": audio_info, "real_saturation_detection": real_saturation_detection,
            "software_version": software_versions(), "started_at": utc_now(), "finished_at": None,
            "resumed_at": [],
        }
        entries, events = experiment.plan()
        session.update(entries)
        # one atomic step: session.json, the trials.csv header and the plan appear together or not at all
        store.create(session, events=events)
        store.hold_trials()  # held from now to the end: a file moved or replaced meanwhile stops the session
        return [], []
    store.session = previous
    rows = store.read_trials()        # every row checked: a damaged file is refused, naming the line
    events = store.read_events()      # a torn last line is kept aside before anything is appended
    store.hold_trials()               # held once mended: a change from now on stops the session
    # the kind checks the rows and its files against the session (and writes what a kill lost) before the
    # resumption is recorded: a refused file leaves session.json and schedule.jsonl as they were
    note = experiment.restore(store, rows, events)
    if note and not getattr(args, "quiet", False):
        print(note, flush=True)
    store.session.setdefault("resumed_at", []).append(utc_now())
    # parallel to resumed_at: the audio (cue source) of each resumed part, which may differ from the first
    store.session.setdefault("audio_resumed", []).append(audio_info)
    store.write_session()
    store.log_event({"event": "resume", "attempts_on_disk": len(rows), "software_version": software_versions()})
    return rows, events
