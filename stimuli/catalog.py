"""The sample catalog: real and virtual test samples (thesis Table 4.1) loaded from TOML.

The default catalog ``stimuli/catalog.toml`` lists the twelve samples of
Table 4.1. A user catalog has the same format; with ``include_default = true``
at its top it extends the default one (a new material, stiffness or library).
"""

from __future__ import annotations

import math
import tomllib
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from plumbing.fileio import read_text_utf8

from .library import HfamLibrary
from .transients import DecayingSinusoid, NoTransient, Pulse

DEFAULT_CATALOG = Path(__file__).with_name("catalog.toml")
KINDS = ("real", "virtual")
TRANSIENTS = ("none", "pulse", "sinusoid", "hfam")
COMMON_KEYS = {"name", "label", "kind", "stiffness_N_m", "transient", "real_sample", "library"}
PARAM_KEYS = {
    "none": set(),
    "pulse": {"amplitude_Ns_m", "duration_s", "gain"},
    "sinusoid": {"amplitude_Ns_m", "duration_s", "frequency_hz", "gain"},
    "hfam": {"gain", "max_extrapolation"},
}
TOP_KEYS = {"sample", "include_default"}


@dataclass(frozen=True)
class CatalogSample:
    """One test sample.

    Attributes
    ----------
    name : str
        Unique identifier (used in trial files).
    kind : str
        ``"real"`` (a physical sample, motor off) or ``"virtual"``.
    stiffness_N_m : float
        Proportional wall stiffness (virtual) or approximate measured stiffness (real).
    transient : str
        ``"none" | "pulse" | "sinusoid" | "hfam"``.
    library : Path or None
        Resolved HFAM library file (hfam only).
    real_sample : str or None
        Sim sample name for real samples (``devices.sim.SAMPLES``).
    params : dict
        Transient parameters (amplitude_Ns_m, duration_s, frequency_hz, gain, max_extrapolation).
    label : str
        Human-readable name.
    library_ref : str or None
        The library path as written in the catalog (relative paths are
        resolved against the catalog's directory or ``library_dir``).
    """

    name: str
    kind: str
    stiffness_N_m: float
    transient: str
    library: Path | None = None
    real_sample: str | None = None
    params: dict = field(default_factory=dict)
    label: str = ""
    library_ref: str | None = None

    def make_transient(self, library_dir=None):
        """The transient object for this sample (Pulse, DecayingSinusoid, HfamLibrary or NoTransient).

        Parameters
        ----------
        library_dir : path or None
            Directory to resolve a relative library path against instead of the
            catalog's own directory.
        """
        p = dict(self.params)
        if self.transient == "pulse":
            return Pulse(**p)
        if self.transient == "sinusoid":
            with warnings.catch_warnings():  # Table 4.1's 55 ms is 6.05 half periods of 55 Hz: within tolerance
                warnings.simplefilter("default")
                return DecayingSinusoid(**p)
        if self.transient == "hfam":
            path = self.library
            if library_dir is not None and self.library_ref is not None and not Path(self.library_ref).is_absolute():
                path = Path(library_dir) / self.library_ref
            if path is None or not Path(path).is_file():
                raise FileNotFoundError(f"sample {self.name!r}: HFAM library {path} does not exist")
            return HfamLibrary.load(path, gain=p.get("gain"), max_extrapolation=p.get("max_extrapolation"))
        return NoTransient()


def _number(where: str, key: str, value, positive: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: key {key!r} must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value) or (positive and value <= 0):
        raise ValueError(f"{where}: key {key!r} must be a positive finite number, got {value!r}")
    return value


