"""Successive isolation (thesis sec. 3.5, Figure 3.13): the stages in order, each in its mechanical
configuration, each fitting only the outermost parameters on the model built up so far; resumable state,
the model file (a sim parameter file with every parameter's stage, residual and unit) and the report."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

from plumbing.fileio import atomic_write_text

from ...base import Device
from ...registry import make_device
from ...sim.params import SimParams, load_sim_params
from .amplifier import identify_amplifier
from .bench import Bench
from .cables import identify_cables
from .common import UNITS, ModelBuilder, StageResult, base_params_dict
from .drum import identify_drum
from .figures import stage_figures
from .handle import identify_handle
from .linkage import identify_linkage
from .motor import identify_motor
from .timing import identify_timing
from .user import identify_user

# (name, function, configuration) in the order of the dynamic chain, away from the amplifier
STAGES = (("timing", identify_timing), ("amplifier", identify_amplifier), ("motor", identify_motor),
          ("cables", identify_cables), ("drum", identify_drum), ("linkage", identify_linkage),
          ("handle", identify_handle), ("user", identify_user))
STAGE_NAMES = tuple(n for n, _ in STAGES)
STATE_FILE = "successive_state.json"
MODEL_FILE = "model.json"


@dataclass
class SuccessiveResult:
    """Result of :func:`identify_successive`.

    Attributes
    ----------
    params : SimParams
        The identified nonlinear model (loadable by ``SimDevice``; ``sim:<model file>``).
    stages : list of StageResult
    device : str
    elapsed_s : float
    ticks : int
        Servo ticks played on the device.
    """

    params: SimParams
    stages: list
    device: str = ""
    elapsed_s: float = 0.0
    ticks: int = 0
    extra: dict = field(default_factory=dict)

    def provenance(self) -> dict:
        """``"section.key" -> {"value", "unit", "stage", "residual"}`` for every identified parameter."""
        out = {}
        for st in self.stages:
            for key, value in st.values.items():
                out[key] = {"value": value, "unit": UNITS.get(key, ""), "stage": st.stage,
                            "config": st.config, "residual": st.residuals.get(key)}
        return out

    def model_dict(self) -> dict:
        """The model file's content: the sim parameter file plus ``identification`` metadata."""
        d = self.params.to_dict()
        d["identification"] = {"method": "successive isolation (thesis sec. 3.5)", "device": self.device,
                               "parameters": self.provenance(),
                               "stages": [s.to_json() for s in self.stages], "elapsed_s": self.elapsed_s}
        return d


def _open_device(device_spec_or_factory, seed: int):
    if isinstance(device_spec_or_factory, Device):
        return device_spec_or_factory, getattr(device_spec_or_factory.info, "name", "device"), False
    if callable(device_spec_or_factory):
        dev = device_spec_or_factory()
        return dev, dev.info.name, True

    spec = str(device_spec_or_factory)
    dev = make_device(spec, seed=seed) if spec.startswith("sim") else make_device(spec)
    return dev, spec, True


