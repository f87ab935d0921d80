"""Shared pieces of the successive-isolation stages: the built-up model simulation, the least-squares fit of
a stage's outermost parameters on it (scipy.optimize), stage results and errors (thesis sec. 3.5.1)."""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares

from ...sim import kernel as K
from ...sim.device import SimDevice
from ...sim.params import SimParams, default_params, params_from_dict
from ...sim.person import DEFAULT_PERSON
from .experiment import Experiment, Trace, run_on_sim_fast

# units of every identified parameter (model-file keys "section.key")
UNITS = {
    "device.servo_rate_hz": "Hz", "device.current_amplifier_A": "A",
    "amplifier.bandwidth_hz": "Hz", "amplifier.gain": "A/A", "amplifier.offset_A": "A",
    "mechanics.m_m_kg": "kg", "mechanics.b_m_Ns_m": "N s/m", "mechanics.c_m_N": "N",
    "mechanics.k_c_N_m": "N/m", "mechanics.b_c_Ns_m": "N s/m",
    "mechanics.m_d_kg": "kg", "mechanics.b_d_Ns_m": "N s/m", "mechanics.c_d_N": "N",
    "mechanics.k_lp_N_m": "N/m", "mechanics.k_ln_N_m": "N/m", "mechanics.f_lp_N": "N", "mechanics.f_ln_N": "N",
    "mechanics.gamma_l_rad_m": "rad/m", "mechanics.b_l_Ns_m": "N s/m", "mechanics.m_h_kg": "kg",
    "user.k_u_N_m": "N/m", "user.b_u_Ns_m": "N s/m", "user.nominal_grip_N": "N",
    "person.arm_mass_kg": "kg",
}
PERSON_PREFIX = "person."


def default_person():
    """The sim's default simulated person if it has a hand mass (``devices.sim.person.DEFAULT_PERSON``),
    else None (the prescribed hand of eq. 3.34: spring-damper to a position source)."""
    return DEFAULT_PERSON if hasattr(DEFAULT_PERSON, "arm_mass_kg") else None


def person_with(values: dict):
    """The default person with ``person.<field>`` values replaced, or None if none is given/available."""
    fields = {k[len(PERSON_PREFIX):]: v for k, v in values.items() if k.startswith(PERSON_PREFIX)}
    base = default_person()
    if not fields or base is None:
        return None

    return replace(base, **fields)

# placeholders for elements not identified yet: every stage's configuration disconnects or locks them,
# so their values never reach a fit (the procedure does not use any device's Table 3.1 values)
_PLACEHOLDER_MECHANICS = {"m_m_kg": 1.0, "b_m_Ns_m": 0.0, "c_m_N": 0.0, "k_c_N_m": 1.0, "b_c_Ns_m": 0.0,
                          "m_d_kg": 1.0, "b_d_Ns_m": 0.0, "c_d_N": 0.0, "k_lp_N_m": 1.0, "k_ln_N_m": 1.0,
                          "f_lp_N": 0.1, "f_ln_N": -0.1, "gamma_l_rad_m": 1.0, "b_l_Ns_m": 0.0, "m_h_kg": 1.0,
                          "hysteresis": True}


OFFSET = "_encoder_offset_m"


class StageError(ValueError):
    """A stage's measurement is implausible or was made in the wrong configuration (message says which)."""


@dataclass
class StageResult:
    """Outcome of one stage.

    Attributes
    ----------
    stage : str
    config : str
        Mechanical configuration the stage ran in (``devices.sim.mechconfig.CONFIGS`` key).
    values : dict
        Identified parameters, ``"section.key" -> value`` (SI, see ``UNITS``).
    residuals : dict
        ``"section.key" -> fit residual`` (normalized RMS error of the fit that determined it; for
        quasi-static estimates the relative standard error).
    figure_data : dict
        Arrays for the stage's figure (not saved in the model file).
    notes : list of str
    elapsed_s : float
    """

    stage: str
    config: str
    values: dict
    residuals: dict
    figure_data: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    elapsed_s: float = 0.0

    def to_json(self) -> dict:
        """JSON-able summary (everything but the figure arrays)."""
        return {"stage": self.stage, "config": self.config, "values": dict(self.values),
                "residuals": dict(self.residuals), "notes": list(self.notes), "elapsed_s": self.elapsed_s}


