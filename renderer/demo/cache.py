"""The demo's offline HFAM pipeline (thesis Figure 4.7), cached in a user cache folder.

Three long steps, each through the owning package's Python API:

1. identify the sim device at several grip levels (swept sine, ETFE, automatic
   LTI fit: :func:`devices.identify.pipeline.identify_device`), giving a
   grip-dependent model set of commanded current -> handle acceleration;
2. record real taps on the simulated ``wood_on_foam`` sample over a range of
   incoming velocities with the motor off (:func:`devices.recording.record_taps`,
   written in the ``python -m devices record`` CSV format);
3. build the HFAM current library from those recordings and the per-grip
   models (:func:`stimuli.hfam.build_library`).

The results live in ``<cache base>/demo-<key>/`` where ``key`` hashes every
parameter of the three steps *and* the source code of the modules that
compute them, so a changed parameter or a changed algorithm never reuses a
stale library. ``<cache base>`` is ``--cache-dir`` or
``$XDG_CACHE_HOME/hfam-haptics`` (``~/.cache/hfam-haptics``). A cache entry
is written into a temporary folder and renamed when complete, so an
interrupted run never leaves a half-built entry behind.

The figures that depend only on an entry (the library, Figure 4.8, and the identification's Bode
plot) are kept beside it in ``figures-<key>/`` once drawn, where ``key`` hashes the drawing code, the
project style and the matplotlib version; a cached run copies them (checked against their SHA-256)
instead of drawing them again.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import json
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from devices.identify.modelset import load_model_set
from plumbing.outdir import output_folder
from devices.registry import make_device
from plumbing.fileio import user_cache_dir
from stimuli import HfamLibrary
from stimuli.hfam.pipeline import PipelineSettings, Progress, build_pipeline
from stimuli.hfam.scoring import (ScoreSettings, device_linkage, hfam_claims, hfam_claims_not_measured,
                                  pipeline_libraries, score_pipeline)
from stimuli.recordings import read_tap_csv

from .fidelity import claims_from_dicts

#: modules whose code determines the cached results (hashed into the cache key)
_CODE_PATHS = ("devices/sim", "devices/identify", "devices/model.py", "devices/recording.py",
               "stimuli/hfam", "stimuli/library.py", "stimuli/recordings.py", "renderer/demo/cache.py")
CACHE_VERSION = 1
#: code and style that draw an entry's own figures (hashed into the name of their cached copies)
_FIGURE_CODE_PATHS = ("renderer/demo/figures.py", "stimuli/cli_show.py", "devices/identify/figures.py", "figstyle")
#: an entry's own figures: name in the demo's results -> file stem (PNG, SVG and .plot.csv each)
PIPELINE_FIGURES = {"library": "fig_library", "bode": "fig_bode"}
_FIGURE_SUFFIXES = (".png", ".svg", ".plot.csv")


@dataclass
class Pipeline:
    """The cached products of :func:`build_or_load`.

    Attributes
    ----------
    directory : Path
        The cache entry.
    model_set : devices.identify.modelset.ModelSet
        Identified current -> acceleration (and motor position) models per grip.
    library : stimuli.HfamLibrary
    fs_hz : float
    taps : list of stimuli.recordings.Tap
        The recorded real taps (t relative to impact).
    from_cache : bool
    timings_s : dict
        Wall time of each step when it was built.
    """

    directory: Path
    model_set: object
    library: object
    fs_hz: float
    taps: list
    from_cache: bool
    timings_s: dict

    @property
    def etfe_npz(self) -> Path:
        """The identification's acceleration ETFEs (``identify/etfe_accel.npz``)."""
        return self.directory / "identify" / "etfe_accel.npz"

    @property
    def recordings_csv(self) -> Path:
        """The real-sample tap recordings the library was built from."""
        return self.directory / "recordings.csv"

    @property
    def library_npz(self) -> Path:
        """The HFAM library file."""
        return self.directory / "library.npz"