def identify_successive(device_spec_or_factory="sim", stages=STAGE_NAMES, state_dir=None, resume: bool = False,
                        log=print, prompt=None, seed: int = 0, config_override: dict | None = None,
                        name: str = "successive-isolation", hand=None) -> SuccessiveResult:
    """Identify the nonlinear model of eq. 3.32-3.35 stage by stage (thesis sec. 3.5).

    Parameters
    ----------
    device_spec_or_factory : str, Device or callable
        Device string (``sim``, ``sim:<file>``, ``serial:...``), an open :class:`Device`, or a factory
        returning a new device (opened and closed here).
    stages : sequence of str
        Stages to run, in order (default all of ``STAGE_NAMES``); a stage needs the ones before it
        (their values come from ``state_dir`` when resuming).
    state_dir : path or None
        Where the per-stage state (``successive_state.json``) is written after every stage.
    resume : bool
        Skip the stages already in ``state_dir``'s state (hardware: continue after an interruption).
    log, prompt : callable
        Progress output; operator prompts on hardware (default ``input``).
    seed : int
        Noise seed of a simulated device made from a device string.
    config_override : dict or None
        Tests: mechanical configuration actually used for a requested one (an operator's mistake).
    hand : object or None
        Simulated device: the person holding it (None: the sim's default person).

    Returns
    -------
    SuccessiveResult

    Raises
    ------
    StageError (ValueError)
        Naming the stage and the implausible measurement.
    """
    t0 = time.perf_counter()
    unknown = [s for s in stages if s not in STAGE_NAMES]
    if unknown:
        raise ValueError(f"unknown stage(s) {unknown}; valid: {', '.join(STAGE_NAMES)}")
    dev, label, owned = _open_device(device_spec_or_factory, seed)
    done: list[StageResult] = []
    state_path = Path(state_dir) / STATE_FILE if state_dir is not None else None
    if resume and state_path is not None and state_path.is_file():
        for d in json.loads(state_path.read_text())["stages"]:
            done.append(StageResult(d["stage"], d["config"], d["values"], d["residuals"], notes=d.get("notes", []),
                                    elapsed_s=d.get("elapsed_s", 0.0)))
        log(f"resuming: stages {', '.join(s.stage for s in done)} loaded from {state_path}")
    try:
        if owned:
            dev.open()
        builder = ModelBuilder(base_params_dict(dev.info, name=name))
        for st in done:
            _apply(builder, st)
        bench = Bench(dev, prompt=prompt, log=log, config_override=config_override, hand=hand)
        if "device.current_amplifier_A" in builder.values:
            bench.saturation_A = builder.values["device.current_amplifier_A"]
        have = {s.stage for s in done}
        order = [n for n in STAGE_NAMES if n in stages]
        for i, stage in enumerate(order):
            if stage in have:
                continue
            fn = dict(STAGES)[stage]
            log(f"[{i + 1}/{len(order)}] stage {stage} ...")
            res = fn(bench, builder)
            done.append(res)
            log(f"[{i + 1}/{len(order)}] stage {stage}: " + "; ".join(res.notes) + f" ({res.elapsed_s:.1f} s)")
            if state_path is not None:
                state_path.parent.mkdir(parents=True, exist_ok=True)
                atomic_write_text(state_path, json.dumps({"device": label, "stages": [s.to_json() for s in done]},
                                                         indent=1, default=float))
        dev.command(0.0)
        if bench.simulated:
            dev.set_mechanical_config("assembled")
    finally:
        if owned:
            dev.close()
    params = builder.params(noiseless=False)
    done.sort(key=lambda s: STAGE_NAMES.index(s.stage))
    return SuccessiveResult(params, done, label, time.perf_counter() - t0, bench.ticks)


def _apply(builder: ModelBuilder, st: StageResult) -> None:
    """Restore a finished stage's values into the built-up model (resume)."""
    builder.values.update(st.values)
    if st.stage == "amplifier":
        bw = st.values.get("amplifier.bandwidth_hz", 0.0)
        ideal = any("ideal" in n for n in st.notes)
        builder.base["amplifier"]["kind"] = "ideal" if ideal else "lowpass"
        if ideal:
            builder.values.pop("amplifier.bandwidth_hz", None)
        else:
            builder.values["amplifier.bandwidth_hz"] = bw


def save_result(result: SuccessiveResult, out_dir, overwrite: bool = False, figures: bool = True) -> Path:
    """Write ``model.json`` (loadable with ``load_sim_params`` / ``sim:<file>``), ``report.json``,
    ``report.txt`` and one figure per stage into ``out_dir``.

    Raises
    ------
    FileExistsError
        If ``out_dir`` already holds a model and ``overwrite`` is False (a user's results are never
        overwritten silently).
    """
    out = Path(out_dir)
    model = out / MODEL_FILE
    if model.exists() and not overwrite:
        raise FileExistsError(f"{out} already holds a model ({MODEL_FILE}); choose another folder or pass "
                              f"--force")
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(model, json.dumps(result.model_dict(), indent=2, default=float) + "\n")
    load_sim_params(model)  # the file must load as a sim device
    report = {"device": result.device, "elapsed_s": result.elapsed_s, "ticks": result.ticks,
              "parameters": result.provenance(), "stages": [s.to_json() for s in result.stages], **result.extra}
    atomic_write_text(out / "report.json", json.dumps(report, indent=2, default=float) + "\n")
    atomic_write_text(out / "report.txt", format_result(result))
    if figures:

        stage_figures(result, out)
    return model


def format_result(result: SuccessiveResult) -> str:
    """Plain-text table: every parameter with its value, unit, stage and fit residual."""
    lines = [f"successive isolation of {result.device}: {len(result.stages)} stages, {result.elapsed_s:.1f} s, "
             f"{result.ticks} servo ticks on the device",
             f"{'parameter':32s} {'value':>12s} {'unit':7s} {'stage':10s} {'residual':>9s}"]
    for key, p in result.provenance().items():
        r = p["residual"]
        lines.append(f"{key:32s} {p['value']:12.6g} {p['unit']:7s} {p['stage']:10s} "
                     f"{'' if r is None else f'{r:9.4f}'}")
    for st in result.stages:
        for n in st.notes:
            lines.append(f"{st.stage}: {n}")
    return "\n".join(lines) + "\n"
