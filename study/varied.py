"""A catalog sample with one parameter set to a value, and what the simulated participant perceives of it: the
stimuli of the method of adjustment and of magnitude estimation (:mod:`study.adjustment`, :mod:`study.magnitude`).

Any parameter of a virtual catalog sample can be varied: its wall stiffness ``stiffness_N_m`` (N/m), its
transient's ``gain`` (1), or any number among its transient's parameters (``amplitude_Ns_m`` N*s/m,
``frequency_hz`` Hz, ``duration_s`` s, as :func:`stimuli.load_catalog` reads them). A derived sample is named
``<sample>@<parameter>=<value>`` (the forced-choice experiments' naming).

The simulated participant's percept of a presentation comes from what the device rendered in its own taps
(:func:`study.forcedchoice.perception.measured`): the wall's stiffness (force at the deepest penetration over
that penetration) when stiffness is varied, the contact vibration per unit incoming velocity otherwise; times
log-normal Weber noise from the participant's JNDs (force and compliance, 16.8 % for stiffness by default;
vibrotactile amplitude 20 %). THIS TESTS THE PIPELINE AND PLANS STUDIES; IT IS NOT A VALIDATED MODEL OF
PERCEPTION.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .forcedchoice.perception import measured, sigma_of_jnd

#: units of the parameters by their names' suffixes (the project's naming rule: the unit in the name)
SUFFIX_UNITS = (("_N_m", "N/m"), ("_Ns_m", "N*s/m"), ("_hz", "Hz"), ("_s", "s"))


def unit_of(vary: str) -> str:
    """The unit of a varied parameter, from its name (``gain`` and names without a unit: ``1``)."""
    return next((unit for suffix, unit in SUFFIX_UNITS if vary.endswith(suffix)), "1")


def check_varied(sample, vary: str, where: str) -> float:
    """Check that ``vary`` is a parameter of the virtual catalog ``sample`` that can be set; returns its value in
    the catalog (``gain``: 1 unless the sample sets it).

    Raises
    ------
    ValueError
        Naming ``where``, the sample and the parameter.
    """
    if sample.kind != "virtual":
        raise ValueError(f"{where}: sample {sample.name!r} must be a virtual sample (the motor renders it)")
    if vary == "stiffness_N_m":
        return float(sample.stiffness_N_m)
    if sample.transient == "none":
        raise ValueError(f"{where}: sample {sample.name!r} has no transient, so only stiffness_N_m can vary, "
                         f"not {vary!r}")
    if vary == "gain":
        return float(sample.params.get("gain", 1.0))
    value = sample.params.get(vary)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: {vary!r} is not a parameter of sample {sample.name!r} (it has stiffness_N_m, "
                         f"gain{''.join(', ' + k for k in sorted(sample.params) if k != 'gain')})")
    return float(value)


def varied_name(base: str, vary: str, value: float) -> str:
    """``<base>@<vary>=<value>`` (10 significant digits)."""
    return f"{base}@{vary}={format(float(value), '.10g')}"


def varied_sample(base, vary: str, value: float):
    """``base`` (a :class:`stimuli.CatalogSample`) with ``vary`` set to ``value``, named by :func:`varied_name`."""
    value = float(value)
    s = replace(base, stiffness_N_m=value) if vary == "stiffness_N_m" else replace(base, params={**base.params,
                                                                                                  vary: value})
    return replace(s, name=varied_name(base.name, vary, value), label=f"{base.label or base.name}, {vary} {value:g}")


def percept_sigma(vary: str, config) -> float:
    """Log-SD of one presentation's percept (stiffness: force and compliance noise in quadrature; otherwise
    the vibrotactile amplitude JND), from the participant's settings
    (:class:`study.session.participants.SimParticipantConfig`)."""
    if vary == "stiffness_N_m":
        return math.hypot(sigma_of_jnd(config.jnd_force_frac), sigma_of_jnd(config.jnd_compliance_frac))
    return sigma_of_jnd(config.jnd_vibration_frac)


def perceive(vary: str, trace: dict, force_per_amp_N_A: float, config, rng: np.random.Generator) -> tuple[float, float]:
    """``(measured, percept)`` of one presentation: the noise-free quantity from the device's own taps
    (NaN when no tap gave one) and the percept with Weber noise (:func:`percept_sigma`)."""
    value = measured("discrimination", vary, trace, force_per_amp_N_A, None)
    e = float(rng.standard_normal())
    if not math.isfinite(value):
        return value, value
    return value, value * math.exp(percept_sigma(vary, config) * e)