@functools.lru_cache(maxsize=4)
def code_digest(root: Path | None = None, paths: tuple[str, ...] = _CODE_PATHS) -> str:
    """SHA-256 over the source files that compute the cached results (``paths``, default ``_CODE_PATHS``).

    Computed once per process: the code a process runs is the code it imported.
    """
    root = Path(__file__).resolve().parents[2] if root is None else root
    h = hashlib.sha256()
    for rel in paths:
        p = root / rel
        files = sorted(p.rglob("*")) if p.is_dir() else [p]
        for f in files:
            if f.is_file() and f.suffix in (".py", ".toml", ".json", ".mplstyle"):
                h.update(str(f.relative_to(root)).encode())
                h.update(f.read_bytes())
    return h.hexdigest()


def cache_key(settings: PipelineSettings) -> str:
    """16-hex-digit key of the settings, the sim parameters and the code (see module doc)."""
    dev = make_device(settings.device)
    params = dev.params.to_dict() if hasattr(dev, "params") and hasattr(dev.params, "to_dict") else {}
    blob = json.dumps({"version": CACHE_VERSION, "settings": settings.to_dict(), "sim_params": params,
                       "code": code_digest()}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def build_or_load(settings: PipelineSettings, cache_base: Path | None = None, rebuild: bool = False,
                  progress: Progress | None = None) -> Pipeline:
    """Return the pipeline products, from the cache when present, else built (and cached).

    Parameters
    ----------
    settings : PipelineSettings
    cache_base : Path or None
        Cache folder (default :func:`plumbing.fileio.user_cache_dir`).
    rebuild : bool
        Ignore and replace an existing cache entry.
    progress : Progress or None
        Where the three steps report; None prints nothing.
    """
    progress = progress or Progress(3, quiet=True)
    base = Path(cache_base) if cache_base is not None else user_cache_dir()
    key = cache_key(settings)
    entry = base / f"demo-{key}"
    if not rebuild and (entry / "manifest.json").is_file():
        try:
            return _load(entry, settings)
        except (OSError, ValueError, KeyError) as exc:  # a damaged entry is rebuilt, not trusted
            progress.say(f"cache entry {entry} unusable ({exc}); rebuilding", indent=False)
    # built beside the entry and swapped in whole, one builder at a time (plumbing.outdir): a killed build
    # leaves no half entry, and its debris is removed by the next build
    with output_folder(entry, True, what="demo cache entry", command="demo cache", own=("*",)) as folder:
        tmp = folder.path
        timings = build_pipeline(tmp, settings, progress)
        manifest = {"key": key, "settings": settings.to_dict(), "timings_s": timings,
                    "created_unix": time.time(), "version": CACHE_VERSION}
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    pipe = _load(entry, settings)
    pipe.from_cache = False
    return pipe


def _load(entry: Path, settings: PipelineSettings) -> Pipeline:
    manifest = json.loads((entry / "manifest.json").read_text())
    if manifest.get("settings") != settings.to_dict():
        raise ValueError("settings in manifest.json differ from the requested ones")
    mset = load_model_set(entry / "identify")
    lib = HfamLibrary.load(entry / "library.npz")
    _, taps = read_tap_csv(entry / "recordings.csv")
    return Pipeline(entry, mset, lib, lib.fs_hz, taps, True, manifest.get("timings_s", {}))


def figure_folder(pipe: Pipeline) -> Path:
    """Where the entry's own figures drawn by the current code, style and matplotlib are kept."""
    blob = code_digest(paths=_FIGURE_CODE_PATHS) + importlib.metadata.version("matplotlib")
    return pipe.directory / f"figures-{hashlib.sha256(blob.encode()).hexdigest()[:16]}"


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def restore_figures(pipe: Pipeline, out: Path) -> dict | None:
    """Copy the entry's kept figures into ``out``; None if they are not kept (or damaged: redraw them).

    Returns
    -------
    dict or None
        ``PIPELINE_FIGURES`` name -> PNG written into ``out``.
    """
    folder = figure_folder(pipe)
    try:
        sums = json.loads((folder / "sha256.json").read_text())
        names = [stem + suf for stem in PIPELINE_FIGURES.values() for suf in _FIGURE_SUFFIXES]
        if sorted(sums) != sorted(names) or any(_sha256(folder / n) != sums[n] for n in names):
            return None
    except (OSError, ValueError):
        return None
    out = Path(out)
    for n in names:
        # under a temporary name and renamed, like figstyle.save: never half a figure in ``out``
        tmp = out / f".{n}.tmp"
        shutil.copyfile(folder / n, tmp)
        os.replace(tmp, out / n)
    return {k: out / f"{stem}.png" for k, stem in PIPELINE_FIGURES.items()}


def keep_figures(pipe: Pipeline, out: Path) -> bool:
    """Keep the entry's own figures just drawn into ``out`` for later runs (best effort: a read-only or
    full cache only means they are drawn again). Returns whether they were kept."""
    folder = figure_folder(pipe)
    if folder.is_dir():
        return True
    tmp = None
    try:
        tmp = Path(tempfile.mkdtemp(prefix=".figures-", dir=pipe.directory))
        sums = {}
        for stem in PIPELINE_FIGURES.values():
            for suf in _FIGURE_SUFFIXES:
                shutil.copyfile(Path(out) / (stem + suf), tmp / (stem + suf))
                sums[stem + suf] = _sha256(tmp / (stem + suf))
        (tmp / "sha256.json").write_text(json.dumps(sums, indent=1, sort_keys=True) + "\n")
        os.replace(tmp, folder)
        return True
    except OSError:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        return False


#: the HFAM accuracy claims of an entry, computed once: the scoring code and the sim are in the key
HFAM_CLAIMS_FILE = "hfam_claims.json"


def hfam_score_settings(settings: PipelineSettings) -> ScoreSettings | None:
    """How the demo's HFAM claims are scored for its pipeline ``settings``, or None if they cannot be.

    The scoring plays its taps on the default sim or its linear-linkage variant
    (:func:`stimuli.hfam.scoring.device_linkage`): a demo on ``sim``, or on ``sim:<params file>`` holding one of
    those two devices, is scored on that device, with the demo's tap stop time (``--tap-stop-time``). Any other
    device (``sim:lti``, other parameters) is None: its claims are "not measured", never scored on another device.
    """
    linkage = device_linkage(settings.device)
    if linkage is None:
        return None
    return ScoreSettings(linkage=linkage, stop_time_s=settings.tap_stop_time_s)


def entry_hfam_claims(pipe: Pipeline, settings: PipelineSettings) -> list[dict]:
    """The HFAM claims of fidelity.csv for the entry's libraries (:func:`stimuli.hfam.scoring.hfam_claims`).

    Scoring the open-loop, refined (at unseen conditions, two persons) and raised-limit libraries taps
    ~100 cells (10-20 s); the result depends only on what the entry's key hashes (the pipeline settings,
    the sim and ``stimuli/hfam``, scoring included), so it is kept in the entry (best effort, as the
    figures) and read back on later runs. A kept file that does not parse or whose rows are not claims
    (:func:`renderer.demo.fidelity.claims_from_dicts`) is recomputed and replaced. On a device the scoring
    cannot play (:func:`hfam_score_settings`) the claims are "not measured" (NaN, not holding, the reason).
    """
    score_settings = hfam_score_settings(settings)
    if score_settings is None:
        return hfam_claims_not_measured(
            f"the HFAM scoring plays its taps on the default sim (Table 3.1) or its linear-linkage variant, and this "
            f"demo ran on {settings.device}; scoring on another device would not be this demo's library")
    path = pipe.directory / HFAM_CLAIMS_FILE
    try:
        rows = json.loads(path.read_text())
        if isinstance(rows, list) and rows:
            claims_from_dicts(rows)     # every row a claim, or ValueError: recomputed below
            return rows
    except (OSError, ValueError):
        pass
    open_loop, refined, raised, models = pipeline_libraries(pipe.directory, settings)
    rows = hfam_claims(score_pipeline(open_loop, refined, raised, models, settings=score_settings))
    try:
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(rows, indent=1, allow_nan=True) + "\n")
        os.replace(tmp, path)
    except OSError:
        pass
    return rows
