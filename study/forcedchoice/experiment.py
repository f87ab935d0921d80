"""The forced-choice experiments: the ``[experiment]`` table of a protocol file, the stimuli and the trial plan.

A protocol file (``--protocol FILE``, TOML or JSON) holds the realism study's settings (keys of
:class:`study.session.config.ProtocolConfig`: timing, masking, cues) and, for a psychophysics session, an
``[experiment]`` table (keys of :class:`ExperimentConfig`) naming the kind:

* ``real-virtual-2afc`` -- two taps per trial, one on the real sample (placed by the operator) and one on a
  rendering; "which was real?"; proportion correct per rendering, chance 0.5.
* ``discrimination`` -- a reference wall and a comparison differing in stiffness (or transient amplitude or
  gain); "which was harder?"; the fraction of "comparison harder" answers against the comparison's value
  gives PSE and JND (Weber fraction = JND / reference).
* ``detection`` -- the weakest transient felt: one interval has the wall with its transient at the tested
  amplitude, the other the same wall without it; "which interval had the click?"; chance 0.5.

Data (``trials.csv``, ``session.json["experiment"]``) follow the contract of docs/study.md ("Psychophysics
sessions"), which ``python -m analysis psychometric`` reads: the psychometric function
``psi(x) = gamma + (1 - gamma - lambda) F(x; alpha, beta)`` with gamma = 1/2 for the 2-interval tasks
"which was real?" and "which had the click?" and 0 for "which was harder?".

"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

from devices.base import DeviceInfo
from devices.limits import IMPLAUSIBLE_STIFFNESS_FACTOR, one_count_stiffness_N_m
from plumbing.validation import require_int
from psychophysics.multistair import Interleaved
from psychophysics.names import METHOD_NAMES

from ..session.config import ProtocolConfig, experiment_config, protocol_from, read_protocol_file
from ..session.rng import seed_sequence, session_rng

KINDS = ("real-virtual-2afc", "discrimination", "detection")
#: adaptive methods (:mod:`psychophysics.methods`: Levitt 1971, Kaernbach 1991, Watson 2017, Kontsevich & Tyler 1999)
ADAPTIVE_METHODS = METHOD_NAMES
METHODS = ("constant", *ADAPTIVE_METHODS)
VARIED = {"discrimination": ("stiffness_N_m", "amplitude_Ns_m", "gain"),
          "detection": ("amplitude_Ns_m", "gain")}
UNITS = {"stiffness_N_m": "N/m", "amplitude_Ns_m": "N*s/m", "gain": "1", "rendering": "1"}
#: the sizes an [experiment] table may ask for, so that a session's plan, memory and time stay bounded (a typo
#: such as ``trials_per_level = 1e9`` or a QUEST+ grid of 10^6 intensities is refused, naming the key and the
#: bound): levels (or renderings), trials per level, trials planned in all, staircases, a staircase's
#: ``max_trials``, the points of one QUEST+/Psi grid and the cells of its likelihood table (intensities x
#: thresholds x slopes x lapses)
MAX_LEVELS = 100
MAX_TRIALS_PER_LEVEL = 1000
MAX_PLANNED_TRIALS = 10_000
MAX_STAIRCASES = 20
MAX_STAIRCASE_TRIALS = 2000
MAX_GRID_POINTS = 1000
MAX_GRID_CELLS = 4_000_000
#: the grids of a QUEST+/Psi table (:mod:`psychophysics.quest`)
GRID_KEYS = ("intensities", "thresholds", "slopes", "lapses")
QUESTIONS = {"real-virtual-2afc": "Which tap was on the real sample?",
             "discrimination": "Which surface was harder?",
             "detection": "Which tap had the click?"}


@dataclass(frozen=True)
class ExperimentConfig:
    """The ``[experiment]`` table of a protocol file.

    Attributes
    ----------
    kind : str
        ``real-virtual-2afc``, ``discrimination`` or ``detection``.
    method : str
        ``constant`` (method of constant stimuli: every level ``trials_per_level`` times, random order) or an
        adaptive method, ``updown`` (transformed up-down, Levitt 1971), ``weighted`` (weighted up-down,
        Kaernbach 1991), ``quest+`` (Watson 2017) or ``psi`` (Kontsevich & Tyler 1999), run by the
        ``staircases`` (discrimination and detection only).
    real_sample : str
        real-virtual-2afc: catalog name of the real sample the operator places (default ``wood``).
    renderings : list of str
        real-virtual-2afc: catalog names of the virtual renderings compared with it (one condition each).
    sample : str
        discrimination, detection: catalog name of the virtual sample whose parameter ``vary`` is varied.
    vary : str
        The varied parameter: ``stiffness_N_m`` (N/m), ``amplitude_Ns_m`` (N*s/m, a pulse's or a decaying
        sinusoid's amplitude A of eqs. 4.7/4.8) or ``gain`` (dimensionless transient gain, e.g. of an HFAM
        library). Default: stiffness for discrimination, amplitude for detection.
    reference : float
        discrimination: the reference's value of ``vary`` (physical units).
    levels : list of float
        discrimination: the comparison's values; detection: the transient's values (physical units, > 0).
    trials_per_level : int
        Trials per level (real-virtual-2afc: per rendering); the target interval is balanced within each.
    intensity_scale : str
        ``linear`` or ``log10``: the scale of trials.csv's ``intensity`` column (``intensity_physical``
        always holds the physical value).
    alternatives : int
        Intervals per trial (2: two-interval forced choice).
    staircases : dict
        Adaptive methods: label -> the staircase's table (the method's parameters, :mod:`psychophysics.methods`:
        ``start``, ``step_down``, ``max_trials``, ``max_reversals``, ... for up-down; ``intensities``,
        ``thresholds``, ``slopes`` for QUEST+/Psi), in physical units of ``vary``; a table may name its own
        ``method``. Several labels are interleaved (:class:`psychophysics.multistair.Interleaved`).
    order : str
        Interleaving of the staircases: ``random`` (shuffled per round) or ``fixed``.
    catch_rate : float
        Probability of a catch trial before a staircase trial (adaptive only; excluded from fits).
    catch_intensity : float or None
        The catch trials' value of ``vary`` (detection: 0 presents no transient in either interval).
    """

    kind: str = ""
    method: str = "constant"
    real_sample: str = "wood"
    renderings: tuple = ()
    sample: str = ""
    vary: str = ""
    reference: float | None = None
    levels: tuple = ()
    trials_per_level: int = 10
    intensity_scale: str = "linear"
    alternatives: int = 2
    staircases: dict = field(default_factory=dict)
    order: str = "random"
    catch_rate: float = 0.0
    catch_intensity: float | None = None

    def __post_init__(self) -> None:
        for key in ("renderings", "levels"):   # bounded before anything is made of them
            value = getattr(self, key)
            if isinstance(value, (list, tuple)) and len(value) > MAX_LEVELS:
                raise ValueError(f"{key} lists {len(value)} values; at most {MAX_LEVELS}")
        object.__setattr__(self, "renderings", _str_tuple("renderings", self.renderings))
        object.__setattr__(self, "levels", _float_tuple("levels", self.levels))
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {list(KINDS)}, got {self.kind!r}")
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {list(METHODS)}, got {self.method!r}")
        require_int("trials_per_level", self.trials_per_level, minimum=1, maximum=MAX_TRIALS_PER_LEVEL)
        cells = len(self.renderings) if self.kind == "real-virtual-2afc" else len(self.levels)
        if cells * self.trials_per_level > MAX_PLANNED_TRIALS:
            raise ValueError(f"trials_per_level = {self.trials_per_level} x {cells} levels plans "
                             f"{cells * self.trials_per_level} trials; at most {MAX_PLANNED_TRIALS} in one session")
        require_int("alternatives", self.alternatives, minimum=2, maximum=2)
        if self.intensity_scale not in ("linear", "log10"):
            raise ValueError(f"intensity_scale must be \"linear\" or \"log10\", got {self.intensity_scale!r}")
        if not isinstance(self.staircases, dict):
            raise ValueError(f"staircases must be a table of labelled staircase tables, got {self.staircases!r}")
        _check_staircase_sizes(self.staircases)
        if self.kind == "real-virtual-2afc":
            self._check_real_virtual()
        else:
            self._check_varied()

    def _check_real_virtual(self) -> None:
        if not self.real_sample:
            raise ValueError("real_sample must name the catalog's real sample the operator places")
        if not self.renderings:
            raise ValueError("renderings must list at least one virtual catalog sample")
        if len(set(self.renderings)) != len(self.renderings):
            raise ValueError(f"renderings lists a sample twice: {list(self.renderings)}")
        for key in ("sample", "vary", "levels"):
            if getattr(self, key):
                raise ValueError(f"{key} is not used by kind real-virtual-2afc (it compares renderings)")
        if self.reference is not None:
            raise ValueError("reference is not used by kind real-virtual-2afc")
        if self.intensity_scale != "linear":
            raise ValueError("intensity_scale must be \"linear\" for real-virtual-2afc (no intensity is varied)")
        if self.adaptive:
            raise ValueError(f"method {self.method!r}: real-virtual-2afc varies no intensity; use method = "
                             "\"constant\"")

    def _check_varied(self) -> None:
        if not self.sample:
            raise ValueError(f"sample must name the virtual catalog sample that kind {self.kind} varies")
        if self.renderings:
            raise ValueError(f"renderings is only for kind real-virtual-2afc, not {self.kind}")
        vary = self.vary or VARIED[self.kind][0]
        object.__setattr__(self, "vary", vary)
        if vary not in VARIED[self.kind]:
            raise ValueError(f"vary must be one of {list(VARIED[self.kind])} for kind {self.kind}, got {vary!r}")
        if self.adaptive:
            self._check_adaptive()
        elif len(self.levels) < 2:
            raise ValueError(f"levels must list at least 2 values of {vary}, got {list(self.levels)}")
        elif self.staircases or self.catch_rate:
            raise ValueError("staircases, catch_rate and catch_intensity are for adaptive methods; method "
                             "\"constant\" presents the levels")
        if len(set(self.levels)) != len(self.levels):
            raise ValueError(f"levels lists a value twice: {list(self.levels)}")
        if any(x <= 0 for x in self.levels):
            raise ValueError(f"levels must be > 0 ({vary}), got {list(self.levels)}")
        if self.kind == "discrimination":
            if self.reference is None:
                raise ValueError(f"reference (the reference's {vary}) is required for kind discrimination")
            if isinstance(self.reference, bool) or not isinstance(self.reference, (int, float)) \
                    or not math.isfinite(self.reference) or self.reference <= 0:
                raise ValueError(f"reference must be a number > 0, got {self.reference!r}")
            object.__setattr__(self, "reference", float(self.reference))
        elif self.reference is not None:
            raise ValueError("reference is only for kind discrimination (detection compares with no transient)")

    def _check_adaptive(self) -> None:
        if self.levels:
            raise ValueError(f"levels are for method \"constant\"; method {self.method!r} chooses the intensities "
                             "(give its staircases)")
        if not self.staircases:
            raise ValueError(f"method {self.method!r} needs at least one staircase table, e.g. "
                             "[experiment.staircases.A]")
        if self.catch_rate and self.kind == "discrimination" and not (
                isinstance(self.catch_intensity, (int, float)) and self.catch_intensity > 0):
            raise ValueError(f"catch_intensity must be > 0 ({self.vary}) for discrimination, "
                             f"got {self.catch_intensity!r}")
        if self.catch_rate and isinstance(self.catch_intensity, (int, float)) and self.catch_intensity < 0:
            raise ValueError(f"catch_intensity must be >= 0, got {self.catch_intensity!r}")
        handler = self.handler(0)   # every staircase key checked now, named
        for label, m in handler.methods.items():
            low = m.next_intensity()
            if not low > 0:
                raise ValueError(f"staircases.{label}: the first intensity must be > 0 ({self.vary}), got {low!r}")

    @property
    def adaptive(self) -> bool:
        """True for an adaptive method (staircases), False for constant stimuli."""
        return self.method in ADAPTIVE_METHODS

    def handler(self, seed: int):
        """The session's interleaved staircases (:class:`psychophysics.multistair.Interleaved`), seeded by ``seed``."""
        stairs = {}
        for label, table in self.staircases.items():
            if not isinstance(table, dict):
                raise ValueError(f"staircases.{label} must be a table of the method's parameters, got {table!r}")
            stairs[label] = {"method": self.method, **table}
        return Interleaved.from_table({"order": self.order, "seed": int(seed), "catch_rate": self.catch_rate,
                                       "catch_intensity": self.catch_intensity, "staircases": stairs})

    # -- what the contract records ------------------------------------------
    @property
    def gamma(self) -> float:
        """Guess rate of the psychometric function: 1/alternatives, 0 for "which was harder?"."""
        return 0.0 if self.kind == "discrimination" else 1.0 / self.alternatives

    @property
    def unit(self) -> str:
        """The physical unit of ``intensity_physical``."""
        return UNITS["rendering" if self.kind == "real-virtual-2afc" else self.vary]

    def to_session(self) -> dict:
        """``session.json["experiment"]``: the contract's keys plus this table's settings."""
        out = {"kind": self.kind, "alternatives": self.alternatives, "method": self.method,
               "intensity_scale": self.intensity_scale,
               "reference": self.reference, "guess_rate": self.gamma, "intensity_unit": self.unit,
               "question": QUESTIONS[self.kind], "config": self.to_dict()}
        return out

    def to_dict(self) -> dict:
        """The table as plain data (lists for tuples), re-readable by :func:`experiment_from_dict`."""
        d = asdict(self)
        d["renderings"], d["levels"] = list(self.renderings), list(self.levels)
        d["staircases"] = {k: dict(v) for k, v in self.staircases.items()}
        return d


