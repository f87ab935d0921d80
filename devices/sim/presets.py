"""Named simulated devices (``sim:<name>`` device strings) and the linear-linkage variant; no numpy, no scipy.

* ``joystick`` (also plain ``sim``): the thesis's Table 3.1 joystick, the Impulse Engine 2000 testbed of
  section 3.5 with its hysteretic linkage (section 3.5.3): chapter 3's successive isolation and chapter 5's
  teleoperation testbed.
* ``onedof``: the device of chapter 4's claims. Section 4.4.3 ran HFAM's grip experiments on "a custom
  one-degree-of-freedom testbed" with "a Maxon RE025 motor" and one LTI model per grip (section 3.4.6), and
  section 4.2.2 asks that nonlinear parts "should be fixed or replaced to enable the use of a linear model".
  The thesis gives that testbed's motor, sensors and servo rate (the sim already has them) but not its
  mechanics, so this is Table 3.1's masses, cables and friction with the linkage a linear spring at the
  small-signal stiffness (:func:`linear_linkage_params`): the same device without the amplitude-dependent
  resonance.
* ``lti``: section 3.4.4's Phantom as an LTI model (``phantom_lti.toml``).

See docs/sim.md ("Named devices").
"""

from __future__ import annotations

from .params import SimParams, default_params

#: the named devices of ``sim:<name>`` and what each stands for (docs/sim.md)
PRESETS = {
    "joystick": "Table 3.1 joystick, hysteretic linkage (chapter 3's successive isolation, chapter 5's testbed)",
    "onedof": "the section 4.4.3 one-dof testbed: Table 3.1's masses with a linear linkage (chapter 4's claims)",
    "lti": "section 3.4.4's Phantom as an LTI model",
}
#: the device chapter 4's claims run on by default (the demo, the HFAM scoring, the study's simulated sessions)
CHAPTER_4_DEVICE = "sim:onedof"
#: the name the one-dof device reports (``DeviceInfo.name``)
ONEDOF_NAME = "sim-onedof"


def linkage_stiffness_N_m(mechanics, linkage: str = "small_signal") -> float:
    """Linear stiffness standing in for the hysteretic linkage (section 3.5.3).

    ``"asymptotic"``: the mean slope of the two asymptotes, (k_lp + k_ln)/2:
    the loop's mean slope for deflection swings much larger than 1/gamma.
    ``"small_signal"``: the mean slope of the minor loops traced by swings
    much smaller than 1/gamma (~0.1 mm for Table 3.1), the regime of
    high-frequency transients. After each reversal the filtered force moves
    toward the other (offset) asymptote at dF/dx = gamma*(F_hat - F) (eq.
    3.24), so a small symmetric oscillation settles midway between the
    offset asymptotes and sees the slope
    ``(k_lp + k_ln)/2 + gamma*(f_lp - f_ln)/2`` (the g_p/g_n offsets of eq.
    3.30-3.31 contribute the first term). With ``hysteresis = false`` both
    give the mean slope.
    """
    k_mean = 0.5 * (mechanics["k_lp_N_m"] + mechanics["k_ln_N_m"])
    if linkage == "asymptotic" or not mechanics["hysteresis"]:
        return k_mean
    if linkage != "small_signal":
        raise ValueError(f"linkage must be 'small_signal' or 'asymptotic', got {linkage!r}")
    return k_mean + 0.5 * mechanics["gamma_l_rad_m"] * (mechanics["f_lp_N"] - mechanics["f_ln_N"])


def linear_linkage_params(params, linkage: str = "small_signal"):
    """The same nonlinear device with its hysteretic linkage (section 3.5.3) replaced by a linear spring.

    A device variant, not a model: the kernel still integrates eq. 3.32-3.35 with Coulomb friction, the
    hand and the samples, but the linkage force is ``k x`` with ``k = linkage_stiffness_N_m(mechanics,
    linkage)`` (``mechanics.hysteresis = false`` and ``k_lp_N_m = k_ln_N_m = k``; the offsets f_lp, f_ln
    and gamma are then unused). With ``"small_signal"`` (7817.5 N/m for Table 3.1) the variant's analytic
    model equals the hysteretic device's small-signal :func:`linear_model`; it stands for a transmission
    without the joystick's amplitude-dependent resonance (section 3.5.3), such as the section 4.4.3 one-dof
    testbed (a Maxon RE025, one LTI model per grip in section 3.4.6; the thesis reports no hysteresis for it).

    Parameters
    ----------
    params : devices.sim.params.SimParams
        A ``nonlinear`` model's parameters.
    linkage : str
        ``"small_signal"`` or ``"asymptotic"`` (:func:`linkage_stiffness_N_m`).

    Returns
    -------
    devices.sim.params.SimParams
        Re-validated copy, named ``<name>-linear-linkage``.

    Raises
    ------
    ValueError
        An ``lti`` model (it has no linkage) or an unknown ``linkage``.
    """
    if params.model != "nonlinear":
        raise ValueError(f"{params.source}: a linear linkage needs the nonlinear model, got model {params.model!r}")
    if linkage not in ("small_signal", "asymptotic"):
        raise ValueError(f"linkage must be 'small_signal' or 'asymptotic', got {linkage!r}")
    k = linkage_stiffness_N_m(params.mechanics, linkage)
    return params.replace(name=f"{params.name}-linear-linkage",
                          mechanics={"hysteresis": False, "k_lp_N_m": k, "k_ln_N_m": k})



_onedof: list = []


def onedof_params() -> SimParams:
    """The ``onedof`` device: :func:`linear_linkage_params` of Table 3.1 at the small-signal stiffness, named
    :data:`ONEDOF_NAME` (cached)."""
    if not _onedof:
        _onedof.append(linear_linkage_params(default_params()).replace(name=ONEDOF_NAME))
    return _onedof[0]


def preset_params(name: str) -> SimParams:
    """Parameters of a named device (:data:`PRESETS`; ``nonlinear`` is ``joystick``).

    Raises
    ------
    ValueError
        An unknown name (listing the valid ones).
    """
    if name in ("joystick", "nonlinear"):
        return default_params("nonlinear")
    if name == "onedof":
        return onedof_params()
    if name == "lti":
        return default_params("lti")
    raise ValueError(f"unknown sim device {name!r}; named devices: {', '.join(PRESETS)}")
