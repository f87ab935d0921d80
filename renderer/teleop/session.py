"""Teleoperation controllers and sessions on the simulated testbed (thesis sections 4.3, 5.1-5.7).

Controllers: ``pd`` (bilateral position-position PD), ``pd+hfam`` (PD plus high-frequency
acceleration matching, section 4.3.1), ``pf`` (position-force with mu, lambda and the stabilisers b,
K_mu, K_lambda of section 5.4) and ``pf+cimm`` (position-force with cancellation of induced master
motion, eq. 5.20). Settling time and stability are defined once here (docs/teleop.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np
from scipy.signal import butter, sosfiltfilt

from devices.sim import teleop_kernel as K
from devices.sim.teleop import CimmModel, Testbed, tap_path
from plumbing.validation import require_choice, require_number, require_positive

CONTROLLERS = ("pd", "pd+hfam", "pf", "pf+cimm")

# ---- definitions shared by docs/teleop.md, the sweep and the tests ----
CONTACT_THRESHOLD_N = 0.05       # the tip is "in contact" when the measured force exceeds this
SETTLE_BAND = 0.10               # settled: force within 10 % of its quasi-static value ...
SETTLE_FLOOR_N = 0.05            # ... or within this absolute band, whichever is larger
QS_WINDOW_S = (0.20, 0.30)       # reported quasi-static value: median of the low-passed force 200-300 ms after impact
QS_CUTOFF_HZ = 8.0               # quasi-static force: zero-phase low-pass at the user's 8 Hz bandwidth
GRACE_S = 0.030                  # contact breaks in the first 30 ms after impact are the impact's own bounce
ANALYSIS_END_S = 0.30            # analysis window after impact (inside the 0.4 s dwell)

# Contact classification of one tap, calibrated on Figure 5.10's words (section 5.7.2): "settles" (contact
# held, the transient decays: lambda = 1, "decay in about 50 ms"), "buzzes" (contact held, "the contact
# transient is prolonged to over 100 ms ... a slight buzzing on impact": lambda = 3) and "make-break" ("the
# slave makes and breaks contact with the environment several times": lambda = 6).
BUZZ_S = 0.100                   # a held contact whose transient lasts longer than this buzzes
# The count is of the losses after the impact's own bounce (GRACE_S, 30 ms): the slave's natural impact, with no
# feedback loop that could be unstable, bounces within those 30 ms on the rule's servo; the project's "stable"
# definition already lets the impact's own bounce pass there.
MAKE_BREAK_LOSSES = 2            # contact lost this often later than GRACE_S after the impact: make-break
CONTACT_CLASSES = ("settles", "buzzes", "make-break")

# Servo gains from one rule (docs/teleop.md, "Gains"): every PD servo on a joystick (the slave in both
# architectures, the master in bilateral PD) is a second-order loop on that joystick's moving mass
# (m_m + m_d + m_h in handle space) with its natural frequency at the user's motion-control bandwidth,
# "from steady state to about eight hertz" (sections 5.5.2, 5.6.2: the voluntary motion the slave must
# track lies below it) and damping ratio 0.7 (the quickest response without ringing). The thesis gives
# no slave or master gains (section 5.7.2: "proportional and derivative feedback on the slave").
SERVO_BANDWIDTH_HZ = 8.0
SERVO_DAMPING_RATIO = 0.7
# Force-feedback saturation (Figure 5.10 plots "the saturated force feedback signal"): the thesis's
# "maximum feedback force" is the force that deflects its user model by 2 mm (section 5.7.1:
# q_u = 3.125e13 N/m^5 "tuned to allow only two millimeters of deflection at maximum feedback force"),
# with the linear part k_u = 40 N/m (Table 3.1): 40 * 0.002 + 3.125e13 * 0.002**5 = 1.08 N.
FF_MAX_N = 40.0 * 0.002 + 3.125e13 * 0.002 ** 5


def servo_gains(mass_kg: float, natural_hz: float = SERVO_BANDWIDTH_HZ,
                damping_ratio: float = SERVO_DAMPING_RATIO) -> tuple[float, float]:
    """PD gains of a second-order servo on a mass: k = m w^2, b = 2 zeta m w (w = 2 pi f_n).

    Parameters
    ----------
    mass_kg : float
        Moving mass in handle space (kg).
    natural_hz, damping_ratio : float
        Natural frequency (Hz) and damping ratio of the closed loop.

    Returns
    -------
    (kp_N_m, kd_Ns_m) : tuple of float
    """
    w = 2 * math.pi * natural_hz
    return mass_kg * w * w, 2 * damping_ratio * mass_kg * w


def joystick_mass_kg(params) -> float:
    """Moving mass of a joystick in handle space, m_m + m_d + m_h (Table 3.1: 0.032 kg)."""
    m = params.mechanics
    return m["m_m_kg"] + m["m_d_kg"] + m["m_h_kg"]


@dataclass(frozen=True)
class TeleopConfig:
    """Controller settings of a session.

    Attributes
    ----------
    controller : str
        One of ``CONTROLLERS``.
    mu, lam : float
        Position scale and force-feedback gain (section 5.1).
    kp_s_N_m, kd_s_Ns_m : float or None
        Slave PD gains on the motor position; None (default): :func:`servo_gains` of the slave's moving
        mass at ``servo_bandwidth_hz`` (the rule of docs/teleop.md, "Gains"; resolved by
        :func:`resolve_gains`).
    kp_m_N_m, kd_m_Ns_m : float or None
        Master PD gains (bilateral PD only); None: the same rule on the master's moving mass.
    servo_bandwidth_hz : float
        Natural frequency of the rule's servos (Hz; default ``SERVO_BANDWIDTH_HZ``, 8 Hz, the user's
        motion-control bandwidth); damping ratio ``SERVO_DAMPING_RATIO``. Explicit gains override it.
    ff_max_N : float
        Position-force: saturation of the force feedback F_f (N; 0 = none); default ``FF_MAX_N``.
    b_Ns_m : float
        Master damping (eq. 5.9), position-force only.
    k_mu_hz, k_lambda_hz : float
        First-order low-pass corner of the position-command filter K_mu (eq. 5.10) and of the
        force-feedback filter K_lambda (eq. 5.11); 0 = filter off.
    master_pd_lowpass_hz : float
        Bilateral PD only: first-order low-pass corner on the master's PD force (0 = off). With HFAM the PD
        is the low-frequency power band and HFAM the information band above ~20 Hz (section 4.3.1,
        Figure 4.2); unfiltered, the master PD pulls back the handle motion HFAM creates.
    velocity_hz : float
        Low-pass corner of the backward-difference velocity estimates.
    divergence_m, divergence_m_s : float
        Safety: |x_s - x_c| or a speed beyond these stops the session with zero output.
    """

    controller: str = "pf"
    mu: float = 1.0
    lam: float = 1.0
    kp_s_N_m: float | None = None
    kd_s_Ns_m: float | None = None
    kp_m_N_m: float | None = None
    kd_m_Ns_m: float | None = None
    servo_bandwidth_hz: float = SERVO_BANDWIDTH_HZ
    ff_max_N: float = FF_MAX_N
    b_Ns_m: float = 0.0
    k_mu_hz: float = 0.0
    k_lambda_hz: float = 0.0
    master_pd_lowpass_hz: float = 0.0
    velocity_hz: float = 500.0
    divergence_m: float = 0.03
    divergence_m_s: float = 3.0

    def __post_init__(self) -> None:
        require_choice("controller", self.controller, CONTROLLERS)
        require_positive(self, "mu", "divergence_m", "divergence_m_s", "velocity_hz", "servo_bandwidth_hz")
        for name in ("kp_s_N_m", "kd_s_Ns_m", "kp_m_N_m", "kd_m_Ns_m"):
            if getattr(self, name) is not None:
                require_number(name, getattr(self, name), minimum=0.0)
        if self.kp_s_N_m is not None:
            require_positive(self, "kp_s_N_m")
        for name in ("lam", "b_Ns_m", "k_mu_hz", "k_lambda_hz", "master_pd_lowpass_hz", "ff_max_N"):
            require_number(name, getattr(self, name), minimum=0.0)


def resolve_gains(cfg: TeleopConfig, tb: Testbed) -> TeleopConfig:
    """``cfg`` with every unset servo gain replaced by :func:`servo_gains` of its joystick's moving mass at
    ``cfg.servo_bandwidth_hz`` and damping ratio ``SERVO_DAMPING_RATIO``.

    Parameters
    ----------
    cfg : TeleopConfig
    tb : Testbed
        Supplies the slave's and the master's mechanics.

    Returns
    -------
    TeleopConfig
        With numbers in ``kp_s_N_m``, ``kd_s_Ns_m``, ``kp_m_N_m``, ``kd_m_Ns_m`` (run.json records them).
    """
    ks, bs = servo_gains(joystick_mass_kg(tb.slave), cfg.servo_bandwidth_hz)
    km, bm = servo_gains(joystick_mass_kg(tb.master), cfg.servo_bandwidth_hz)
    return replace(cfg, kp_s_N_m=ks if cfg.kp_s_N_m is None else cfg.kp_s_N_m,
                   kd_s_Ns_m=bs if cfg.kd_s_Ns_m is None else cfg.kd_s_Ns_m,
                   kp_m_N_m=km if cfg.kp_m_N_m is None else cfg.kp_m_N_m,
                   kd_m_Ns_m=bm if cfg.kd_m_Ns_m is None else cfg.kd_m_Ns_m)


@dataclass
class SessionResult:
    """Traces and counters of one session.

    Attributes
    ----------
    traces : ndarray (n_ticks, N_OUT)
        Columns ``devices.sim.teleop_kernel.O_*`` (time s, positions m, forces N, accelerations m/s^2,
        currents A).
    fs_hz : float
    impact_ticks : ndarray of int
        Nominal surface crossings of the operator's path.
    fault : int
        0 none, 1 NaN, 2 divergence (``teleop_kernel.FAULT_*``); ``fault_tick`` where it stopped.
    counts : dict
        Clip counts of master, slave and HFAM currents; NaN count.
    """

    traces: np.ndarray
    fs_hz: float
    impact_ticks: np.ndarray
    fault: int
    fault_tick: int
    counts: dict = field(default_factory=dict)

    def col(self, idx: int) -> np.ndarray:
        """One trace column, cut at a fault."""
        n = self.fault_tick + 1 if self.fault else len(self.traces)
        return self.traces[:n, idx]


def controller_params(p: np.ndarray, tb: Testbed, cfg: TeleopConfig, hfam=None) -> None:
    """Write the controller part of the parameter array ``p`` (in place)."""
    fs = tb.servo_rate_hz
    cfg = resolve_gains(cfg, tb)
    p[K.P_FF_MAX] = cfg.ff_max_N
    p[K.P_MODE] = K.MODE_PD if cfg.controller.startswith("pd") else K.MODE_PF
    p[K.P_MU], p[K.P_LAM] = cfg.mu, cfg.lam
    p[K.P_KPS], p[K.P_KDS], p[K.P_KPM], p[K.P_KDM] = cfg.kp_s_N_m, cfg.kd_s_Ns_m, cfg.kp_m_N_m, cfg.kd_m_Ns_m
    p[K.P_VEL_A] = 1 - math.exp(-2 * math.pi * cfg.velocity_hz / fs)
    p[K.P_BDAMP] = cfg.b_Ns_m
    p[K.P_KMU_A] = 1 - math.exp(-2 * math.pi * cfg.k_mu_hz / fs) if cfg.k_mu_hz > 0 else 1.0
    p[K.P_KLAM_A] = 1 - math.exp(-2 * math.pi * cfg.k_lambda_hz / fs) if cfg.k_lambda_hz > 0 else 1.0
    p[K.P_MPD_A] = 1 - math.exp(-2 * math.pi * cfg.master_pd_lowpass_hz / fs) if cfg.master_pd_lowpass_hz > 0 else 1.0
    p[K.P_DIV_POS], p[K.P_DIV_VEL] = cfg.divergence_m, cfg.divergence_m_s
    if cfg.controller == "pd+hfam":
        if hfam is None:
            raise ValueError("controller pd+hfam needs the HFAM filter (renderer.teleop.hfam.design_hfam)")
        p[K.P_HF_ON] = 1.0
        p[K.P_HF_GAIN] = hfam.gain
        p[K.P_HF_IMAX] = hfam.max_current_A
        p[K.P_FIR:K.P_FIR + K.N_FIR] = hfam.fir
        sos = np.asarray(hfam.sos)
        if len(sos) > K.MAX_SOS:
            raise ValueError(f"HFAM filter has {len(sos)} sections, at most {K.MAX_SOS}")
        p[K.P_HF_NSOS] = len(sos)
        for q, row in enumerate(sos):
            b0, b1, b2, a0, a1, a2 = row
            p[K.P_SOS + 5 * q:K.P_SOS + 5 * q + 5] = (b0 / a0, b1 / a0, b2 / a0, a1 / a0, a2 / a0)


def run_session(tb: Testbed, cfg: TeleopConfig, path_m: np.ndarray, *, cimm: CimmModel | None = None,
                hfam=None, stroke_m: np.ndarray | None = None, seed: int = 1,
                link_lost_tick: int | None = None, impact_ticks=None,
                initial_velocity_m_s: float = 0.0, push_from_tick: int = 0) -> SessionResult:
    """Run one session on the simulated testbed (all in one compiled call).

    Parameters
    ----------
    tb : Testbed
    cfg : TeleopConfig
    path_m : ndarray (n,)
        Operator's voluntary path in master handle space (m), one value per servo tick.
    cimm : CimmModel or None
        Required for ``pf+cimm``.
    hfam : HfamFilter or None
        Required for ``pd+hfam``.
    stroke_m : ndarray (n,) or None
        Tangential coordinate along the texture (m) per tick.
    link_lost_tick : int or None
        Simulate loss of the master link from this tick: master output zero, slave holds.
    impact_ticks : array of int or None
        Ticks of the nominal impacts (the taps :func:`session_metrics` splits at).
    initial_velocity_m_s : float
        Master (and operator) velocity at the start (m/s, up); the slave starts tracking it.
    push_from_tick : int
        Tick from which the operator's constant push (``Operator.push_N``) acts.

    Returns
    -------
    SessionResult
    """
    if cfg.controller == "pf+cimm" and cimm is None:
        raise ValueError("controller pf+cimm needs a CIMM model")
    use_cimm = cimm if cfg.controller == "pf+cimm" else None
    p = tb.pack(use_cimm)
    controller_params(p, tb, cfg, hfam)
    if link_lost_tick is not None:
        p[K.P_LINK_LOST_TICK] = float(link_lost_tick)
    p[K.P_PUSH_TICK] = float(push_from_tick)
    path = np.ascontiguousarray(path_m, dtype=np.float64)
    n = len(path)
    stroke = np.zeros(n) if stroke_m is None else np.ascontiguousarray(stroke_m, dtype=np.float64)
    s = tb.initial_state(float(path[0]), cfg.mu, initial_velocity_m_s)
    rs = np.array([np.uint64(0x9E3779B97F4A7C15 ^ (seed * 0x2545F4914F6CDD1D % (1 << 64)) or 1)], dtype=np.uint64)
    out = np.zeros((n, K.N_OUT))
    fault, fault_tick = K.run_session(p, s, rs, path, stroke, out, 0, n, 0)
    counts = {"master_clip_ticks": int(s[K.S_CLIP_M]), "slave_clip_ticks": int(s[K.S_CLIP_S]),
              "hfam_clip_ticks": int(s[K.S_CLIP_HF]), "nan_ticks": int(s[K.S_NAN])}
    return SessionResult(out, tb.servo_rate_hz, np.asarray(impact_ticks if impact_ticks is not None else []),
                         int(fault), int(fault_tick), counts)


# ---------------------------------------------------------------- analysis (docs/teleop.md)
@dataclass(frozen=True)
class TapMetrics:
    """Contact-transient metrics of one tap (definitions in docs/teleop.md).

    Attributes
    ----------
    impact_s : float
        First time the measured force exceeds ``CONTACT_THRESHOLD_N`` (session time, s).
    settling_s : float
        Time from the impact until the force stays within max(10 % of F_qs(t), 0.05 N) of F_qs(t) up to
        ``ANALYSIS_END_S`` (inf if it never does); F_qs(t) is :func:`quasi_static` of the force.
    quasi_static_N : float
        Median of F_qs 200-300 ms after the impact.
    breaks : int
        Contact losses (force below threshold for >= 1 ms) later than 30 ms after the impact.
    stable : bool
        No such contact loss, settled within the window, no fault.
    hf_energy_fraction : float
        Fraction of F_f's energy above 50 Hz in the first 100 ms after impact.
    contact_losses : int
        Contact losses (force below threshold for >= 1 ms) from the impact to the end of the analysis
        window, the impact's own bounce included (``breaks`` leaves out the first ``GRACE_S``).
    contact_class : str
        :func:`classify_contact` of the losses after the impact's bounce (``breaks``): ``"settles"``,
        ``"buzzes"`` or ``"make-break"``.
    oscillation_N : float
        Largest |F - F_qs| later than ``GRACE_S`` after the impact, in the analysis window (N): the oscillation
        the static contact force ``quasi_static_N`` must outweigh for contact to hold.
    """

    impact_s: float
    settling_s: float
    quasi_static_N: float
    breaks: int
    stable: bool
    hf_energy_fraction: float
    contact_losses: int = 0
    contact_class: str = "settles"
    oscillation_N: float = float("nan")


def classify_contact(contact_losses: int, settling_s: float) -> str:
    """One tap's contact, in Figure 5.10's words (section 5.7.2).

    Parameters
    ----------
    contact_losses : int
        Contact losses later than ``GRACE_S`` (30 ms) after the impact (``TapMetrics.breaks``: the impact's own
        bounce left out).
    settling_s : float
        Settling time of the contact force (s; inf if it never settles in the window).

    Returns
    -------
    str
        ``"make-break"`` if contact was lost ``MAKE_BREAK_LOSSES`` (2) or more times ("makes and breaks
        contact with the environment several times"); otherwise ``"buzzes"`` if the transient lasts longer
        than ``BUZZ_S`` (100 ms: "prolonged to over 100 ms ... a slight buzzing"); otherwise ``"settles"``.
    """
    if contact_losses >= MAKE_BREAK_LOSSES:
        return "make-break"
    if not settling_s <= BUZZ_S:
        return "buzzes"
    return "settles"


def _count_losses(force_N: np.ndarray, fs_hz: float) -> int:
    """Runs of >= 1 ms with the force at or below ``CONTACT_THRESHOLD_N``."""
    low = np.concatenate(([False], np.asarray(force_N) <= CONTACT_THRESHOLD_N, [False])).astype(np.int8)
    edges = np.diff(low)                       # +1 where a run of low samples starts, -1 after it ends
    lengths = np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)
    return int(np.count_nonzero(lengths >= max(1, int(0.001 * fs_hz))))


def tap_metrics(force_N: np.ndarray, ff_N: np.ndarray, fs_hz: float, start: int, stop: int,
                fault: bool = False) -> TapMetrics | None:
    """Settling time and stability of one tap's contact-force transient (blind: force traces only).

    Parameters
    ----------
    force_N : ndarray
        Measured slave tip force (N, positive = pushed up by the environment).
    ff_N : ndarray
        Force applied at the master motor (N).
    fs_hz : float
    start, stop : int
        Sample range of the tap (from before its impact to the end of its dwell).
    fault : bool
        The session stopped on a fault inside this range.

    Returns
    -------
    TapMetrics or None (no contact in the range)
    """
    f = force_N[start:stop]
    above = np.flatnonzero(f > CONTACT_THRESHOLD_N)
    if len(above) == 0:
        return None
    i0 = int(above[0])
    n_end = min(len(f), i0 + int(ANALYSIS_END_S * fs_hz))
    fqs_t = quasi_static(f, fs_hz)
    w0, w1 = i0 + int(QS_WINDOW_S[0] * fs_hz), i0 + int(QS_WINDOW_S[1] * fs_hz)
    fqs = float(np.median(fqs_t[w0:min(w1, len(f))])) if w0 < len(f) else float("nan")
    seg = f[i0:n_end]
    ref = fqs_t[i0:n_end]
    band = np.maximum(SETTLE_BAND * np.abs(ref), SETTLE_FLOOR_N)
    outside = np.flatnonzero(np.abs(seg - ref) > band)
    if len(outside) == 0:
        settle = 0.0
    elif outside[-1] >= len(seg) - int(0.02 * fs_hz):
        settle = math.inf
    else:
        settle = (outside[-1] + 1) / fs_hz
    # contact breaks after the impact's own bounce (stability and classification), and all losses from the impact on
    breaks = _count_losses(seg[int(GRACE_S * fs_hz):], fs_hz)
    losses = _count_losses(seg, fs_hz)
    ff = ff_N[start + i0:start + min(len(f), i0 + int(0.1 * fs_hz))]
    hf = hf_energy_fraction(ff, fs_hz)
    stable = (breaks == 0) and math.isfinite(settle) and not fault
    cls = "make-break" if fault else classify_contact(breaks, settle)
    late = np.abs(seg - ref)[int(GRACE_S * fs_hz):]
    osc = float(np.max(late)) if late.size else float("nan")
    return TapMetrics(start / fs_hz + i0 / fs_hz, settle, fqs, breaks, stable, hf, losses, cls, osc)


def quasi_static(force_N: np.ndarray, fs_hz: float) -> np.ndarray:
    """Quasi-static force: zero-phase 2nd-order Butterworth low-pass at ``QS_CUTOFF_HZ`` (the user's
    voluntary bandwidth, section 5.6.2); the contact transient is what lies outside it."""
    if len(force_N) < 30:
        return np.asarray(force_N, dtype=float)
    return sosfiltfilt(_quasi_static_sos(float(fs_hz)).copy(), force_N)


@lru_cache(maxsize=None)
def _quasi_static_sos(fs_hz: float) -> np.ndarray:
    """The low-pass of :func:`quasi_static` at ``fs_hz``: designed once per rate (a sweep measures thousands of
    taps at one rate; the design took a third of each tap's metrics). The caller filters with a copy."""
    return butter(2, QS_CUTOFF_HZ, fs=fs_hz, output="sos")


def hf_energy_fraction(x: np.ndarray, fs_hz: float, f_cut_hz: float = 50.0) -> float:
    """Fraction of the energy of ``x`` (mean removed, Hann window) above ``f_cut_hz``."""
    if len(x) < 8:
        return float("nan")
    x = (x - np.mean(x)) * np.hanning(len(x))
    X = np.abs(np.fft.rfft(x)) ** 2
    f = np.fft.rfftfreq(len(x), 1 / fs_hz)
    tot = X.sum()
    return float(X[f > f_cut_hz].sum() / tot) if tot > 0 else 0.0


def session_metrics(res: SessionResult) -> list[TapMetrics | None]:
    """:func:`tap_metrics` for every tap of a session (split at the path's surface crossings)."""
    fe = res.traces[:, K.O_FE]
    ff = res.traces[:, K.O_FF]
    n_valid = res.fault_tick + 1 if res.fault else len(fe)
    ticks = list(res.impact_ticks) + [len(fe)]
    out = []
    for j in range(len(ticks) - 1):
        a = max(0, int(ticks[j]) - int(0.02 * res.fs_hz))
        b = min(int(ticks[j + 1]) - int(0.02 * res.fs_hz), a + int((ANALYSIS_END_S + 0.15) * res.fs_hz))
        if a >= n_valid:
            out.append(None)
            continue
        out.append(tap_metrics(fe[:n_valid], ff[:n_valid], res.fs_hz, a, min(b, n_valid),
                               fault=bool(res.fault) and b >= n_valid))
    return out


#: how far below the surface the operator's path presses (m): the thesis gives none ("the user tapped repeatedly on
#: the environment, as though trying to explore its surface", section 5.7.2); the sweeps also run 3 and 4 mm
PRESS_DEPTH_M = 0.002
#: the press depths of the sweeps' press-depth column (m)
PRESS_DEPTHS_M = (0.002, 0.003, 0.004)


def default_path(fs_hz: float, mu: float, n_taps: int = 10, speed_m_s: float = 0.1,
                 press_depth_m: float = PRESS_DEPTH_M, **kw):
    """Ten taps of the operator, scaled so the slave descends ``10 mm`` and presses ``press_depth_m`` (default
    ``PRESS_DEPTH_M``, 2 mm) below the surface (path, crossings)."""
    return tap_path(n_taps, fs_hz, speed_m_s=speed_m_s, approach_m=0.01 / mu, press_m=press_depth_m / mu, **kw)