def _grid_size(value) -> int | None:
    """The number of points of a grid as written (a list, or ``{"min", "max", "n"}``), None if not a grid."""
    if isinstance(value, (list, tuple)):
        return len(value)
    if isinstance(value, dict) and isinstance(value.get("n"), int) and not isinstance(value.get("n"), bool):
        return value["n"]
    return None


def _check_staircase_sizes(staircases: dict) -> None:
    """Refuse staircases whose memory or time would be unbounded, naming the key and the bound (before any
    staircase is built: a QUEST+ grid of 10^6 intensities would be allocated by its constructor)."""
    if len(staircases) > MAX_STAIRCASES:
        raise ValueError(f"staircases lists {len(staircases)} staircases; at most {MAX_STAIRCASES}")
    for label, table in staircases.items():
        if not isinstance(table, dict):
            continue   # refused with its own message when the staircases are built
        cap = table.get("max_trials")
        if isinstance(cap, int) and not isinstance(cap, bool) and cap > MAX_STAIRCASE_TRIALS:
            raise ValueError(f"staircases.{label}.max_trials = {cap}; at most {MAX_STAIRCASE_TRIALS}")
        cells = 1
        for key in GRID_KEYS:
            n = _grid_size(table.get(key))
            if n is None:
                continue
            if n > MAX_GRID_POINTS:
                raise ValueError(f"staircases.{label}.{key} has {n} points; at most {MAX_GRID_POINTS}")
            cells *= max(n, 1)
        if cells > MAX_GRID_CELLS:
            raise ValueError(f"staircases.{label}: its grids ({' x '.join(k for k in GRID_KEYS if k in table)}) "
                             f"make {cells} cells; at most {MAX_GRID_CELLS}")


