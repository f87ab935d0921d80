"""The wall's passivity observer: how an unstable servo loop is recognised and stopped.

An impedance-type device renders a wall with a sampled spring (eq. 2.1); sampling, the amplifier's delay
and position quantisation make it slightly active, and too stiff a wall for the device and the hand
chatters or diverges (Colgate & Schenkel 1997; thesis section 4.5.2: encoder buzzing near the very firm
gain). The observer (Hannaford & Ryu 2002, "Time-domain passivity control of haptic interfaces") sums,
every tick, the work the wall's force held over the last period did on the handle plus the change of
the energy the wall stores, ``E <- a E + F_{k-1} (x_k - x_{k-1}) + U(x_k) - U(x_{k-1})``, with a leak
``a = exp(-T / instability_window_s)``. A spring-like wall gives back what it stored: ``E`` stays at the
sampling leak, of order ``k T v^2`` per tap (under 1 % of the limit below at 340-1020 N/m, docs/renderer.md);
a chattering or diverging loop generates energy every cycle. ``renderer.law`` compiles
:func:`wall_energy` into the servo law and stops the loop (``"unstable"``, zero current) once ``E``
exceeds the limit of :func:`passivity_constants`. Scalar code with no imports from the project: the law's
compiled build (``renderer.sim_aot``) is keyed by its sources.
"""

from __future__ import annotations

import math


def wall_energy(k, f_c, d, nz):
    """Energy (J) the proportional wall stores at penetration ``d`` (m), the potential of its force.

    Along z the wall pushes ``k d nz`` (``d``'s z-gradient is ``-nz``), clamped at ``f_c`` (N): the
    potential is ``k d^2 / 2`` up to the clamp at ``d_s = f_c / (|nz| k)``, then grows by
    ``f_c / |nz|`` per metre. Plain scalar code: ``renderer.law`` compiles it into the servo law.

    Parameters
    ----------
    k : float
        Stiffness (N/m).
    f_c : float
        Force limit along z (N).
    d : float
        Penetration (m, > 0 inside).
    nz : float
        z component of the surface normal.

    Returns
    -------
    float
    """
    if d <= 0.0:
        return 0.0
    a = abs(nz)
    if a * k * d <= f_c or a < 1e-6:
        return 0.5 * k * d * d
    d_s = f_c / (a * k)
    return 0.5 * k * d_s * d_s + f_c / a * (d - d_s)


#: Travel (m) over which the wall's full force does the energy a very stiff wall's limit adds. A wall far
#: stiffer than its force limit (one that saturates within micrometres) stores almost nothing, yet each
#: crossing of its surface leaks about ``F_c v T`` through sampling (30 nm of full-force travel per
#: mm/s of speed at 10 kHz): taps at 0.05-0.3 m/s on a 10^6 N/m wall on the simulated device gather
#: 0.8 mJ within the 1 s window, about a quarter of ``F_c TRAVEL_M``; a wall that buzzes at full
#: current (2 x 10^5 N/m pressed: 187 Hz, 1.2 A peak to peak) gathers 4.3 mJ (docs/renderer.md).
TRAVEL_M = 1e-3


def energy_limit(k, f_c, frac):
    """Stop threshold (J) of a passivity observer on a spring ``k`` (N/m) clamped at ``f_c`` (N).

    ``frac * (f_c^2 / (2 k) + f_c TRAVEL_M)``: the most energy the spring stores before its clamp, plus
    full force over :data:`TRAVEL_M`; inf without stiffness (nothing stored, never stopped) or with
    ``frac`` inf (the check off). Used for the wall (:func:`passivity_constants`) and homing's PD.
    """
    if not k > 0.0:
        return math.inf
    return frac * (f_c * f_c / (2.0 * k) + f_c * TRAVEL_M)


def passivity_constants(cfg, dt_s: float, wall_force_limit_N: float) -> tuple[float, float]:
    """Leak factor and stop threshold of the wall's passivity observer (module doc).

    The loop stops once the observed energy exceeds ``instability_energy_frac * (F_c^2 / (2 k) +
    F_c TRAVEL_M)``: the most energy the wall stores before its force limit ``F_c``, plus full force
    over :data:`TRAVEL_M`. A wall without stiffness stores nothing and is never stopped by it (its
    damping only dissipates).

    Parameters
    ----------
    cfg : renderer.config.RendererConfig
        ``stiffness_N_m``, ``instability_window_s``, ``instability_energy_frac``.
    dt_s : float
        Servo period T (s).
    wall_force_limit_N : float
        ``F_c``: the wall channel's current limit times the force per amp (N).

    Returns
    -------
    decay, limit_J : float
        Per-tick leak factor ``exp(-T / instability_window_s)`` and the threshold (J; inf without
        stiffness).
    """
    k = float(cfg.stiffness_N_m)
    f_c = float(wall_force_limit_N)
    limit = energy_limit(k, f_c, cfg.instability_energy_frac)
    return math.exp(-dt_s / cfg.instability_window_s), limit


class PassivityObserver:
    """The energy observer of a plain-Python servo law (Hannaford & Ryu 2002; the wall's, inlined in the
    compiled law, follows the same update): every tick

        E <- max(0, decay E + F_{k-1} (x_k - x_{k-1}) + U(x_k) - U(x_{k-1}))

    with ``U`` the energy the law's (saturated) spring stores; the law is unstable once ``E`` exceeds
    ``limit_J``.

    Parameters
    ----------
    decay : float
        Leak per tick, ``exp(-T / window)``.
    limit_J : float
        Energy limit (J), e.g. :func:`energy_limit`.
    stored_J : float
        The spring's stored energy at the start (J).

    Attributes
    ----------
    energy_J, peak_J : float
        The observed energy now and its largest value (J).
    """

    __slots__ = ("decay", "limit_J", "energy_J", "peak_J", "_stored_J")

    def __init__(self, decay: float, limit_J: float, stored_J: float = 0.0):
        self.decay = float(decay)
        self.limit_J = float(limit_J)
        self.energy_J = 0.0
        self.peak_J = 0.0
        self._stored_J = float(stored_J)

    def update(self, force_N: float, dx_m: float, stored_J: float) -> bool:
        """Add one tick: ``force_N`` held over the last period, the displacement ``dx_m`` (m) and the spring's
        stored energy now (J). Returns True when the energy exceeds the limit (unstable)."""
        e = self.energy_J * self.decay + force_N * dx_m + stored_J - self._stored_J
        if e < 0.0:
            e = 0.0  # dissipated energy is no credit for what an unstable loop generates later
        self.energy_J = e
        self._stored_J = stored_J
        if e > self.peak_J:
            self.peak_J = e
            return e > self.limit_J
        return False
