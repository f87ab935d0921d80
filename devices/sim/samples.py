"""Simulated physical samples under the stylus (thesis Table 4.1, section 4.5.2).

Each sample's top surface is at height 0 (positions positive up). Contact
forces use the Hunt-Crossley impact model ``F = k*d*(1 + alpha*d_dot)``
(d: penetration >= 0, d_dot: penetration rate; F clamped at >= 0 so the
surface never pulls), which dissipates energy in proportion to penetration,
so there is no force jump at first contact.

``wood_on_foam`` is a thin wood tile (mass ``block_mass_kg``) resting on a
viscoelastic foam (standard linear solid plus a parallel damper); the stylus
hits the tile through the same Hunt-Crossley contact as the ``wood`` sample.
Its static stiffness is that of the contact and the foam in series (~350 N/m,
Table 4.1), but at impact rates the foam is ~70x stiffer and lossy, so the
stylus, the hand and the tile ring together at ~55 Hz and decay within a few
tens of ms: the decaying transient the thesis tuned its virtual transients to
(section 4.5.2; Table 4.1's sinusoid, 55 Hz).
"""

from __future__ import annotations

from dataclasses import dataclass

KIND_NONE = 0
KIND_HALFSPACE = 1
KIND_BLOCK_ON_FOAM = 2


@dataclass(frozen=True)
class SampleParams:
    """One simulated sample.

    Attributes
    ----------
    name : str
    kind : int
        ``KIND_NONE`` (placeholder), ``KIND_HALFSPACE`` (contact to ground) or
        ``KIND_BLOCK_ON_FOAM``.
    stiffness_N_m : float
        Effective static stiffness, thesis Table 4.1 (0 for the placeholder).
    contact_k_N_m : float
        Hunt-Crossley contact stiffness k.
    contact_alpha_s_m : float
        Hunt-Crossley damping factor alpha (s/m).
    block_mass_kg, foam_k_N_m, foam_b_Ns_m : float
        Block on foam substrate (``KIND_BLOCK_ON_FOAM`` only): block mass (kg),
        the foam's equilibrium (quasi-static) stiffness (N/m) and damping (N s/m).
    maxwell_k_N_m, maxwell_tau_s : float
        Viscoelastic foam (standard linear solid): a Maxwell branch, spring
        ``maxwell_k_N_m`` in series with a damper of relaxation time
        ``maxwell_tau_s``, in parallel with the equilibrium spring (the foam
        substrate of ``KIND_BLOCK_ON_FOAM``; the contact of ``KIND_HALFSPACE``).
        At impact rates (>> 1/(2 pi tau)) the foam is ``k + maxwell_k`` stiff,
        in a slow press only ``k``. 0 N/m: elastic.
    """

    name: str
    kind: int
    stiffness_N_m: float
    contact_k_N_m: float = 0.0
    contact_alpha_s_m: float = 0.0
    block_mass_kg: float = 0.0
    foam_k_N_m: float = 0.0
    foam_b_Ns_m: float = 0.0
    maxwell_k_N_m: float = 0.0
    maxwell_tau_s: float = 1.0

    @property
    def static_stiffness_N_m(self) -> float:
        """Stiffness felt when pressing slowly (contact and foam in series for a block on foam)."""
        if self.kind == KIND_BLOCK_ON_FOAM:
            return 1.0 / (1.0 / self.contact_k_N_m + 1.0 / self.foam_k_N_m)
        return self.contact_k_N_m


#: the restitution of a metal-tipped stylus on wood that the ``wood`` sample's damping is derived from (the middle of
#: the measured 0.5-0.8 for wood struck by metal at tapping speeds; docs/sim.md "Samples")
WOOD_RESTITUTION = 0.65
#: the speed at which that restitution is taken: section 4.5.4's mean incoming velocity (m/s)
WOOD_RESTITUTION_SPEED_M_S = 0.10