def _str_tuple(key: str, value) -> tuple:
    if isinstance(value, str) or not isinstance(value, (list, tuple)) or \
            not all(isinstance(v, str) and v for v in value):
        raise ValueError(f"{key} must be a list of names, got {value!r}")
    return tuple(value)


def _float_tuple(key: str, value) -> tuple:
    if isinstance(value, str) or not isinstance(value, (list, tuple)) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value):
        raise ValueError(f"{key} must be a list of finite numbers, got {value!r}")
    return tuple(float(v) for v in value)


def experiment_from_dict(data: dict, where: str) -> ExperimentConfig:
    """Build an :class:`ExperimentConfig` from a table; unknown keys and bad values name ``where`` and the key."""
    return experiment_config(ExperimentConfig, data, where)


def load_protocol_file(path, where: str = "command line", **overrides):
    """Read ``--protocol FILE``: the protocol's keys and, optionally, an ``[experiment]`` table.

    Parameters
    ----------
    path : str, Path or None
        TOML (``.toml``) or JSON file; None: defaults and ``overrides`` only, no experiment.
    where : str
        Source named in messages when there is no file.
    **overrides
        Protocol values that win over the file's (None ignored), as :func:`study.session.config.load_protocol`.

    Returns
    -------
    (ProtocolConfig, ExperimentConfig or None)
        A forced-choice session has no familiarization or demonstration phase (``familiarization_sample``
        empty).

    Raises
    ------
    FileNotFoundError, ValueError
        Naming the file and the key.
    """
    data, table = read_protocol_file(path)
    experiment = None if table is None else experiment_from_dict(table, str(Path(path)))
    protocol: ProtocolConfig = protocol_from(data, path, where, **overrides)
    if experiment is None:
        return protocol, None
    return replace(protocol, familiarization_sample=""), experiment