def _parse_sample(entry, where: str, base_dir: Path, library_dir: Path | None) -> CatalogSample:
    if not isinstance(entry, dict):
        raise ValueError(f"{where}: must be a table")
    for key in ("name", "kind", "stiffness_N_m", "transient"):
        if key not in entry:
            raise ValueError(f"{where}: missing key {key!r}")
    name = entry["name"]
    if not isinstance(name, str) or not name:
        raise ValueError(f"{where}: key 'name' must be a non-empty string")
    where = f"{where} ({name!r})"
    kind, transient = entry["kind"], entry["transient"]
    if kind not in KINDS:
        raise ValueError(f"{where}: key 'kind' must be one of {KINDS}, got {kind!r}")
    if transient not in TRANSIENTS:
        raise ValueError(f"{where}: key 'transient' must be one of {TRANSIENTS}, got {transient!r}")
    allowed = COMMON_KEYS | PARAM_KEYS[transient]
    unknown = sorted(set(entry) - allowed)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown} for transient {transient!r} "
                         f"(allowed: {sorted(allowed)})")
    stiffness = _number(where, "stiffness_N_m", entry["stiffness_N_m"])
    real_sample = entry.get("real_sample")
    if kind == "real":
        if not isinstance(real_sample, str) or not real_sample:
            raise ValueError(f"{where}: a real sample needs key 'real_sample' (the sim sample name)")
        if transient != "none":
            raise ValueError(f"{where}: a real sample has transient 'none', got {transient!r}")
    elif real_sample is not None:
        raise ValueError(f"{where}: key 'real_sample' is only for kind 'real'")
    params = {k: _number(where, k, entry[k], positive=(k != "gain")) for k in PARAM_KEYS[transient] if k in entry}
    if "gain" in params and params["gain"] < 0:
        raise ValueError(f"{where}: key 'gain' must be >= 0")
    library = library_ref = None
    if transient == "hfam":
        library_ref = entry.get("library")
        if not isinstance(library_ref, str) or not library_ref:
            raise ValueError(f"{where}: an hfam sample needs key 'library' (path to the .npz library)")
        path = Path(library_ref)
        if not path.is_absolute():
            path = (library_dir if library_dir is not None else base_dir) / path
        if not path.is_file():
            raise FileNotFoundError(f"{where}: key 'library': HFAM library {path} does not exist")
        library = path
    elif "library" in entry:
        raise ValueError(f"{where}: key 'library' is only for transient 'hfam'")
    if transient in ("pulse", "sinusoid"):  # construct once so bad parameters fail at load time
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                (Pulse if transient == "pulse" else DecayingSinusoid)(**params)
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
    return CatalogSample(name, kind, stiffness, transient, library, real_sample, params,
                         str(entry.get("label") or name), library_ref)


def load_catalog(path=None, library_dir=None) -> list[CatalogSample]:
    """Load and validate a sample catalog (default: the 12 samples of Table 4.1).

    Parameters
    ----------
    path : path or None
        Catalog TOML; None for ``stimuli/catalog.toml``.
    library_dir : path or None
        Directory for relative HFAM library paths (default: the catalog file's directory).

    Returns
    -------
    list of CatalogSample
        In file order (default samples first when ``include_default = true``).

    Raises
    ------
    FileNotFoundError
        The catalog or a referenced library file does not exist (named).
    ValueError
        TOML syntax errors, unknown or missing keys, bad values, duplicate
        names; messages name the file, the sample index and the key.
    """
    path = DEFAULT_CATALOG if path is None else Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"catalog file not found: {path}")
    text = read_text_utf8(path, "catalog")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: invalid TOML ({exc})") from None
    except RecursionError:   # nested 10^5 deep: one line, not a traceback
        raise ValueError(f"{path}: invalid TOML (nested too deeply)") from None
    unknown = sorted(set(data) - TOP_KEYS)
    if unknown:
        raise ValueError(f"{path}: unknown top-level key(s) {unknown} (allowed: {sorted(TOP_KEYS)})")
    include = data.get("include_default", False)
    if not isinstance(include, bool):
        raise ValueError(f"{path}: key 'include_default' must be true or false")
    entries = data.get("sample", [])
    if not isinstance(entries, list):
        raise ValueError(f"{path}: 'sample' must be an array of tables ([[sample]])")
    samples = []
    if include and path.resolve() != DEFAULT_CATALOG.resolve():
        samples = load_catalog(None)
    lib_dir = Path(library_dir) if library_dir is not None else None
    for i, entry in enumerate(entries):
        samples.append(_parse_sample(entry, f"{path}: sample[{i}]", path.parent, lib_dir))
    seen = set()
    for s in samples:
        if s.name in seen:
            raise ValueError(f"{path}: duplicate sample name {s.name!r}")
        seen.add(s.name)
    if not samples:
        raise ValueError(f"{path}: no samples")
    return samples
