"""Where the CIMM master model comes from (one place, so tests and commands share the source).

The CIMM model must come from the project's own identification of the master, never from the
simulator's true parameters. Default (:func:`identified_params`): successive isolation
(``devices.identify.successive.identify_successive``, thesis section 3.5) of the simulated master,
cached as a ``model.json`` under ``$XDG_CACHE_HOME/hfam-haptics/teleop/`` keyed by the simulator's
parameter file and the code of ``devices/sim`` and ``devices/identify``. Alternatives: a parameter file (``--cimm-model FILE``, loadable by
``load_sim_params``) or ``--cimm-model stand-in``: **clearly marked perturbed Table 3.1 parameters**
(every mechanical parameter off by 5-20 %), for quick runs and a harder robustness case.
"""

from __future__ import annotations

import hashlib
import math
import os
import time
from pathlib import Path

import numpy as np

from devices.identify.successive import identify_successive, save_result
from devices.sim.linear import linear_linkage_params
from devices.sim.params import DEFAULT_PARAMS_FILE, SimParams, default_params, load_sim_params
from plumbing.fileio import user_cache_dir

# relative errors of the stand-in model (the marked alternative to the default successive-isolation model, whose
# errors are what identification left): name -> factor
STAND_IN_ERRORS = {"m_m_kg": 1.08, "m_d_kg": 0.92, "m_h_kg": 1.10, "k_c_N_m": 0.90, "b_c_Ns_m": 1.20,
                   "c_m_N": 0.85, "c_d_N": 1.15, "k_lp_N_m": 1.05, "k_ln_N_m": 0.95, "gamma_l_rad_m": 1.10,
                   "b_d_Ns_m": 1.2}
STAND_IN_SOURCE = "stand-in: Table 3.1 with 5-20 % errors (not identified)"
SUCCESSIVE_SOURCE = "successive isolation (devices.identify.successive) of the simulated master"
#: the code the cached identification depends on (part of its cache key)
_IDENTIFIED_BY = (Path(DEFAULT_PARAMS_FILE).parent, Path(DEFAULT_PARAMS_FILE).parents[1] / "identify")


def identified_params(log=print) -> tuple[SimParams, str]:
    """Successive-isolation identification of the simulated master (once, then cached; the time it took is
    printed).

    Returns
    -------
    params : SimParams
        Loaded from the saved ``model.json``.
    source : str
    """

    # the parameter file and the code of the simulated master, its person and the identification: a cached model
    # is never one an earlier simulator made
    h = hashlib.sha256(Path(DEFAULT_PARAMS_FILE).read_bytes())
    for folder in _IDENTIFIED_BY:
        for f in sorted(folder.rglob("*.py")):
            h.update(f.name.encode())
            h.update(f.read_bytes())
    key = h.hexdigest()[:16]
    base = user_cache_dir() / "teleop" / key
    model = base / "model.json"
    if not model.is_file():
        log("identifying the master by successive isolation (once; cached afterwards)...")
        t0 = time.monotonic()
        result = identify_successive("sim", log=lambda *a, **k: None)
        log(f"identified the master in {time.monotonic() - t0:.1f} s")
        tmp = base.with_name(base.name + f".tmp{os.getpid()}")
        save_result(result, tmp, figures=False)
        tmp.mkdir(parents=True, exist_ok=True)
        try:
            tmp.rename(base)
        except OSError:  # another process finished first: use its result
            pass
    return load_sim_params(model), f"{SUCCESSIVE_SOURCE}: {model}"


#: ``--cimm-model linear-linkage``: the identified master with its linkage made linear (Figure 5.11's simpler model)
LINEAR_LINKAGE = "linear-linkage"


def simpler_params(params: SimParams, source: str) -> tuple[SimParams, str]:
    """Figure 5.11's "simpler, less-accurate model of the human-master dynamics" (section 5.7.2): the same
    identified master with its hysteretic linkage (section 3.5.3) replaced by a linear spring at its small-signal
    stiffness (:func:`devices.sim.linear.linear_linkage_params`).

    The thesis does not say what its simpler model left out; the hysteretic linkage is what section 3.5 adds to a
    linear model to reach the sixth-order nonlinear one, so this is the model without it.

    Parameters
    ----------
    params : SimParams
        A nonlinear (sixth-order) master model, e.g. :func:`identified_params`'s.
    source : str
        Its source description.

    Returns
    -------
    (SimParams, str)
        The simpler model and its source description.
    """
    return linear_linkage_params(params), f"{source}; linkage made linear (Figure 5.11's simpler model)"


