"""Real-time HFAM for teleoperation (thesis section 4.3.1, eq. 4.4-4.5).

Slave tip acceleration -> 15-point modified Bartlett-Hanning smoothing (7-sample delay) -> second-order
Butterworth high-pass at 22 Hz -> Tustin discretisation of the inverse of the identified
current-to-handle-acceleration model H_ha (made proper by added high-frequency zeros, right-half-plane
zeros reflected into the left half plane: same magnitude, stable causal inverse; real ones in the band
are the fit's stand-in for delay, so the gain's sign leaves a delay-like all-pass, +1 at DC) -> its own
saturation. The discrete inverse's frequency response is checked against the continuous one at start-up,
and what the inverse leaves of the model (the all-pass) must be delay-like in the band.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal
from scipy.signal import windows

import figstyle

from devices.identify.etfe import etfe
from devices.identify.fit import FitOptions, fit_etfes
from devices.identify.record import record_condition
from devices.identify.sweep import SweepConfig
from devices.model import ZpkModel
from devices.sim.device import SimDevice
from devices.sim.person import PRESCRIBED, Person
from devices.sim.teleop import Operator
from stimuli.hfam.inversion import make_proper

FIR_TAPS = 15
HIGHPASS_HZ = 22.0


@dataclass(frozen=True)
class HfamFilter:
    """The causal HFAM filter as the kernel runs it.

    Attributes
    ----------
    fir : ndarray (15,)
        Modified Bartlett-Hanning window, unit DC gain.
    sos : ndarray (n, 6)
        High-pass then inverse model, scipy ``sos`` layout.
    gain : float
        Overall gain on the filter output (A per A: 1 for exact matching).
    max_current_A : float
        Saturation of the HFAM channel, separate from the PD channel.
    check : dict
        Start-up check: max magnitude (dB) and phase (deg) error of discrete vs continuous inverse over
        22-1000 Hz, the number of reflected zeros (and of real ones in the band, treated as delay), added
        zeros, and the phase (deg) of model x continuous inverse / high-pass at 50 Hz (``allpass_phase_50hz_deg``:
        near 0 for a delay-like residual, near +-180 for an inverse of the wrong sign).
    """

    fir: np.ndarray
    sos: np.ndarray
    gain: float
    max_current_A: float
    check: dict


def bartlett_hann_fir(n: int = FIR_TAPS) -> np.ndarray:
    """The n-point modified Bartlett-Hanning window (section 4.3.1), normalised to unit DC gain.

    ``scipy.signal.windows.barthann(n)``, the same as MATLAB's ``barthannwin(n)``: its two end taps are zero,
    so 15 points smooth over 13 nonzero taps with the thesis' 7-sample delay. The alternative reading, 15
    nonzero taps (``barthann(17)`` without its ends), low-passes harder (at 5 kHz: -5.9 / -11.1 / -19.5 dB at
    300 / 400 / 500 Hz against -4.4 / -8.2 / -13.8 dB), and a third of a wood tap's 22-1000 Hz energy lies at
    300-600 Hz: even an exact inverse after it leaves a normalised RMS error of 0.57 (0.49 after this one).
    """

    w = windows.barthann(n)
    return w / w.sum()


def design_hfam(model: ZpkModel, fs_hz: float, *, max_current_A: float = 2.0, added_zero_hz: float = 1500.0,
                added_zero_zeta: float = 0.7, gain: float = 1.0) -> HfamFilter:
    """Causal real-time inverse of ``model`` (current -> handle acceleration) with the 22 Hz high-pass.

    Parameters
    ----------
    model : ZpkModel
        Identified H_ha (eq. 4.5); its pure delay is ignored (removed in the analysis).
    fs_hz : float
        Servo rate.
    max_current_A : float
        Saturation of the HFAM current.
    added_zero_hz, added_zero_zeta : float
        High-frequency zeros making the model proper (relative degree zero) before inversion.

    Returns
    -------
    HfamFilter
    """

    z = np.asarray(model.zeros_rad_s, complex)
    p = np.asarray(model.poles_rad_s, complex)
    rhp = z.real > 0
    n_rhp = int(np.sum(rhp))
    k = float(model.gain)
    # A fit with (almost) no pure delay represents the servo cycle's delay and the sensor lag by right-half-plane
    # zeros. Reflection (|s - z| = |s + conj(z)| on the jw axis) keeps the magnitude; what it leaves out is the
    # all-pass H / H_min. For a real zero a > 0 above the band's lower edge, (s - a) / (s + a) is -1 in the band
    # below a: left alone, the inverse would push the handle the wrong way there (the energy of tapping lies at
    # 100-600 Hz). Flipping the gain makes the residual all-pass (a - s) / (a + s): +1 at DC, a phase lag of
    # ~2/a s (first-order Pade of a delay), which the analysis removes with the pipeline delay. Complex pairs
    # reflect with unit all-pass at DC and at infinity; a real zero below the band is absorbed by the high-pass.
    delay_like = rhp & (np.abs(z.imag) <= 1e-9 * np.abs(z)) & (np.abs(z) > 2 * math.pi * HIGHPASS_HZ)
    n_delay_like = int(delay_like.sum())
    if n_delay_like % 2:
        k = -k
    z = np.where(rhp, -np.conj(z), z)
    # zeros at (or near) s = 0 of an acceleration model: the 22 Hz high-pass supplies s^2, so cancel them
    zero_at_dc = np.abs(z) < 2 * math.pi * 5.0   # far below the 22 Hz band: treated as s = 0
    n_dc = int(zero_at_dc.sum())
    z_rest = z[~zero_at_dc]
    zp, pp, kp, n_added = make_proper(z_rest, p, k, added_zero_hz, added_zero_zeta)
    # extra poles at s = 0 from the cancelled zeros belong to the inverse; combine with the high-pass s^2
    w = 2 * math.pi * HIGHPASS_HZ
    hp_poles = np.roots([1.0, math.sqrt(2.0) * w, w * w])
    if n_dc > 2:
        raise ValueError(f"H_ha has {n_dc} zeros at DC; at most 2 can be absorbed by the 22 Hz high-pass")
    # inverse: zeros <- model poles, poles <- model zeros; high-pass: s^2 / (s^2 + sqrt2 w s + w^2) with s^n_dc
    inv_z = np.concatenate([pp, np.zeros(2 - n_dc, complex)])
    inv_p = np.concatenate([zp, hp_poles])
    inv_k = 1.0 / kp
    # the continuous inverse, and its Tustin discretisation with prewarping at nothing (bilinear)
    zd, pd, kd = signal.bilinear_zpk(inv_z, inv_p, inv_k, fs_hz)
    if np.any(np.abs(pd) >= 1.0):
        raise ValueError("HFAM inverse is unstable after discretisation")
    sos = signal.zpk2sos(zd, pd, kd)
    f = np.geomspace(HIGHPASS_HZ, min(1000.0, 0.45 * fs_hz), 200)
    s = 2j * np.pi * f
    hc = inv_k * np.prod([s - q for q in inv_z], axis=0) / np.prod([s - q for q in inv_p], axis=0)
    _, hd = signal.sosfreqz(sos, worN=f, fs=fs_hz)
    # the Tustin map warps frequency; compare at the same physical frequency
    mag_db = 20 * np.log10(np.abs(hd) / np.abs(hc))
    ph = np.degrees(np.angle(hd / hc))
    # what the inverse leaves of the model at the bottom of the band: a delay-like all-pass is ~0 deg there
    s50 = 2j * math.pi * 50.0
    inv50 = inv_k * np.prod(s50 - inv_z) / np.prod(s50 - inv_p)
    hp50 = s50 * s50 / (s50 * s50 + math.sqrt(2.0) * w * s50 + w * w)
    allpass50 = inv50 * complex(model.frequency_response(np.array([50.0]))[0]) / hp50
    if abs(math.degrees(np.angle(allpass50))) > 90.0:
        raise ValueError(f"HFAM inverse has the wrong sign in the band (model x inverse at 50 Hz: "
                         f"{math.degrees(np.angle(allpass50)):.0f} deg)")
    check = {"max_mag_error_db": float(np.max(np.abs(mag_db))), "max_phase_error_deg": float(np.max(np.abs(ph))),
             "band_hz": [float(f[0]), float(f[-1])], "reflected_rhp_zeros": n_rhp,
             "delay_like_rhp_zeros": n_delay_like, "added_zeros": int(n_added),
             "allpass_phase_50hz_deg": float(math.degrees(np.angle(allpass50))),
             "sections": int(len(sos))}
    return HfamFilter(bartlett_hann_fir(), sos, gain, max_current_A, check)


def identify_master_hha(master_params, fs_hz: float, grip_N: float = 2.0, trials: int = 2,
                        operator: Operator | None = None) -> ZpkModel:
    """H_ha of the simulated master by the project's comprehensive identification (swept sine, ETFE, fit).

    H_ha includes the hand that holds the handle (section 4.2: the user's impedance shapes the
    current-to-handle-acceleration response), so on hardware the identification is run with the user who
    then teleoperates. ``operator`` does the same here: the identification's simulated person gets the
    teleoperation operator's grip (k_u, b_u at ``grip_N``), hand/arm mass and muscle impedance.

    Parameters
    ----------
    master_params : SimParams
        The simulated master (the identification only sees its sensors).
    fs_hz : float
        Servo rate of the teleoperator (the sweep runs at it).
    grip_N : float
        Grip during the sweep (the operator's grip impedance is taken to be the one at this grip).
    trials : int
        Swept-sine trials (half with reversed polarity).
    operator : Operator or None
        The teleoperation operator holding the master; None: the simulated device's default person.
    """
    params = master_params.replace(device={"servo_rate_hz": float(fs_hz)},
                                   simulation={"max_step_s": 1.0 / fs_hz / round(1.0 / fs_hz / 1e-5)})
    source = f"teleop master, grip {grip_N:g} N"
    if operator is not None:
        params = params.replace(user={"k_u_N_m": operator.k_u_N_m, "b_u_Ns_m": operator.b_u_Ns_m,
                                      "nominal_grip_N": float(grip_N)})
        source += ", held by the teleoperation operator"
    dev = SimDevice(params, seed=7)
    sweep = SweepConfig(amplitude_A=0.75, f_start_hz=5.0, f_end_hz=min(1000.0, 0.4 * fs_hz), duration_s=2.0,
                        fs_hz=fs_hz)
    if operator is None:
        recs = record_condition(dev, sweep, float(grip_N), trials)
    else:
        # the operator's hand/arm behind the grip (zero mass: the grip tied to a held position)
        # (and no fingertip: the teleoperation operator's grip impedance acts on the handle itself)
        hand = (Person(arm_mass_kg=operator.hand_mass_kg, muscle_stiffness_N_m=operator.muscle_k_N_m,
                       muscle_damping_Ns_m=operator.muscle_b_Ns_m, fingertip_mass_kg=0.0)
                if operator.hand_mass_kg > 0 else PRESCRIBED)
        dev.set_user(None, grip_N=float(grip_N), hand=hand)
        # grip None: record_condition would otherwise hand the handle to the default person before each trial
        recs = record_condition(dev, sweep, None, trials)
    curve = etfe(recs, "accel_m_s2", label=f"grip {grip_N:g} N")
    return fit_etfes([curve], FitOptions(), source=source, grip_N=float(grip_N)).model


def accel_match(slave_tip_m_s2: np.ndarray, master_handle_m_s2: np.ndarray, fs_hz: float,
                band_hz=(HIGHPASS_HZ, 1000.0), max_delay_s: float = 0.02) -> dict:
    """How well the master handle reproduces the slave tip acceleration (section 4.3.1, Figure 4.5).

    Both signals are band-passed (4th-order Butterworth, ``band_hz``), the master is shifted by the
    delay (0..``max_delay_s``) that maximises the correlation, then compared.

    Returns
    -------
    dict: ``correlation``, ``nrmse`` (RMS error / RMS of the tip), ``delay_s``, ``rms_ratio``
    (master / tip RMS), ``delay_samples``.
    """

    sos = signal.butter(4, [band_hz[0], min(band_hz[1], 0.45 * fs_hz)], btype="bandpass", fs=fs_hz, output="sos")
    a = signal.sosfilt(sos, np.asarray(slave_tip_m_s2, float))
    b = signal.sosfilt(sos, np.asarray(master_handle_m_s2, float))
    n = len(a)
    best_c, best_d = -2.0, 0
    for d in range(0, int(max_delay_s * fs_hz) + 1):
        x, y = a[:n - d], b[d:]
        sx, sy = np.std(x), np.std(y)
        c = float(np.mean((x - x.mean()) * (y - y.mean())) / (sx * sy)) if sx > 0 and sy > 0 else 0.0
        if c > best_c:
            best_c, best_d = c, d
    x, y = a[:n - best_d], b[best_d:]
    rms = float(np.sqrt(np.mean(x ** 2)))
    return {"correlation": best_c, "nrmse": float(np.sqrt(np.mean((y - x) ** 2)) / rms) if rms > 0 else float("nan"),
            "delay_s": best_d / fs_hz, "delay_samples": best_d,
            "rms_ratio": float(np.sqrt(np.mean(y ** 2)) / rms) if rms > 0 else float("nan")}


def _highpass(fs_hz: float) -> np.ndarray:
    """Section 4.3.1's high-pass: "a second-order linear filter with a bandwidth of 22 hertz" (Butterworth, sos)."""
    return signal.butter(2, HIGHPASS_HZ, btype="highpass", fs=fs_hz, output="sos")


def hfam_target(slave_tip_m_s2: np.ndarray, fs_hz: float) -> np.ndarray:
    """ã_st, the signal the master must replicate (eq. 4.4): the slave tip acceleration smoothed by the 15-point
    modified Bartlett-Hanning window and high-passed at 22 Hz, causally, as the HFAM channel computes it before
    the inverse model (section 4.3.1)."""
    a = np.convolve(np.asarray(slave_tip_m_s2, float), bartlett_hann_fir())[:len(slave_tip_m_s2)]
    return signal.sosfilt(_highpass(fs_hz), a)


def _match(ref: np.ndarray, x: np.ndarray, fs_hz: float, max_delay_s: float) -> dict:
    """``x`` against ``ref``: correlation, NRMSE (of ``ref``'s RMS), RMS ratio at the delay in 0..``max_delay_s``
    that maximises the correlation."""
    n = len(ref)
    best_c, best_d = -2.0, 0
    for d in range(0, int(max_delay_s * fs_hz) + 1):
        a, b = ref[:n - d], x[d:]
        sa, sb = np.std(a), np.std(b)
        c = float(np.mean((a - a.mean()) * (b - b.mean())) / (sa * sb)) if sa > 0 and sb > 0 else 0.0
        if c > best_c:
            best_c, best_d = c, d
    a, b = ref[:n - best_d], x[best_d:]
    rms = float(np.sqrt(np.mean(a ** 2)))
    return {"correlation": best_c, "nrmse": float(np.sqrt(np.mean((b - a) ** 2)) / rms) if rms > 0 else float("nan"),
            "delay_s": best_d / fs_hz, "delay_samples": best_d,
            "rms_ratio": float(np.sqrt(np.mean(b ** 2)) / rms) if rms > 0 else float("nan")}


def accel_match_target(slave_tip_m_s2: np.ndarray, master_handle_m_s2: np.ndarray, fs_hz: float,
                       max_delay_s: float = 0.02) -> dict:
    """HFAM scored against what it must replicate, eq. 4.4 ``ã_mh(t) = ã_st(t)``, and the smoothing's loss apart.

    ``match``: the master handle acceleration high-passed at 22 Hz (ã_mh) against :func:`hfam_target` (ã_st), the
    delay (0..``max_delay_s``) that maximises their correlation removed. ``smoothing_loss``: ã_st against the tip
    acceleration high-passed the same way without the smoothing: what the prescribed 15-point window (and its
    7-sample delay, removed) takes out before the inverse model sees the signal, which no inverse can restore.

    Returns
    -------
    dict
        ``match`` and ``smoothing_loss``, each ``correlation``, ``nrmse``, ``delay_s``, ``delay_samples``,
        ``rms_ratio``.
    """
    hp = _highpass(fs_hz)
    target = hfam_target(slave_tip_m_s2, fs_hz)
    master = signal.sosfilt(hp, np.asarray(master_handle_m_s2, float))
    tip = signal.sosfilt(hp, np.asarray(slave_tip_m_s2, float))
    return {"match": _match(target, master, fs_hz, max_delay_s),
            "smoothing_loss": _match(tip, target, fs_hz, max_delay_s)}


def figure_45(slave_tip_m_s2, master_handle_m_s2, fs_hz: float, delay_samples: int, path, title: str = "") -> None:
    """Figure 4.5-style plot: slave tip vs master handle acceleration (22-1000 Hz, delay removed), first impact;
    project style (figstyle: PNG, SVG, the plotted numbers as ``.plot.csv``)."""

    sos = signal.butter(4, [HIGHPASS_HZ, min(1000.0, 0.45 * fs_hz)], btype="bandpass", fs=fs_hz, output="sos")
    a = signal.sosfilt(sos, np.asarray(slave_tip_m_s2, float))
    b = signal.sosfilt(sos, np.asarray(master_handle_m_s2, float))
    i0 = int(np.argmax(np.abs(a) > 0.2 * np.max(np.abs(a))))
    lo, hi = max(0, i0 - int(0.01 * fs_hz)), min(len(a) - delay_samples, i0 + int(0.06 * fs_hz))
    t = (np.arange(lo, hi) - i0) / fs_hz * 1e3
    with figstyle.style() as plt:
        fig, ax = plt.subplots(figsize=figstyle.figsize("page", height_in=3.0), layout="constrained")
        ax.plot(t, a[lo:hi], label="slave tip")
        ax.plot(t, b[lo + delay_samples:hi + delay_samples],
                label=f"master handle (delay {delay_samples / fs_hz * 1e3:.1f} ms removed)")
        ax.set_xlabel("time (ms)")
        ax.set_ylabel("acceleration 22-1000 Hz (m/s^2)")
        ax.set_title(title, fontsize=8)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=6, borderaxespad=0.0)
        data = {"t_ms": t, "slave_tip_m_s2": a[lo:hi], "master_handle_m_s2": b[lo + delay_samples:hi + delay_samples]}
        figstyle.save(fig, path, data, force=True)   # the command's own folder
