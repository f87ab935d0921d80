"""The simulated person holding the device: a hand/arm mass that carries momentum (thesis 3.4.6, 3.5.2, 5.6.2).

This is the default simulated user of :class:`devices.sim.SimDevice` (and the
operator of the teleoperation sweeps). The person is a chain of three parts::

    handle --[grip impedance k_u(g), b_u(g)]-- hand/arm mass m_a --[muscles]-- voluntary plan x_t(t)

* **Grip impedance** (Table 3.1, eq. 3.34): the finger pads between the
  handle and the hand, ``k_u(g) = k_u g / g_nom``, ``b_u(g) = b_u g / g_nom``
  (40 N/m, 23 N s/m at 2 N; the device's ``[user]`` parameters).
* **Hand/arm mass** ``arm_mass_kg``: the inertia behind the grip, so a
  contact impulse J changes the hand's speed by J / (m_a + m_tool). A
  transient's impulse therefore cancels real incoming momentum (section
  4.5.5), and a stiff sample stops a real mass.
* **Muscles**: the intrinsic (reflex-free) muscle impedance ``muscle_stiffness_N_m``,
  ``muscle_damping_Ns_m`` towards the plan, the feedforward
  ``(m_a + m_tool) a_t`` of an internal model of arm and tool (free motion
  follows the plan), and the **low-frequency compensation** of section
  5.6.2: the person removes slow deflections "at frequencies from steady
  state to about eight hertz" by extra hand force. Modelled as the
  position error to the plan, low-passed at ``compensation_bandwidth_hz``
  (8 Hz) and pushed back with ``compensation_stiffness_N_m``: stiff against
  a sustained push, absent at impact frequencies.
* **Voluntary tapping motion**: the plan is a :class:`TapTrajectory`
  (approach at the tap speed, through the surface, lift). The plan is not
  a velocity source: at the surface nothing but the arm's momentum and the
  weak intrinsic impedance act until the **contact reflex**: once the
  handle pushes up on the hand by more than ``reflex_force_N``, after
  ``reflex_delay_s`` the plan stops descending and holds where it is, until
  the scheduled lift rises above it.

The equations (handle space, positive up; eq. 3.34 for the handle)::

    F_u = -k_u(g) (x_h - x_a) - b_u(g) (v_h - v_a)            force of the hand on the handle
    e_f' = 2 pi f_c (x_t - x_a - e_f)                          compensation error, low-passed
    m_a a_a = -F_u + k_m (x_t - x_a) + b_m (v_t - v_a) + k_c e_f + (m_a + m_tool) a_t

Literature (values at the stylus, i.e. the handle of the thesis' joystick):
see docs/sim.md, "The simulated person", for the ranges and sources.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields


@dataclass(frozen=True)
class Person:
    """Parameters of the simulated person (the default user of the sim device).

    The grip impedance itself (Table 3.1 ``k_u``, ``b_u`` at the nominal
    grip, scaled linearly with grip) is a device parameter (``[user]`` in the
    sim parameter file), since identification measures it through the
    device; this class holds what is behind it.

    Attributes
    ----------
    arm_mass_kg : float
        Effective hand/arm mass at the handle (kg), 0.07 kg. A tap with a
        held stylus is a wrist/finger flexion; the hand's inertia about the
        wrist (~1-3e-3 kg m^2) seen 0.12-0.15 m from the wrist is 0.05-0.2
        kg, far above the finger pad's few grams (Hajian & Howe 1997 [53]:
        ~4-6 g at the fingertip) and below the whole forearm's.
    muscle_stiffness_N_m : float
        Intrinsic (reflex-free) muscle stiffness towards the plan (N/m),
        60 N/m: a relaxed wrist, ~1 N m/rad (Kuchenbecker, Park & Niemeyer
        2003 [84] report wrist stiffness of order 1 N m/rad rising with
        co-contraction) over (0.13 m)^2.
    muscle_damping_Ns_m : float
        Intrinsic muscle damping (N s/m), 3 N s/m (~0.05 N m s/rad over
        (0.13 m)^2; wrist damping of 0.03-0.1 N m s/rad, rising with
        co-contraction, [84]). With the compensation below it sets the
        damping ratio of the person's ~6 Hz mode (arm and tool on muscles
        and compensation) to ~0.2. The compensation's lag feeds energy into
        that mode: the earlier 1.5 N s/m with 150 N/m of compensation made it
        grow, so a holding hand shook the handle by ~1 cm and hard taps on a
        firm wall built up until the handle left the workspace.
    compensation_stiffness_N_m : float
        Gain of the low-frequency compensation (N/m), 100 N/m: with the
        intrinsic stiffness, ~160 N/m against slow loads.
    compensation_bandwidth_hz : float
        Corner of the compensation (Hz), 8 Hz: the thesis' "from steady
        state to about eight hertz" (section 5.6.2).
    reflex_delay_s : float
        Contact-force onset to the plan holding (s), 0.04 s: between the
        spinal (~30 ms) and long-latency (~50-60 ms) stretch reflexes, well
        under the ~140 ms voluntary reaction time (section 4.2.2, [92]).
    reflex_force_N : float
        Upward handle force on the hand that counts as contact (N), 0.3 N
        (~10x the device's free-space drag; armed only while the plan is
        not accelerating, so starting a tap does not trigger it).
    """

    arm_mass_kg: float = 0.07
    muscle_stiffness_N_m: float = 60.0
    muscle_damping_Ns_m: float = 3.0
    compensation_stiffness_N_m: float = 100.0
    compensation_bandwidth_hz: float = 8.0
    reflex_delay_s: float = 0.04
    reflex_force_N: float = 0.3
    fingertip_mass_kg: float = 0.005
    fingertip_stiffness_N_m: float = 6240.0
    fingertip_damping_Ns_m: float = 23.0

    def __post_init__(self):
        for f in fields(self):
            val = getattr(self, f.name)
            if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
                raise ValueError(f"Person: {f.name} must be a finite number, got {val!r}")
            if f.name in ("arm_mass_kg", "compensation_bandwidth_hz"):
                if not val > 0:
                    raise ValueError(f"Person: {f.name} must be > 0, got {val!r}")
            elif val < 0:
                raise ValueError(f"Person: {f.name} must be >= 0, got {val!r}")
        if self.fingertip_mass_kg > 0 and not self.fingertip_stiffness_N_m > 0:
            raise ValueError("Person: a fingertip (fingertip_mass_kg > 0) needs fingertip_stiffness_N_m > 0, got "
                             f"{self.fingertip_stiffness_N_m!r}")

    def replace(self, **changes) -> "Person":
        """A copy with some parameters changed (validated).

        Parameters
        ----------
        **changes : float
            Attribute name -> new value.

        Returns
        -------
        Person
        """
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise ValueError(f"Person: unknown parameter(s) {', '.join(sorted(unknown))}")
        vals = {f.name: getattr(self, f.name) for f in fields(self)}
        vals.update(changes)
        return Person(**vals)


#: The default simulated person.
DEFAULT_PERSON = Person()

#: ``SimDevice.set_user(..., hand=PRESCRIBED)``: the old hand, the grip spring-damper tied directly to the
#: desired trajectory (a velocity source; no momentum). Kept for the LTI model and for comparisons.
PRESCRIBED = "prescribed"