# -- stimuli ------------------------------------------------------------------

def level_name(base: str, vary: str, value: float | None) -> str:
    """Catalog name of a derived stimulus: ``<base>@<vary>=<value>`` (``none`` for no transient)."""
    return f"{base}@{vary}={'none' if value is None else format(value, '.10g')}"


def stimulus_catalog(catalog, exp: ExperimentConfig) -> list:
    """The samples a session presents, derived from the catalog (list of :class:`stimuli.CatalogSample`).

    real-virtual-2afc: the real sample and the renderings as they are. discrimination: the base sample with
    ``vary`` set to the reference and to each level. detection: the base sample with its transient at each
    level, and the same wall without a transient.

    Raises
    ------
    ValueError
        A named sample missing from the catalog, or of the wrong kind or transient for ``vary``.
    """
    by_name = {s.name: s for s in catalog}

    def get(name: str, key: str):
        if name not in by_name:
            raise ValueError(f"[experiment] {key} = {name!r} is not in the catalog ({sorted(by_name)})")
        return by_name[name]

    if exp.kind == "real-virtual-2afc":
        real = get(exp.real_sample, "real_sample")
        if real.kind != "real":
            raise ValueError(f"[experiment] real_sample = {real.name!r} is a {real.kind} sample, not a real one")
        out = [real]
        for name in exp.renderings:
            s = get(name, "renderings")
            if s.kind != "virtual":
                raise ValueError(f"[experiment] renderings: {name!r} is a {s.kind} sample, not a rendering")
            out.append(s)
        return out
    base = get(exp.sample, "sample")
    if base.kind != "virtual":
        raise ValueError(f"[experiment] sample = {base.name!r} must be a virtual sample (the motor renders it)")
    if exp.vary == "amplitude_Ns_m" and base.transient not in ("pulse", "sinusoid"):
        raise ValueError(f"[experiment] vary = \"amplitude_Ns_m\" needs a pulse or sinusoid transient; sample "
                         f"{base.name!r} has {base.transient!r} (use vary = \"gain\")")
    if exp.vary == "gain" and base.transient == "none":
        raise ValueError(f"[experiment] vary = \"gain\": sample {base.name!r} has no transient")
    values = list(exp.levels) + ([exp.reference] if exp.kind == "discrimination" else [])
    out = [derive_sample(base, exp, value) for value in sorted(set(values))]
    if exp.kind == "detection":
        out.append(derive_sample(base, exp, None))
    return out