def hunt_crossley_alpha(restitution: float, speed_m_s: float) -> float:
    """Hunt-Crossley damping factor alpha (s/m) for a coefficient of restitution at an impact speed.

    Hunt & Crossley (1975): for ``F = k d (1 + alpha d')`` the energy an impact at ``v`` dissipates, to first
    order in ``alpha v`` (the motion taken as the undamped half sine ``d = (v/w) sin wt``, ``w = sqrt(k/m)``),
    is ``dE = int k alpha d d'^2 dt = (2/3) alpha v^3 m``; with ``1 - e^2 = dE / (m v^2 / 2) = (4/3) alpha v``
    and ``1 - e^2 ~ 2 (1 - e)`` near ``e = 1``: ``e = 1 - (2/3) alpha v``, i.e. ``alpha = 3 (1 - e) / (2 v)``.
    Mass and stiffness drop out (docs/sim.md "Samples" shows the derivation and the exact restitution the
    contact law then gives, which is higher than ``e`` for large ``alpha v``).

    Parameters
    ----------
    restitution : float
        Coefficient of restitution e, 0 < e <= 1.
    speed_m_s : float
        Impact speed v (m/s), > 0.

    Returns
    -------
    float
        alpha (s/m).
    """
    if not 0.0 < restitution <= 1.0 or not speed_m_s > 0.0:
        raise ValueError(f"hunt_crossley_alpha needs 0 < e <= 1 and v > 0, got e={restitution!r}, v={speed_m_s!r}")
    return 3.0 * (1.0 - restitution) / (2.0 * speed_m_s)


#: the wood's Hunt-Crossley damping: 3 (1 - 0.65) / (2 x 0.10 m/s) = 5.25 s/m
WOOD_ALPHA_S_M = round(hunt_crossley_alpha(WOOD_RESTITUTION, WOOD_RESTITUTION_SPEED_M_S), 9)

SAMPLES: dict[str, SampleParams] = {
    "placeholder": SampleParams("placeholder", KIND_NONE, 0.0),
    # Table 4.1's stiffness; the damping from the restitution of wood struck by metal (WOOD_ALPHA_S_M)
    "wood": SampleParams("wood", KIND_HALFSPACE, 70000.0, contact_k_N_m=70000.0, contact_alpha_s_m=WOOD_ALPHA_S_M),
    # a thin wood tile (3 g: ~4 x 4 x 0.4 cm of pine) on viscoelastic foam; the stylus meets the same wood
    # as the `wood` sample (Table 4.1's 70 000 N/m, the same alpha). The foam is ~70x stiffer at impact rates
    # than in a slow press (Maxwell branch) and lossy there (20 N s/m: loss factor ~0.28 at 55 Hz). The
    # stylus and hand, riding the light tile, are stopped within half a ~55 Hz cycle (~9 ms; the Table 4.1
    # sinusoid's 55 Hz); the motor and drum, rebounding through the linkage, then lift the handle off for
    # 5-12 ms (< 0.11 mm) and the ring is over within ~30 ms. (The earlier 0.12 kg block on a nearly
    # lossless foam threw the handle off for a ~30 ms, ~30 Hz chatter: docs/sim.md, "Samples".)
    "wood_on_foam": SampleParams("wood_on_foam", KIND_BLOCK_ON_FOAM, 350.0, contact_k_N_m=70000.0,
                                 contact_alpha_s_m=WOOD_ALPHA_S_M, block_mass_kg=0.003, foam_k_N_m=352.0, foam_b_Ns_m=20.0,
                                 maxwell_k_N_m=25000.0, maxwell_tau_s=2.0),
    "foam": SampleParams("foam", KIND_HALFSPACE, 220.0, contact_k_N_m=220.0, contact_alpha_s_m=5.0,
                         maxwell_k_N_m=30.0, maxwell_tau_s=0.05),
}


def get_sample(name: str) -> SampleParams:
    """Look up a sample by name.

    Raises
    ------
    ValueError
        For an unknown name, listing the valid ones.
    """
    try:
        return SAMPLES[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown sample {name!r}; valid samples: {', '.join(SAMPLES)}") from None