def cimm_params(path=None) -> tuple[SimParams, str]:
    """The master parameters for the CIMM model and a description of their source.

    Parameters
    ----------
    path : str or Path or None
        A parameter file (TOML/JSON, nonlinear model); ``"stand-in"``: the marked stand-in;
        ``"linear-linkage"``: :func:`identified_params` with the linkage made linear (:func:`simpler_params`,
        Figure 5.11's "simpler, less-accurate model"); None: :func:`identified_params` (successive isolation).

    Returns
    -------
    params : SimParams
    source : str
    """
    if path is None:
        return identified_params()
    if str(path) == LINEAR_LINKAGE:
        return simpler_params(*identified_params())
    if str(path) != "stand-in":
        p = load_sim_params(path)
        if p.model != "nonlinear":
            raise ValueError(f"{path}: the CIMM model needs a nonlinear (sixth-order) parameter file")
        return p, f"file: {path}"
    base = default_params()
    mech = {k: base.mechanics[k] * f for k, f in STAND_IN_ERRORS.items()}
    return base.replace(name="cimm-stand-in", mechanics=mech), STAND_IN_SOURCE


def underestimation_check(cimm, master: SimParams, f_max_hz: float = 8.0, force_N: float = 1.0) -> dict:
    """Start-up check of eq. 5.14: does the model overestimate the master's induced motion below 8 Hz?

    Compares the magnitude of the model's linearised force -> motor position response (grip stiffness
    linearised at the deflection ``force_N`` gives, washout included) with the identified/measured
    small-signal response of the held master (``master`` with the user's linear grip k_u, b_u) on
    0.5-8 Hz.

    Returns
    -------
    dict with ``max_ratio`` (model / measured, max over the band), ``f_at_max_hz`` and ``warning``
    (a sentence, or "" if the model underestimates everywhere below 8 Hz).
    """
    f = np.geomspace(0.5, f_max_hz, 40)
    w = 2 * np.pi * f
    # deflection under force_N with the linear + quintic stiffness: solve k x + q x^5 = F
    k, q = cimm.k_u_N_m, cimm.q_u_N_m5
    x = force_N / max(k, 1e-9)
    for _ in range(60):
        g = k * x + q * x ** 5 - force_N
        x -= g / (k + 5 * q * x ** 4)
    k_eff = k + 5 * q * x ** 4
    m_model = sum(cimm.params.mechanics[n] for n in ("m_m_kg", "m_d_kg", "m_h_kg")) + cimm.hand_mass_kg
    g_model = 1 / np.abs(-m_model * w ** 2 + 1j * w * cimm.b_u_Ns_m + k_eff)
    if cimm.washout_hz > 0:
        g_model = g_model * np.abs(1j * w / (1j * w + 2 * np.pi * cimm.washout_hz))
    m_true = sum(master.mechanics[n] for n in ("m_m_kg", "m_d_kg", "m_h_kg"))
    ku, bu = master.user["k_u_N_m"], master.user["b_u_Ns_m"]
    g_meas = 1 / np.abs(-m_true * w ** 2 + 1j * w * bu + ku)
    ratio = g_model / g_meas
    j = int(np.argmax(ratio))
    warn = ""
    if ratio[j] > 1.0:
        warn = (f"warning: the CIMM model overestimates induced master motion below {f_max_hz:g} Hz "
                f"(x{ratio[j]:.2f} at {f[j]:.1f} Hz): positive feedback (eq. 5.14)")
    return {"max_ratio": float(ratio[j]), "f_at_max_hz": float(f[j]), "warning": warn,
            "linearised_at_N": force_N, "k_eff_N_m": float(k_eff) if math.isfinite(k_eff) else None}