#: the slowest tap a person makes on the stand (m/s; the thesis's taps are 0.05-0.3 m/s, section 4.5): a
#: velocity-scaled transient that asks more force than the amplifier gives even at this speed saturates every tap
SLOWEST_TAP_M_S = 0.05


def device_info(info) -> DeviceInfo:
    """A :class:`devices.base.DeviceInfo` from the session's record of it (``asdict`` of one), or itself."""
    if isinstance(info, DeviceInfo):
        return info
    names = {f.name for f in fields(DeviceInfo)}
    return DeviceInfo(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in dict(info).items() if k in names})


def unrenderable(sample, info) -> str | None:
    """Why the device cannot render ``sample`` (a catalog sample, possibly derived), or None when it can.

    Two bounds, the same the servo loop applies (:func:`devices.limits.check_stiffness`) or would meet on every
    tap: a wall stiffer than :data:`devices.limits.IMPLAUSIBLE_STIFFNESS_FACTOR` times the stiffness at which one
    encoder count commands the continuous force; a pulse or decaying sinusoid (eqs. 4.7, 4.8) whose force at
    the slowest tap (:data:`SLOWEST_TAP_M_S`), ``gain * A * v``, is beyond the amplifier's (its current limit
    times the force per amp): every tap would saturate and every attempt be invalid.

    Parameters
    ----------
    sample : stimuli.CatalogSample
    info : devices.base.DeviceInfo or dict
    """
    info = device_info(info)
    if sample.kind != "virtual":
        return None
    k_max = IMPLAUSIBLE_STIFFNESS_FACTOR * one_count_stiffness_N_m(info)
    if sample.stiffness_N_m > k_max:
        return (f"stiffness {sample.stiffness_N_m:g} N/m is beyond what {info.name} can render (at most "
                f"{k_max:.4g} N/m: {IMPLAUSIBLE_STIFFNESS_FACTOR:g} times the stiffness at which one encoder count "
                "commands its continuous force)")
    if sample.transient in ("pulse", "sinusoid"):
        amplitude = sample.params.get("amplitude_Ns_m")
        gain = sample.params.get("gain", 1.0)
        if isinstance(amplitude, (int, float)) and isinstance(gain, (int, float)):
            force = float(gain) * float(amplitude) * SLOWEST_TAP_M_S
            limit = info.current_amplifier_A * info.force_per_amp_N_A
            if force > limit:
                return (f"a {sample.transient} of amplitude {gain * amplitude:g} N*s/m asks {force:.3g} N even at "
                        f"a slow tap ({SLOWEST_TAP_M_S:g} m/s), beyond the {limit:.3g} N of {info.name}'s amplifier "
                        f"({info.current_amplifier_A:g} A): every tap would saturate")
    return None