def base_params_dict(info, name: str = "identified") -> dict:
    """A parameter dict (file format) for a device described by ``info`` (DeviceInfo: data-sheet values),
    with sensor and simulation settings of the sim and placeholder mechanics. The user section starts at
    zero impedance (no user).

    Parameters
    ----------
    info : DeviceInfo
    name : str
        Model name written into the file.

    Returns
    -------
    dict
        Nested dict in the sim parameter file format (``devices.sim.params``).
    """
    t = default_params("nonlinear").to_dict()
    d = {"model": "nonlinear", "name": name}
    d["device"] = {
        "encoder_lines": int(info.encoder_lines), "gear_ratio": float(info.gear_ratio),
        "handle_length_m": float(info.handle_length_m), "torque_constant_Nm_A": float(info.torque_constant_Nm_A),
        "current_continuous_A": float(info.current_continuous_A), "current_peak_A": float(info.current_peak_A),
        "current_amplifier_A": float(info.current_amplifier_A), "servo_rate_hz": float(info.servo_rate_hz),
        "winding_resistance_ohm": float(info.winding_resistance_ohm),
        "thermal_resistance_K_W": float(info.thermal_resistance_K_W),
        "thermal_time_constant_s": float(info.thermal_time_constant_s),
        "winding_max_temp_rise_K": float(info.winding_max_temp_rise_K)}
    d["amplifier"] = {"kind": "ideal", "bandwidth_hz": 2000.0}
    d["simulation"] = dict(t["simulation"])
    d["user"] = {"k_u_N_m": 0.0, "b_u_Ns_m": 0.0, "nominal_grip_N": 2.0}
    d["sensors"] = dict(t["sensors"])
    d["sensors"]["accel_range_m_s2"] = float(info.accel_range_m_s2)
    d["sensors"]["grip_max_N"] = float(info.grip_range_N[1])
    d["mechanics"] = dict(_PLACEHOLDER_MECHANICS)
    return d


class ModelBuilder:
    """The built-up simulation: a base parameter dict plus the values identified so far.

    Parameters
    ----------
    base : dict
        Parameter dict in the file format (:func:`base_params_dict`).
    """

    def __init__(self, base: dict):
        self.base = base
        self.values: dict = {}

    def params(self, extra: dict | None = None, noiseless: bool = True) -> SimParams:
        """Validated :class:`SimParams` of the base with the identified values (and ``extra``) set."""
        d = {k: (dict(v) if isinstance(v, dict) else v) for k, v in self.base.items()}
        for key, value in {**self.values, **(extra or {})}.items():
            sec, _, name = key.partition(".")
            if sec in d and isinstance(d[sec], dict) and name in d[sec]:
                d[sec][name] = value
        if noiseless:
            d["sensors"]["accel_noise_m_s2"] = 0.0
        return params_from_dict(d, source="<successive isolation model>")

    def device(self, config: str, extra: dict | None = None, quantized: bool = True):
        """A model :class:`SimDevice` in mechanical configuration ``config``; ``quantized=False`` reads the
        encoder without quantization (open-loop fits: the measured counts then scatter around a smooth
        prediction instead of making the fit error piecewise constant in the parameters)."""
        dev = SimDevice(self.params(extra))
        dev.set_mechanical_config(config)
        if not quantized:
            dev._p[K.P_ENC_RES] = 1e-15
        return dev

    def simulate(self, config: str, experiments, extra: dict | None = None, quantized: bool = True) -> list[Trace]:
        """Run ``experiments`` on the model (one fresh device per call, each experiment from rest); values
        ``person.<field>`` (e.g. the hand mass) set the simulated person holding the model's handle."""
        return list(self.simulate_each(config, experiments, extra, quantized))

    def simulate_each(self, config: str, experiments, extra: dict | None = None, quantized: bool = True):
        """:meth:`simulate`'s traces one at a time, each run when asked for (the same device and the same
        numbers): a caller that has seen enough stops before the rest are simulated."""
        dev = self.device(config, extra, quantized)
        hand = person_with({**self.values, **(extra or {})})
        for e in experiments:
            yield run_on_sim_fast(dev, e, hand)


def nrmse(y: np.ndarray, y_hat: np.ndarray) -> float:
    """Normalized RMS error ``||y - y_hat|| / ||y - mean(y)||`` (0 perfect, 1 as bad as the mean).

    Parameters
    ----------
    y, y_hat : array_like, shape (n,)
        Measured and predicted signal.

    Returns
    -------
    float
    """
    y = np.asarray(y, float)
    den = np.linalg.norm(y - y.mean())
    return float(np.linalg.norm(y - np.asarray(y_hat, float)) / den) if den > 0 else float("inf")


