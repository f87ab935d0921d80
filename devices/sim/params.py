"""Parameters of the simulated device, loaded from TOML/JSON and validated at the boundary.

A parameter file has a top-level ``model`` ("nonlinear" or "lti"), a ``name``
and the sections ``device``, ``amplifier``, ``simulation``, ``user``,
``sensors`` plus ``mechanics`` (nonlinear model, thesis Table 3.1) or ``lti``
(Phantom-like LTI model, section 3.4.4). Every key of the schema below is
required; a missing, unknown, mistyped or non-physical value raises one
``ValueError`` naming the key and the file. See ``docs/sim.md``.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass, fields
from pathlib import Path
from types import MappingProxyType

from ..base import DeviceInfo
from plumbing.validation import is_finite_number, shown_value

_HERE = Path(__file__).parent
DEFAULT_PARAMS_FILE = _HERE / "default_params.toml"
LTI_PARAMS_FILE = _HERE / "phantom_lti.toml"

# constraint codes: "pos" > 0, "nonneg" >= 0, "neg" < 0, "any" finite, "int_pos" integer > 0,
# "bool", "str:<a>|<b>" one of the listed strings, "pairs" list of [f_zero_hz, zeta_zero, f_pole_hz, zeta_pole]
SCHEMA: dict[str, dict[str, str]] = {
    "device": {
        "encoder_lines": "int_pos",
        "gear_ratio": "pos",
        "handle_length_m": "pos",
        "torque_constant_Nm_A": "pos",
        "current_continuous_A": "pos",
        "current_peak_A": "pos",
        "current_amplifier_A": "pos",
        "servo_rate_hz": "pos",
        "winding_resistance_ohm": "pos",
        "thermal_resistance_K_W": "pos",
        "thermal_time_constant_s": "pos",
        "winding_max_temp_rise_K": "pos",
    },
    "amplifier": {
        "kind": "str:ideal|lowpass",
        "bandwidth_hz": "pos",
    },
    "simulation": {
        "max_step_s": "pos",
        "stick_velocity_m_s": "pos",
    },
    "user": {
        "k_u_N_m": "nonneg",
        "b_u_Ns_m": "nonneg",
        "nominal_grip_N": "pos",
    },
    "sensors": {
        "accel_bandwidth_hz": "pos",
        "accel_resolution_m_s2": "pos",
        "accel_noise_m_s2": "nonneg",
        "accel_range_m_s2": "pos",
        "grip_resolution_N": "pos",
        "grip_max_N": "pos",
    },
    "mechanics": {
        "m_m_kg": "pos",
        "b_m_Ns_m": "nonneg",
        "c_m_N": "nonneg",
        "k_c_N_m": "pos",
        "b_c_Ns_m": "nonneg",
        "m_d_kg": "pos",
        "b_d_Ns_m": "nonneg",
        "c_d_N": "nonneg",
        "k_lp_N_m": "pos",
        "k_ln_N_m": "pos",
        "f_lp_N": "nonneg",
        "f_ln_N": "nonpos",
        "gamma_l_rad_m": "pos",
        "b_l_Ns_m": "nonneg",
        "m_h_kg": "pos",
        "hysteresis": "bool",
    },
    "lti": {
        "handle_mass_kg": "pos",
        "resonance_hz": "pos",
        "resonance_zeta": "pos",
        "pairs": "pairs",
        "rolloff_hz": "pos",
        "rolloff_zeta": "pos",
    },
}
MODEL_SECTIONS = {"nonlinear": ("device", "amplifier", "simulation", "user", "sensors", "mechanics"),
                  "lti": ("device", "amplifier", "simulation", "user", "sensors", "lti")}
MAX_STEP_LIMIT_S = 40e-6
# top-level keys a parameter file may carry as metadata (ignored here), e.g. the provenance of every
# parameter written by successive isolation (devices.identify.successive)
METADATA_KEYS = ("identification",)


@dataclass(frozen=True)
class SimParams:
    """Validated parameters of a simulated device (one file).

    Attributes
    ----------
    model : str
        ``"nonlinear"`` (thesis section 3.5.4, eq. 3.32-3.35) or ``"lti"``
        (Phantom-like linear model, section 3.4.4).
    name : str
        Device name reported in :class:`DeviceInfo`.
    device, amplifier, simulation, user, sensors : mapping
        Sections of the file (read-only mappings, keys as in ``SCHEMA``, SI
        units in the key names).
    mechanics : mapping or None
        Table 3.1 parameters in handle space (nonlinear model only).
    lti : mapping or None
        Phantom-like LTI parameters (lti model only).
    source : str
        File the parameters came from (for error messages).
    """

    model: str
    name: str
    device: MappingProxyType
    amplifier: MappingProxyType
    simulation: MappingProxyType
    user: MappingProxyType
    sensors: MappingProxyType
    mechanics: MappingProxyType | None = None
    lti: MappingProxyType | None = None
    source: str = "<defaults>"

    def device_info(self) -> DeviceInfo:
        """The :class:`DeviceInfo` this parameter set describes (simulated=True)."""
        d = self.device
        return DeviceInfo(
            name=self.name,
            encoder_lines=int(d["encoder_lines"]),
            gear_ratio=d["gear_ratio"],
            handle_length_m=d["handle_length_m"],
            torque_constant_Nm_A=d["torque_constant_Nm_A"],
            current_continuous_A=d["current_continuous_A"],
            current_peak_A=d["current_peak_A"],
            current_amplifier_A=d["current_amplifier_A"],
            servo_rate_hz=d["servo_rate_hz"],
            winding_resistance_ohm=d["winding_resistance_ohm"],
            thermal_resistance_K_W=d["thermal_resistance_K_W"],
            thermal_time_constant_s=d["thermal_time_constant_s"],
            winding_max_temp_rise_K=d["winding_max_temp_rise_K"],
            accel_range_m_s2=self.sensors["accel_range_m_s2"],
            grip_range_N=(0.0, self.sensors["grip_max_N"]),
            capabilities=("streaming", "simulated", self.model),
            simulated=True,
        )

    def replace(self, **changes) -> "SimParams":
        """Copy with whole sections or single keys changed, re-validated.

        ``changes`` maps a section name to a dict of key overrides (merged into
        that section), or ``model``/``name`` to a new value, e.g.
        ``p.replace(mechanics={"c_m_N": 0.0, "c_d_N": 0.0, "hysteresis": False})``.
        """
        data = self.to_dict()
        for key, value in changes.items():
            if isinstance(value, dict):
                data.setdefault(key, {}).update(value)
            else:
                data[key] = value
        return params_from_dict(data, source=f"{self.source} (modified)")

    def __reduce__(self):
        # pickled as its file form and validated again when loaded (a read-only section cannot be pickled
        # itself): a parameter set crosses to another process as the same parameters
        return params_from_dict, (self.to_dict(), self.source)

    def to_dict(self) -> dict:
        """Plain nested dict (the file format)."""
        out: dict = {"model": self.model, "name": self.name}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, MappingProxyType):
                out[f.name] = {k: (list(map(list, v)) if k == "pairs" else v) for k, v in value.items()}
        return out


def _check_value(value, rule: str, key: str, where: str):
    """Validate one value against its schema rule; return the normalized value."""
    def fail(why: str):
        raise ValueError(f"{where}: key {key!r} {why}, got {shown_value(value):.200}")

    if rule == "bool":
        if not isinstance(value, bool):
            fail("must be true or false")
        return value
    if rule.startswith("str:"):
        options = rule[4:].split("|")
        if value not in options:
            fail(f"must be one of {options}")
        return value
    if rule == "pairs":
        if not isinstance(value, list):
            fail("must be a list of [f_zero_hz, zeta_zero, f_pole_hz, zeta_pole]")
        pairs = []
        for item in value:
            if not (isinstance(item, list) and len(item) == 4):
                fail("must be a list of [f_zero_hz, zeta_zero, f_pole_hz, zeta_pole]")
            for x in item:
                if not is_finite_number(x) or x <= 0:
                    fail("entries must be positive finite numbers")
            pairs.append(tuple(float(x) for x in item))
        return tuple(pairs)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        fail("must be a number")
    if not is_finite_number(value):
        fail("must be finite")
    if rule == "int_pos":
        if int(value) != value or value <= 0:
            fail("must be a positive integer")
        return int(value)
    value = float(value)
    if rule == "pos" and not value > 0:
        fail("must be > 0")
    if rule == "nonneg" and not value >= 0:
        fail("must be >= 0")
    if rule == "nonpos" and not value <= 0:
        fail("must be <= 0")
    return value


def params_from_dict(data: dict, source: str = "<dict>") -> SimParams:
    """Validate a nested parameter dict (the file format) into :class:`SimParams`.

    Raises
    ------
    ValueError
        Naming ``source`` and the first offending key (``section.key``).
    """
    if not isinstance(data, dict):
        raise ValueError(f"{source}: parameter file must be a table/object at top level")
    model = data.get("model")
    if model not in MODEL_SECTIONS:
        raise ValueError(f"{source}: key 'model' must be one of {sorted(MODEL_SECTIONS)}, got {model!r}")
    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise ValueError(f"{source}: key 'name' must be a non-empty string, got {name!r}")
    wanted = MODEL_SECTIONS[model]
    for key in data:
        if key not in ("model", "name") and key not in wanted and key not in METADATA_KEYS:
            raise ValueError(f"{source}: unknown key {key!r} for model {model!r} "
                             f"(valid sections: {', '.join(wanted)})")
    sections = {}
    for sec in wanted:
        raw = data.get(sec)
        if raw is None:
            raise ValueError(f"{source}: missing section {sec!r}")
        if not isinstance(raw, dict):
            raise ValueError(f"{source}: key {sec!r} must be a section/table")
        for key in raw:
            if key not in SCHEMA[sec]:
                raise ValueError(f"{source}: unknown key '{sec}.{key}' (valid: {', '.join(SCHEMA[sec])})")
        values = {}
        for key, rule in SCHEMA[sec].items():
            if key not in raw:
                raise ValueError(f"{source}: missing key '{sec}.{key}'")
            values[key] = _check_value(raw[key], rule, f"{sec}.{key}", source)
        sections[sec] = MappingProxyType(values)
    _check_relations(sections, source)
    return SimParams(model=model, name=name, source=source, **sections)


def _check_relations(s: dict, source: str) -> None:
    """Cross-key physical constraints."""
    d = s["device"]
    if not d["current_continuous_A"] <= d["current_peak_A"] <= d["current_amplifier_A"]:
        raise ValueError(f"{source}: keys 'device.current_continuous_A' <= 'device.current_peak_A' <= "
                         f"'device.current_amplifier_A' must hold")
    if s["simulation"]["max_step_s"] > MAX_STEP_LIMIT_S:
        raise ValueError(f"{source}: key 'simulation.max_step_s' must be <= {MAX_STEP_LIMIT_S} s, "
                         f"got {s['simulation']['max_step_s']!r}")
    if s["amplifier"]["kind"] == "lowpass" and s["amplifier"]["bandwidth_hz"] * 2 * math.pi * s["simulation"]["max_step_s"] > 1:
        raise ValueError(f"{source}: key 'amplifier.bandwidth_hz' too high for 'simulation.max_step_s'")
    if "mechanics" in s and s["mechanics"]["f_ln_N"] >= s["mechanics"]["f_lp_N"] and s["mechanics"]["hysteresis"]:
        raise ValueError(f"{source}: key 'mechanics.f_ln_N' must be < 'mechanics.f_lp_N'")


def load_sim_params(path=None) -> SimParams:
    """Load and validate a TOML (``.toml``) or JSON (``.json``) parameter file.

    Parameters
    ----------
    path : str or Path or None
        File; None gives the Table 3.1 defaults (``default_params.toml``).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        For an unreadable file or a missing/unknown/non-physical key (the
        message names the file and the key).
    """
    path = Path(DEFAULT_PARAMS_FILE if path is None else path)
    if not path.is_file():
        raise FileNotFoundError(f"sim parameter file not found: {path}")
    suffix = path.suffix.lower()
    try:
        if suffix == ".toml":
            with open(path, "rb") as fh:
                data = tomllib.load(fh)
        elif suffix == ".json":
            with open(path, encoding="utf-8") as fh:
                data = json.load(fh)
        else:
            raise ValueError(f"{path}: parameter file must end in .toml or .json")
    except (tomllib.TOMLDecodeError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot parse parameter file: {exc}") from None
    return params_from_dict(data, source=str(path))


_cache: dict[str, SimParams] = {}


def default_params(model: str = "nonlinear") -> SimParams:
    """Table 3.1 defaults (``"nonlinear"``) or the Phantom-like LTI defaults (``"lti"``), cached."""
    if model not in _cache:
        _cache[model] = load_sim_params(DEFAULT_PARAMS_FILE if model == "nonlinear" else LTI_PARAMS_FILE)
    return _cache[model]