def levels_asked(exp: ExperimentConfig, catalog, base=None, handler=None) -> list:
    """What a session can present, as ``(key, value, sample)``: a constant-stimuli plan's renderings, levels
    and reference (``catalog``: the session's derived samples), or what an adaptive method's staircases can
    ask for (each first intensity, ``max_intensity``, the top of a QUEST+/Psi grid; the catch trials' intensity
    and the reference), derived from ``base``."""
    if handler is None:
        if exp.kind == "real-virtual-2afc":
            return [("renderings", s.name, s) for s in catalog if s.kind == "virtual"]
        by_name = {s.name: s for s in catalog}
        values = [("levels", x) for x in exp.levels] + ([("reference", exp.reference)]
                                                         if exp.kind == "discrimination" else [])
        return [(key, x, by_name[level_name(exp.sample, exp.vary, x)]) for key, x in values]
    asks = []
    for label, m in handler.methods.items():
        asks.append((f"staircases.{label} (its first intensity)", m.next_intensity()))
        if getattr(m, "max_intensity", None) is not None:
            asks.append((f"staircases.{label}.max_intensity", m.max_intensity))
        grid = getattr(m, "x", None)
        if grid is not None and len(grid):
            asks.append((f"staircases.{label}.intensities (the top of the grid)", float(max(grid))))
    if exp.catch_rate and exp.catch_intensity:
        asks.append(("catch_intensity", exp.catch_intensity))
    if exp.kind == "discrimination":
        asks.append(("reference", exp.reference))
    return [(key, float(x), derive_sample(base, exp, float(x))) for key, x in asks]


def check_levels(asks: list, info) -> None:
    """Refuse, before anything is written, a level the device cannot render (:func:`unrenderable`).

    Parameters
    ----------
    asks : list of (str, object, CatalogSample)
        :func:`levels_asked`.
    info : devices.base.DeviceInfo or dict

    Raises
    ------
    ValueError
        ``"[experiment] <key> = <value>: <why>; ..."``.
    """
    for key, value, sample in asks:
        why = unrenderable(sample, info)
        if why:
            shown = f"{value:g}" if isinstance(value, float) else repr(value)
            raise ValueError(f"[experiment] {key} = {shown}: {why}; choose levels the device can render")


def base_sample(catalog, exp: ExperimentConfig):
    """The catalog sample whose ``vary`` a discrimination or detection session varies."""
    return next(s for s in catalog if s.name == exp.sample)


def derive_sample(base, exp: ExperimentConfig, value: float | None):
    """``base`` with ``exp.vary`` set to ``value`` (physical units), named by :func:`level_name`.

    ``value`` None (or, for detection, <= 0: a catch trial without a click) gives the same wall without a
    transient.
    """
    if value is None or (exp.kind == "detection" and value <= 0):
        return replace(base, name=level_name(base.name, exp.vary, None), transient="none", params={},
                       library=None, library_ref=None, label=f"{base.label or base.name}, no transient")
    value = float(value)
    if exp.vary == "stiffness_N_m":
        s = replace(base, stiffness_N_m=value)
    else:
        s = replace(base, params={**base.params, exp.vary: value})
    return replace(s, name=level_name(base.name, exp.vary, value), label=f"{base.label or base.name}, "
                                                                          f"{exp.vary} {value:g}")


