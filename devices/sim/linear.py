"""Analytic LTI models of the simulated devices (what identification should find).

* Nonlinear device: eq. 3.32-3.34 linearized (Coulomb friction dropped, the
  hysteretic linkage replaced by its mean slope (k_lp + k_ln)/2, user
  impedance at the given grip).
* LTI device: the Phantom-like transmission T(s) of section 3.4.4 driving
  the handle mass held by the user's spring-damper.

Both include the amplifier low-pass (if ``amplifier.kind = "lowpass"``), the
accelerometer's first-order low-pass (acceleration output) and the output
delay of the servo cycle: one period plus half a period for the zero-order
hold, ``delay_s = 1.5 / servo_rate_hz``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

from ..model import ZpkModel
# the linear-linkage variant and its stiffness live with the named devices (no scipy there); re-exported here
from .presets import linear_linkage_params, linkage_stiffness_N_m  # noqa: F401

OUTPUTS = ("accel_m_s2", "position_m")


def _pair(f_hz: float, zeta: float) -> np.ndarray:
    """Complex-conjugate root pair of s^2 + 2*zeta*w*s + w^2 (rad/s)."""
    w = 2 * math.pi * f_hz
    if zeta >= 1:
        r = math.sqrt(zeta * zeta - 1)
        return np.array([-w * (zeta - r), -w * (zeta + r)], dtype=complex)
    wd = w * math.sqrt(1 - zeta * zeta)
    return np.array([complex(-zeta * w, wd), complex(-zeta * w, -wd)])


def lti_transmission_zpk(lti) -> tuple[np.ndarray, np.ndarray, float]:
    """Zeros, poles (rad/s) and gain of the unity-DC-gain transmission T(s) (section 3.4.4).

    Primary resonance pole pair at ``resonance_hz``, then each
    ``[f_zero_hz, zeta_zero, f_pole_hz, zeta_pole]`` of ``pairs`` (a lightly
    damped zero pair followed by a pole pair), then a roll-off pole pair:
    relative degree 4 for the default two pairs.
    """
    zeros = [np.zeros(0, dtype=complex)]
    poles = [_pair(lti["resonance_hz"], lti["resonance_zeta"])]
    for fz, zz, fp, zp in lti["pairs"]:
        zeros.append(_pair(fz, zz))
        poles.append(_pair(fp, zp))
    poles.append(_pair(lti["rolloff_hz"], lti["rolloff_zeta"]))
    z = np.concatenate(zeros)
    p = np.concatenate(poles)
    k = float(np.real(np.prod(-p) / np.prod(-z))) if z.size else float(np.real(np.prod(-p)))
    return z, p, k


def _series(ss1, ss2):
    """State-space of ss2 after ss1 (SISO)."""
    a1, b1, c1, d1 = ss1
    a2, b2, c2, d2 = ss2
    n1, n2 = a1.shape[0], a2.shape[0]
    a = np.zeros((n1 + n2, n1 + n2))
    a[:n1, :n1] = a1
    a[n1:, n1:] = a2
    a[n1:, :n1] = b2 @ c1
    b = np.vstack([b1, b2 @ d1])
    c = np.hstack([d2 @ c1, c2])
    return a, b, c, d2 @ d1


def lti_transmission_ss(lti):
    """State-space (A, B, C, D) of :func:`lti_transmission_zpk`, built as a cascade of
    unity-DC-gain second-order sections (well conditioned, unlike one high-order polynomial)."""
    sections = [(np.zeros(0), _pair(lti["resonance_hz"], lti["resonance_zeta"]))]
    for fz, zz, fp, zp in lti["pairs"]:
        sections.append((_pair(fz, zz), _pair(fp, zp)))
    sections.append((np.zeros(0), _pair(lti["rolloff_hz"], lti["rolloff_zeta"])))
    total = None
    for z, p in sections:
        num = np.real(np.poly(z)) if z.size else np.array([1.0])
        den = np.real(np.poly(p))
        num = num * den[-1] / num[-1]            # unity DC gain
        sec = tuple(np.atleast_2d(m).astype(float) for m in signal.tf2ss(num, den))
        total = sec if total is None else _series(total, sec)
    return total


def lti_transmission_zoh(lti, dt_s: float):
    """The LTI transmission of :func:`lti_transmission_ss` discretized with a zero-order hold.

    Parameters
    ----------
    lti : dict
        The ``[lti]`` section of the sim parameters.
    dt_s : float
        Sample period (s): one servo period.

    Returns
    -------
    (ad, bd, cd, dd) : ndarrays
        Discrete state-space matrices (``scipy.signal.cont2discrete``, method ``zoh``).
    """
    ad, bd, cd, dd, _ = signal.cont2discrete(lti_transmission_ss(lti), dt_s, method="zoh")
    return ad, bd, cd, dd


def _user_impedance(params, grip_N: float) -> tuple[float, float]:
    u = params.user
    return u["k_u_N_m"] * grip_N / u["nominal_grip_N"], u["b_u_Ns_m"] * grip_N / u["nominal_grip_N"]


def _cancel(z: np.ndarray, p: np.ndarray, rtol: float = 1e-6, atol: float = 1e-6):
    """Remove zero/pole pairs that coincide (minimal realization of the SISO model)."""
    z = list(z)
    keep_p = []
    for pole in p:
        dist = [abs(pole - zero) for zero in z]
        if dist and min(dist) <= atol + rtol * abs(pole):
            z.pop(int(np.argmin(dist)))
        else:
            keep_p.append(pole)
    return np.array(z, dtype=complex), np.array(keep_p, dtype=complex)


def nonlinear_tf(params, grip_N: float, output: str, linkage: str = "small_signal"):
    """Exact numerator/denominator polynomials (descending powers of s) of eq. 3.32-3.34 linearized.

    Input: motor force (N, handle space); output handle acceleration or motor
    position. Built from the polynomial impedance matrix M(s) X = [F, 0, 0]:
    the denominator is det M(s), the numerators the cofactors of its first row,
    which keeps the exact zeros (e.g. the two at the origin of the acceleration).
    """
    m = params.mechanics
    ku, bu = _user_impedance(params, grip_N)
    kl = linkage_stiffness_N_m(m, linkage)
    kc, bc, bl = m["k_c_N_m"], m["b_c_Ns_m"], m["b_l_Ns_m"]
    m11 = np.array([m["m_m_kg"], bc + m["b_m_Ns_m"], kc])
    m12 = np.array([-bc, -kc])
    m22 = np.array([m["m_d_kg"], bc + m["b_d_Ns_m"] + bl, kc + kl])
    m23 = np.array([-bl, -kl])
    m33 = np.array([m["m_h_kg"], bl + bu, kl + ku])
    P = np.polymul
    c11 = np.polysub(P(m22, m33), P(m23, m23))
    c13 = P(m12, m23)
    det = np.polysub(np.polysub(P(m11, c11), P(P(m12, m12), m33)), np.zeros(1))
    if output == "accel_m_s2":
        num = P(c13, [1.0, 0.0, 0.0])
    else:
        num = c11
    return np.trim_zeros(num, "f"), det


def linear_zpk(params, grip_N: float, output: str = "accel_m_s2", linkage: str = "small_signal"):
    """Zeros, poles (rad/s), gain and delay (s) of current (A) -> ``output``.

    Raises
    ------
    ValueError
        For an unknown output or a negative/non-finite grip.
    """
    if output not in OUTPUTS:
        raise ValueError(f"linear_model: output must be one of {OUTPUTS}, got {output!r}")
    if not (math.isfinite(grip_N) and grip_N >= 0):
        raise ValueError(f"linear_model: grip_N must be finite and >= 0, got {grip_N!r}")
    info = params.device_info()
    kf = info.force_per_amp_N_A
    if params.model == "nonlinear":
        num, den = nonlinear_tf(params, grip_N, output, linkage)
        z, p, k = signal.tf2zpk(num, den)
        z, p, k = np.asarray(z, dtype=complex), np.asarray(p, dtype=complex), float(k) * kf
        if output == "accel_m_s2":
            # the two zeros at the origin are exact (acceleration = s^2 * position)
            small = np.argsort(np.abs(z))[:2]
            z[small] = 0.0
    else:
        lti = params.lti
        zt, pt, kt = lti_transmission_zpk(lti)
        ku, bu = _user_impedance(params, grip_N)
        mh = lti["handle_mass_kg"]
        ph = np.roots([mh, bu, ku]).astype(complex)
        if output == "accel_m_s2":
            z = np.concatenate([zt, np.zeros(2, dtype=complex)])
        else:
            z = zt
        p = np.concatenate([pt, ph])
        k = kt * kf / mh
    z, p = _cancel(z, p)
    amp = params.amplifier
    if amp["kind"] == "lowpass":
        wa = 2 * math.pi * amp["bandwidth_hz"]
        p = np.append(p, -wa)
        k *= wa
    if output == "accel_m_s2":
        ws = 2 * math.pi * params.sensors["accel_bandwidth_hz"]
        p = np.append(p, -ws)
        k *= ws
    delay_s = 1.5 / info.servo_rate_hz
    return z, p, k, delay_s


def linear_model(params, grip_N: float = 2.0, output: str = "accel_m_s2", linkage: str = "small_signal"):
    """:class:`devices.model.ZpkModel` of current -> ``output`` (see :func:`linear_zpk`)."""
    z, p, k, delay_s = linear_zpk(params, grip_N, output, linkage)
    return ZpkModel(z, p, k, delay_s=delay_s, input="current_A", output=output, band_hz=(20.0, 1000.0),
                    grip_N=float(grip_N), source=f"analytic linearization of {params.name} ({params.source})")