def fit_on_model(builder: ModelBuilder, config: str, experiments: list[Experiment], traces: list[Trace],
                 free: dict, channel: str = "x", fixed: dict | None = None, max_nfev: int = 60,
                 log_params=(), quantized: bool | None = None) -> tuple[dict, float, list[Trace]]:
    """Least-squares fit of ``free`` parameters so the model's traces match the measured ones.

    Parameters
    ----------
    free : dict
        ``"section.key" -> (initial, lower, upper)``; names in ``log_params`` are fitted in log space.
    channel : {"x", "a", "xa"}
        Compared signal: encoder position, handle acceleration, or both (each normalized by its spread).
    quantized : bool or None
        Model encoder quantization; None: quantized for closed-loop experiments only (where the
        controller sees the counts), smooth for open-loop ones.

    Returns
    -------
    values, nrmse, model_traces
    """

    fixed = dict(fixed or {})
    if quantized is None:
        quantized = any(e.ref_m is not None for e in experiments)
    free = dict(free)
    if not quantized and "x" in channel:
        # the counts read q(X0 + x) - q(X0): on average x plus an unknown offset within half a count
        res = builder.params().device_info().position_resolution_m
        free[OFFSET] = (0.0, -0.5 * res, 0.5 * res)
    names = list(free)

    def to_x(vals):
        return np.array([math.log(v) if n in log_params else v for n, v in zip(names, vals)])

    def from_x(x):
        return {n: (math.exp(v) if n in log_params else float(v)) for n, v in zip(names, x)}

    x0 = to_x([free[n][0] for n in names])
    lo = to_x([free[n][1] for n in names])
    hi = to_x([free[n][2] for n in names])
    x0 = np.clip(x0, lo + 1e-12 * np.abs(lo), hi - 1e-12 * np.abs(hi))
    scales = []
    for tr in traces:
        sx = float(np.std(tr.x_m)) or 1.0
        sa = float(np.std(tr.a_m_s2)) or 1.0
        scales.append((sx, sa))
    # the model's traces at the last few parameter values, by the values' bits: the encoder offset is no model
    # parameter, so the Jacobian's offset column and the solution's final traces simulate values just
    # simulated (a fifth of an isolation's simulated ticks); the model is deterministic (a fresh noiseless
    # device per call), so the stored traces are the ones a new simulation would give, bit for bit
    memo: OrderedDict[bytes, list[Trace]] = OrderedDict()
    keep = len(names) + 2                          # a base point, its Jacobian's points and the next step

    def simulate(vals: dict) -> list[Trace]:
        key = np.array(list(vals.values()), dtype=float).tobytes()     # names in a fixed order; -0.0 != 0.0
        sims = memo.get(key)
        if sims is None:
            sims = memo[key] = builder.simulate(config, experiments, {**fixed, **vals}, quantized)
            while len(memo) > keep:
                memo.popitem(last=False)
        else:
            memo.move_to_end(key)
        return sims

    def residual(x):
        vals = from_x(x)
        off = vals.pop(OFFSET, 0.0)
        sims = simulate(vals)
        parts = []
        for tr, sm, (sx, sa) in zip(traces, sims, scales):
            w = 1.0 / math.sqrt(tr.x_m.size)
            if "x" in channel:
                parts.append((sm.x_m + off - tr.x_m) / sx * w)
            if "a" in channel:
                parts.append((sm.a_m_s2 - tr.a_m_s2) / sa * w)
        r = np.concatenate(parts)
        return np.where(np.isfinite(r), r, 1e3)

    res = least_squares(residual, x0, bounds=(lo, hi), x_scale="jac", diff_step=1e-3, max_nfev=max_nfev,
                        method="trf")
    vals = from_x(res.x)
    off = vals.pop(OFFSET, 0.0)
    sims = simulate(vals)
    err = []
    for tr, sm in zip(traces, sims):
        if "x" in channel:
            err.append(nrmse(tr.x_m, sm.x_m + off))
        if "a" in channel:
            err.append(nrmse(tr.a_m_s2, sm.a_m_s2))
    return vals, float(np.mean(err)), sims


def log_grid_init(builder: ModelBuilder, config: str, experiments, traces, name: str, lo: float, hi: float,
                  n: int = 13, channel: str = "x", fixed: dict | None = None, quantized: bool = True) -> float:
    """Best value of one parameter on a log grid (initial value for a fit without an analytic estimate).

    Parameters
    ----------
    builder, config, experiments, traces
        As for :func:`fit_on_model`.
    name : str
        ``"section.key"`` of the parameter.
    lo, hi : float
        Grid bounds (same unit as the parameter); ``n`` points, geometric.

    Returns
    -------
    float
        The grid value with the smallest summed NRMSE.
    """
    best, best_err = lo, math.inf
    for v in np.geomspace(lo, hi, n):
        sims = builder.simulate_each(config, experiments, {**(fixed or {}), name: float(v)}, quantized)
        e = 0.0
        for tr, sm in zip(traces, sims):
            if "x" in channel:
                e += nrmse(tr.x_m, sm.x_m)
            if "a" in channel:
                e += nrmse(tr.a_m_s2, sm.a_m_s2)
            if e >= best_err:
                break   # the other experiments only add to it: not the best, whatever they give
        if e < best_err:
            best, best_err = float(v), e
    return best