def adaptive_trial(exp: ExperimentConfig, number: int, staircase: str, value: float, seed: int,
                   subject: str) -> PlannedTrial:
    """An adaptive method's trial as a :class:`PlannedTrial`: the target interval is balanced in pairs of
    trials (a seeded random permutation of (1, 2) for trials 2j - 1 and 2j), the samples derived from
    ``exp.sample`` at ``value`` (and the reference, or the wall without the click)."""
    pair = session_rng(seed, subject, PLAN_STREAM, 1000 + (number - 1) // 2)
    target = int(pair.permutation([1, 2])[(number - 1) % 2])
    shown = level_name(exp.sample, exp.vary, value if (exp.kind != "detection" or value > 0) else None)
    other = level_name(exp.sample, exp.vary, exp.reference if exp.kind == "discrimination" else None)
    return PlannedTrial(number, exp.sample, float(value), target, (shown, other) if target == 1 else (other, shown),
                        staircase)


# -- the trial plan -----------------------------------------------------------

@dataclass(frozen=True)
class PlannedTrial:
    """One 2-interval trial of a constant-stimuli plan.

    Attributes
    ----------
    trial : int
        1-based position in the session.
    condition : str
        Rendering name (real-virtual-2afc) or the varied sample's name.
    intensity_physical : float
        The comparison's / transient's value (physical units; 1.0, the rendering's gain, for real-virtual).
    target_interval : int
        1 or 2: the interval with the real sample, the comparison, or the click.
    samples : tuple of str
        The catalog names presented in interval 1 and 2.
    staircase : str
        The adaptive method's staircase label ("" for constant stimuli).
    """

    trial: int
    condition: str
    intensity_physical: float
    target_interval: int
    samples: tuple
    staircase: str = ""


#: the forced-choice plans' word in the session's seeds (:mod:`study.session.rng`), after which comes the purpose
#: (1 the constant-stimuli plan, 2 the staircases' seed, 1000 + k the target intervals of adaptive trials 2k+1,
#: 2k+2); part of the recorded sessions' meaning (a resumed session replans from it), never changed
PLAN_STREAM = 34


def plan_trials(exp: ExperimentConfig, seed: int, subject: str) -> list[PlannedTrial]:
    """The constant-stimuli plan: every level (or rendering) ``trials_per_level`` times, target interval
    balanced within each (half in interval 1, half in 2; an odd one out drawn at random), in random order.

    Every random choice comes from ``session_rng(seed, subject, PLAN_STREAM, purpose)`` (:mod:`study.session.rng`), so
    the same seed and subject give the same plan (a resumed session replans it exactly).

    Returns
    -------
    list of PlannedTrial
    """
    rng = session_rng(seed, subject, PLAN_STREAM, 1)
    if exp.kind == "real-virtual-2afc":
        cells = [(name, 1.0, exp.real_sample, name) for name in exp.renderings]
    elif exp.kind == "discrimination":
        ref = level_name(exp.sample, exp.vary, exp.reference)
        cells = [(exp.sample, x, level_name(exp.sample, exp.vary, x), ref) for x in exp.levels]
    else:
        blank = level_name(exp.sample, exp.vary, None)
        cells = [(exp.sample, x, level_name(exp.sample, exp.vary, x), blank) for x in exp.levels]
    items = []
    n = exp.trials_per_level
    for condition, x, target, other in cells:
        targets = [1] * (n // 2) + [2] * (n // 2)
        if n % 2:
            targets.append(int(rng.integers(1, 3)))
        for t in targets:
            items.append((condition, x, t, (target, other) if t == 1 else (other, target)))
    order = rng.permutation(len(items))
    return [PlannedTrial(k + 1, *items[i]) for k, i in enumerate(order)]


def handler_seed(seed: int, subject: str) -> int:
    """The staircases' seed (interleaving order, catch draws) from the session's seed and subject id."""
    return int(seed_sequence(seed, subject, PLAN_STREAM, 2).generate_state(1)[0] & 0x7FFFFFFF)


def intensity_of(exp: ExperimentConfig, physical: float) -> float:
    """trials.csv's ``intensity``: the physical value, or its log10 when ``intensity_scale = "log10"``; a catch
    trial's blank (0) has no log10 and gets none (NaN, written as an empty cell: a 0 would read as 1 unit)."""
    if exp.intensity_scale == "log10":
        return math.log10(physical) if physical > 0 else math.nan
    return float(physical)
