"""The on-device renderer the firmware runs (emulated in Python; mirrored in ``firmware/hfam_fw.c``).

Per firmware tick, from raw sensor values only (what a microcontroller
has): encoder count -> handle position, a backward-difference velocity over a
short window, wall current (proportional + damping, thesis Fig. 2.5 / 4.9),
a contact-triggered transient overlaid for its duration (section 4.4.2), two
saturation levels (steady-state wall current at the continuous limit, wall +
transient at the peak limit, Fig. 4.9), and a contact event per tap
(incoming velocity, grip, max penetration, peak acceleration, clipping)
reported when the handle re-arms above ``wall height + re-arm margin``.

A first-order winding thermal model (I^2 R heating, section 3.1.3 and [38] as
cited in 4.4.2) runs on board too: above ``THERMAL_ATTENUATE_FRAC`` of the
allowed temperature rise the output is scaled down linearly, reaching zero at
``THERMAL_END_FRAC`` (the renderer's defaults), and OVER_TEMPERATURE is reported.

The wall's passivity observer (Hannaford & Ryu 2002, as ``renderer.passivity`` on the host; protocol 1.1)
runs in the same integer arithmetic as the C firmware (:meth:`FirmwareRenderer._observe`): the net energy
the wall channel generated, in Q16 ampere x encoder count, with a leak; above the host's limit the
rendering stops with zero output (``unstable``, reported as FAULT + UNSTABLE) until CLEAR_FAULTS.

Plain scalar Python, no numpy in :meth:`FirmwareRenderer.tick` and no
allocation per tick apart from the event dict at the end of a contact.
"""

from __future__ import annotations

import bisect
import math

from ..hardware import wire_protocol as P
from ..hardware.calibration import Calibration

THERMAL_ATTENUATE_FRAC = 0.7
THERMAL_END_FRAC = 0.9

# the C firmware's fixed point (devices/firmware/hfam_fw.c): saturation of its 32-bit values, the observer's bounds
SAT = 0x3FFFFFFF
PO_PEN_MAX = 1 << 22  # Q8 counts
PO_U_MAX = 1 << 29  # Q16 A count
PO_DX_MAX = 8191  # counts per tick


def sat_round(f: float) -> int:
    """The firmware's float -> int32 conversion: rounded half away from zero (lroundf), saturated at +/-1e9."""
    if f > 1e9:
        return 1_000_000_000
    if f < -1e9:
        return -1_000_000_000
    return int(math.floor(f + 0.5)) if f >= 0 else -int(math.floor(-f + 0.5))


def po_clamp_q8(lim_q24: int, k_q24: int) -> int:
    """The wall's clamp penetration F_c / k in Q8 counts, as the firmware's ``po_clamp_q8``."""
    if k_q24 <= 0:
        return PO_PEN_MAX
    lim = min(max(lim_q24, 0), 0xFFFFFF)
    return min((lim * 256 + k_q24 // 2) // k_q24, PO_PEN_MAX)


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


class FirmwareRenderer:
    """Wall + transient rendering at the firmware's own rate (one :meth:`tick` per servo period).

    Parameters
    ----------
    position_resolution_m : float
        Handle travel per encoder count (eq. 3.2-3.4).
    force_per_amp_N_A : float
        rho*k_t/h (eq. 3.17).
    fs_hz : float
        Firmware servo rate.
    amplifier_A : float
        The amplifier's hard limit; uploaded limits are clamped to it.
    max_table_samples : int
        Memory budget for sampled transients (table or re-arm buffer), in float samples.
    velocity_window : int
        Backward-difference window in ticks for the velocity estimate.
    """

    def __init__(self, position_resolution_m: float, force_per_amp_N_A: float, fs_hz: float, amplifier_A: float,
                 max_table_samples: int = 200_000, velocity_window: int = 10, thermal=None) -> None:
        self.res = position_resolution_m
        self.fpa = force_per_amp_N_A
        self.fs = fs_hz
        self.dt = 1.0 / fs_hz
        self.amplifier_A = amplifier_A
        self.max_table_samples = max_table_samples
        self.cal = Calibration()
        # wall
        self.height_m = 0.0
        self.k = 0.0
        self.b = 0.0
        self.rearm_m = 0.001
        # passivity observer (protocol 1.1; off until a WALL carries a limit): fixed point as the firmware
        self._h_q8 = 0
        self._k_q = 0
        self._lim_q = 0
        self._po_ds = PO_PEN_MAX
        self._po_limit = 0
        self._po_leak_m = 0
        self._po_leak_sh = 0
        self.po_e = 0  # the observer's energy, Q16 A count (1 A count = force_per_amp * resolution J)
        self._po_u = 0
        self._po_f = 0
        self._po_x16 = 0
        self._po_fresh = True
        self.unstable = False  # latched when the observer stopped the rendering; clear_unstable() (CLEAR_FAULTS)
        # limits (continuous for the wall alone, peak for wall + transient)
        self.cont_A = 0.0
        self.peak_A = 0.0
        # transient
        self.kind = P.TRANSIENT_NONE
        self.param_amp = 0.0
        self.param_dur_s = 0.0
        self.param_freq = 0.0
        self.param_n = 0
        self.table = None  # (vels, grips, n_s, flat list, gain, max_extrapolation)
        self._pending_table = None
        self.rearm_active: list[float] = []
        self.rearm_back: list[float] = []
        # velocity ring buffer
        self._win = max(1, int(velocity_window))
        self._ring = [0.0] * self._win
        self._ring_t = [0] * self._win  # t_us of each sample: a late (skipped) tick widens the window
        self._tick_us = 1e6 / fs_hz
        self._ring_i = 0
        self._filled = 0
        self.reset_contact()
        self.events: list[dict] = []
        self.n_events = 0
        self.watchdog_during_event = False  # set by the firmware loop when its watchdog trips mid-contact
        self.clipping = False
        self.velocity_m_s = 0.0
        # thermal: (R_w * R_th, 1 - exp(-dt/tau), T_max) or None
        self.temp_rise_K = 0.0
        self.over_temperature = False
        if thermal is not None:
            r_w, r_th, tau, t_max = thermal
            self._heat = r_w * r_th
            self._alpha = -math.expm1(-self.dt / tau)
            self._t_att = THERMAL_ATTENUATE_FRAC * t_max
            self._t_end = THERMAL_END_FRAC * t_max
        else:
            self._heat = 0.0
            self._alpha = 0.0
            self._t_att = self._t_end = math.inf

    # -- configuration (from host frames) -----------------------------------
    def set_wall(self, height_m: float, stiffness_N_m: float, damping_N_s_m: float, rearm_margin_m: float,
                 instability_limit_J: float = 0.0, instability_leak: float = 0.0) -> None:
        """WALL frame: the horizontal wall and its proportional + damping law (thesis Fig. 2.5).

        Parameters
        ----------
        height_m : float
            Wall height (m); contact when the handle is below it.
        stiffness_N_m, damping_N_s_m : float
            Wall stiffness (N/m) and damping (N s/m), both >= 0.
        rearm_margin_m : float
            The handle must rise this far above the wall (m) before the next contact counts.
        instability_limit_J, instability_leak : float
            The passivity observer (protocol 1.1): stop once the wall generated more than this (J; 0: off),
            leaking ``instability_leak = 1 - exp(-T / window)`` of it per tick (0 <= leak < 1).

        Raises
        ------
        ProtocolError
            A value is not finite, or stiffness, damping, margin or limit is negative, or the leak is not in
            [0, 1) (the firmware NAKs).
        """
        if not _finite(height_m, stiffness_N_m, damping_N_s_m, rearm_margin_m, instability_limit_J,
                       instability_leak) or stiffness_N_m < 0 or damping_N_s_m < 0 or rearm_margin_m < 0 \
                or instability_limit_J < 0 or not 0.0 <= instability_leak < 1.0:
            raise P.ProtocolError("WALL needs finite height and non-negative stiffness, damping and re-arm margin"
                                  " (and an observer limit >= 0 and leak in [0, 1))")
        self.height_m, self.k, self.b, self.rearm_m = height_m, stiffness_N_m, damping_N_s_m, rearm_margin_m
        # the firmware's fixed point (hfam_fw.c MSG_WALL): height Q8 counts, stiffness Q24 A per count
        self._h_q8 = sat_round(height_m * 256.0 / self.res)
        self._k_q = sat_round(stiffness_N_m * (self.res / self.fpa) * 16777216.0)
        self._po_ds = po_clamp_q8(self._lim_q, self._k_q)
        limit = leak_m = leak_sh = 0
        if instability_limit_J > 0:
            limit = max(1, sat_round(instability_limit_J * 65536.0 / (self.fpa * self.res)))  # Q16 A count
            leak_m, leak_sh = sat_round(instability_leak * 16777216.0), 1
            if leak_m > 65535:
                leak_m, leak_sh = sat_round(instability_leak * 65536.0), 0
            leak_m = min(leak_m, 65535)
        self._po_limit, self._po_leak_m, self._po_leak_sh = limit, leak_m, leak_sh
        self.po_e = 0
        self._po_fresh = True

    @property
    def instability_limit_q16(self) -> int:
        """The observer's limit as the firmware holds it (Q16 A count; 0: off)."""
        return self._po_limit

    def clear_unstable(self) -> None:
        """CLEAR_FAULTS: forget an observer trip and start it afresh (the energy that tripped it is gone)."""
        self.unstable = False
        self.po_e = 0
        self._po_fresh = True

    def set_limits(self, continuous_A: float, peak_A: float) -> None:
        """LIMITS frame: the wall alone at ``continuous_A``, wall + transient at ``peak_A`` (A; Fig. 4.9).

        Both are clamped to the amplifier limit. Raises ProtocolError unless ``0 <= continuous <= peak``.
        """
        if not _finite(continuous_A, peak_A) or continuous_A < 0 or peak_A < continuous_A:
            raise P.ProtocolError("LIMITS need 0 <= continuous <= peak")
        self.cont_A = min(continuous_A, self.amplifier_A)
        self.peak_A = min(peak_A, self.amplifier_A)
        self._lim_q = sat_round(self.cont_A * 16777216.0)
        self._po_ds = po_clamp_q8(self._lim_q, self._k_q)

    def set_param_transient(self, kind: int, p0: float, p1: float, p2: float, p3: float) -> None:
        """Pulse: p0 = amplitude N*s/m (gain included), p1 = width s (eq. 4.7).
        Sinusoid: p0 = amplitude N*s/m, p1 = duration s, p2 = frequency Hz (eq. 4.8). None: kind 0."""
        if kind == P.TRANSIENT_NONE:
            self.kind = kind
            return
        if kind not in (P.TRANSIENT_PULSE, P.TRANSIENT_SINUSOID) or not _finite(p0, p1, p2, p3) or p0 < 0 or p1 <= 0:
            raise P.ProtocolError(f"TRANSIENT_PARAM kind {kind} with parameters {(p0, p1, p2, p3)} is not valid")
        if kind == P.TRANSIENT_SINUSOID and not 0 < p2 < self.fs / 2:
            raise P.ProtocolError(f"TRANSIENT_PARAM sinusoid frequency {p2} Hz not below Nyquist {self.fs / 2} Hz")
        self.kind = kind
        self.param_amp, self.param_dur_s, self.param_freq = p0, p1, p2
        self.param_n = int(math.floor(p1 * self.fs + 1e-9))

    def table_begin(self, vels, grips, n_s: int, fs: float, gain: float, max_extrapolation: float) -> None:
        """TABLE_BEGIN frame: announce an HFAM table (velocity x grip levels, ``n_s`` samples each, section 4.4.2).

        Parameters
        ----------
        vels, grips : sequence of float
            Increasing incoming-velocity (m/s, > 0) and grip (N) levels.
        n_s : int
            Samples per transient.
        fs : float
            Sample rate of the table (Hz); must equal the firmware rate.
        gain : float
            Output gain applied to every transient.
        max_extrapolation : float
            Largest factor by which a transient is scaled beyond the highest velocity level (>= 1).

        Raises
        ------
        MemoryError
            The table exceeds ``max_table_samples``.
        ProtocolError
            Wrong rate, or levels not increasing.
        """
        if n_s * len(vels) * len(grips) > self.max_table_samples:
            raise MemoryError(f"table of {n_s * len(vels) * len(grips)} samples exceeds {self.max_table_samples}")
        if abs(fs - self.fs) > 1e-3 * self.fs:
            raise P.ProtocolError(f"table sample rate {fs} Hz differs from the firmware rate {self.fs} Hz")
        if any(b <= a for a, b in zip(vels, vels[1:])) or any(b <= a for a, b in zip(grips, grips[1:])) \
                or vels[0] <= 0 or not _finite(gain, max_extrapolation):
            raise P.ProtocolError("table levels must be increasing and velocities > 0")
        self._pending_table = (list(vels), list(grips), n_s, [0.0] * (n_s * len(vels) * len(grips)), gain,
                               max(1.0, max_extrapolation), [False])

    def table_data(self, offset: int, samples) -> None:
        """TABLE_DATA frame: ``samples`` (A) at ``offset`` of the announced table; ProtocolError if outside or NaN/inf."""
        t = self._pending_table
        if t is None or offset + len(samples) > len(t[3]):
            raise P.ProtocolError(f"TABLE_DATA at offset {offset} outside the announced table")
        if not _finite(*samples):
            raise P.ProtocolError(f"TABLE_DATA at offset {offset} contains NaN/inf")
        t[3][offset:offset + len(samples)] = samples
        if offset + len(samples) == len(t[3]):
            t[6][0] = True

    def table_commit(self) -> None:
        """TABLE_COMMIT frame: switch to the uploaded table; ProtocolError before the whole table arrived."""
        t = self._pending_table
        if t is None or not t[6][0]:
            raise P.ProtocolError("TABLE_COMMIT before the whole table arrived")
        self.table = t[:6]
        self._pending_table = None
        self.kind = P.TRANSIENT_TABLE

    def rearm_data(self, offset: int, samples) -> None:
        """REARM_DATA frame: ``samples`` (A) at ``offset`` of the back buffer of the re-armed transient.

        Raises MemoryError beyond ``max_table_samples`` and ProtocolError for NaN/inf samples.
        """
        if offset + len(samples) > self.max_table_samples:
            raise MemoryError("re-arm buffer too large")
        if not _finite(*samples):
            raise P.ProtocolError(f"REARM_DATA at offset {offset} contains NaN/inf")
        back = self.rearm_back
        if len(back) < offset + len(samples):
            back.extend([0.0] * (offset + len(samples) - len(back)))
        back[offset:offset + len(samples)] = samples

    def rearm_commit(self, n_samples: int) -> None:
        """Swap the re-armed buffer in (only between contacts, so a playing transient is never torn)."""
        if n_samples > len(self.rearm_back):
            raise P.ProtocolError(f"REARM_COMMIT of {n_samples} samples but only {len(self.rearm_back)} uploaded")
        self._rearm_ready = self.rearm_back[:n_samples]
        self.rearm_back = []
        self.kind = P.TRANSIENT_REARM

    def reset_contact(self) -> None:
        """Forget any contact in progress: not armed until the handle is seen above the re-arm height."""
        self.armed = False  # becomes True once the handle is seen above the re-arm height
        self.in_event = False
        self.trans_k = 0
        self.trans_n = 0
        self.trans_scale = 0.0
        self._rearm_ready = getattr(self, "_rearm_ready", None)
        self._active_buf = None
        self._tw = None
        # a fresh observer (RENDER_START); an UNSTABLE trip stays latched until clear_unstable()
        self.po_e = 0
        self._po_f = 0
        self._po_fresh = True

    # -- one servo tick ---------------------------------------------------------
    def tick(self, t_us: int, encoder: int, accel_raw: int, grip_raw: int) -> float:
        """Return the motor current (A) for this tick; may append a finished event to ``self.events``."""
        if self.unstable:  # stopped by the passivity observer: no rendering, zero output
            return 0.0
        cal = self.cal
        x = cal.encoder_sign * (encoder - cal.encoder_zero_counts) * self.res
        ring = self._ring
        i = self._ring_i
        old = ring[i]
        ring[i] = x
        ticks = round(((t_us - self._ring_t[i]) & 0xFFFFFFFF) / self._tick_us)
        self._ring_t[i] = t_us
        self._ring_i = i + 1 if i + 1 < self._win else 0
        if self._filled < self._win:  # no velocity until the window has filled once
            self._filled += 1
            v = 0.0
        elif ticks == self._win or ticks <= 0:
            v = (x - old) / (self._win * self.dt)
        else:  # ticks were skipped (a firmware tick overran): divide by the time that passed
            v = (x - old) * self.fs / ticks
        self.velocity_m_s = v
        h = self.height_m
        pen = h - x
        if self._rearm_ready is not None and not self.in_event and self.trans_k >= self.trans_n:
            self.rearm_active = self._rearm_ready
            self._rearm_ready = None
        # contact detection (threshold crossing, section 4.4.2)
        if pen > 0.0 and self.armed:
            self.armed = False
            grip = (grip_raw - cal.grip_offset_counts) * cal.grip_scale_N_per_count
            self._start_event(t_us, -v if v < 0.0 else 0.0, grip)
        elif not self.armed and pen < -self.rearm_m:
            self.armed = True
            if self.in_event:
                self._finish_event()
        # wall: proportional + damping, pushes only, steady-state limit
        i_cmd = 0.0
        clipped = False
        if pen > 0.0:
            f = self.k * pen - self.b * v
            if f > 0.0:
                i_cmd = f / self.fpa
                if i_cmd > self.cont_A:
                    i_cmd = self.cont_A
                    clipped = True
        if self._po_limit:  # passivity observer: in the firmware's integers, on its own fixed-point inputs
            counts = encoder - cal.encoder_zero_counts
            xc = -counts if cal.encoder_sign < 0 else counts
            pen_q8 = self._h_q8 - xc * 256
            ip = 0
            if pen_q8 > 0:
                k = self._k_q
                ip = min((k * pen_q8) >> 8, SAT)  # k * pen before the clamp (Q24 A), as the firmware: exact
            f_q24 = self._lim_q if clipped else sat_round(i_cmd * 16777216.0)
            if self._observe(xc, pen_q8, ip, f_q24):
                i_cmd = 0.0
                clipped = False
                self.trans_n = self.trans_k
                if self.in_event:
                    self._finish_event()
        # transient overlay
        if self.trans_k < self.trans_n:
            i_cmd += self._transient_sample(self.trans_k)
            self.trans_k += 1
        if i_cmd > self.peak_A:
            i_cmd = self.peak_A
            clipped = True
        elif i_cmd < -self.peak_A:
            i_cmd = -self.peak_A
            clipped = True
        temp = self.temp_rise_K
        if temp > self._t_att:  # protect the winding: fade out between the attenuate and end temperatures
            self.over_temperature = True
            i_cmd *= max(0.0, (self._t_end - temp) / (self._t_end - self._t_att))
        else:
            self.over_temperature = False
        self.temp_rise_K = temp + (self._heat * i_cmd * i_cmd - temp) * self._alpha
        self.clipping = clipped
        if self.in_event:
            if pen > self.ev_pen:
                self.ev_pen = pen
            a = abs((accel_raw - cal.accel_offset_counts) * cal.accel_scale_m_s2_per_count)
            if a > self.ev_peak:
                self.ev_peak = a
            if clipped:
                self.ev_clipped = True
        return i_cmd

    def _observe(self, x: int, pen: int, ip: int, f: int) -> bool:
        """One step of the wall's passivity observer, the firmware's ``po_step`` integer for integer.

        ``x`` position (counts), ``pen`` penetration (Q8 counts), ``ip`` k * pen before the clamp (Q24 A, 0
        outside), ``f`` this tick's wall current (Q24 A, 0 .. continuous limit). Energies in Q16 A count.
        Returns True (and latches ``unstable``) when the energy exceeds the limit.
        """
        u = 0
        if pen > 0:
            s, m = ip, min(pen, PO_PEN_MAX)  # U = s m / 2, m = 2 pen - min(pen, d_s) (Q8 counts)
            if s > self._lim_q:
                s = self._lim_q
                m = max(m + m - self._po_ds, 0)
            s16 = (s >> 8) & 0xFFFF
            if m < 1 << 17:
                u = (s16 * ((m >> 1) & 0xFFFF)) >> 8
            else:
                u = min(s16 * (((m >> 8) & 0xFFFF) >> 1), PO_U_MAX)
        x16 = x & 0xFFFF
        if self._po_fresh:
            self._po_fresh = False
            self._po_x16 = x16
            self._po_u = u
        dx = (x16 - self._po_x16) & 0xFFFF
        if dx >= 0x8000:
            dx -= 0x10000
        dx = max(-PO_DX_MAX, min(PO_DX_MAX, dx))
        e = self.po_e
        lk = (e >> 16) * self._po_leak_m
        if self._po_leak_sh:
            lk >>= 8
        e += dx * self._po_f + (u - self._po_u) - lk
        top = e >> 24
        if top >= 0x40:
            e = SAT
        elif top < -0x40:
            e = -SAT
        self.po_e = e
        self._po_x16 = x16
        self._po_u = u
        self._po_f = (f >> 8) & 0xFFFF
        if e > self._po_limit:
            self.unstable = True
            return True
        return False

    def _start_event(self, t_us: int, v_in: float, grip: float) -> None:
        if self.in_event:  # re-contact before re-arm cannot happen (armed is False), kept for safety
            self._finish_event()
        self.in_event = True
        self.ev_t_us = t_us
        self.ev_v = v_in
        self.ev_grip = grip
        self.ev_pen = 0.0
        self.ev_peak = 0.0
        self.ev_clipped = False
        self.ev_kind = self.kind
        self.trans_k = 0
        kind = self.kind
        if kind == P.TRANSIENT_PULSE or kind == P.TRANSIENT_SINUSOID:
            self.trans_n = self.param_n
            self.trans_scale = self.param_amp * v_in / self.fpa
        elif kind == P.TRANSIENT_TABLE:
            self._tw = self._table_weights(v_in, grip)
            self.trans_n = self.table[2]
        elif kind == P.TRANSIENT_REARM:
            self._active_buf = self.rearm_active
            self.trans_n = len(self._active_buf)
        else:
            self.trans_n = 0

    def _finish_event(self) -> None:
        self.in_event = False
        self.n_events += 1
        self.events.append({"t_us": self.ev_t_us, "incoming_velocity_m_s": self.ev_v, "grip_N": self.ev_grip,
                            "max_penetration_m": self.ev_pen, "peak_accel_m_s2": self.ev_peak,
                            "clipped": self.ev_clipped, "kind": self.ev_kind, "index": self.n_events,
                            "watchdog": self.watchdog_during_event})
        self.watchdog_during_event = False

    def _transient_sample(self, k: int) -> float:
        kind = self.ev_kind
        if kind == P.TRANSIENT_PULSE:
            return self.trans_scale
        if kind == P.TRANSIENT_SINUSOID:
            t = (k + 1) * self.dt
            return (self.trans_scale * math.exp(math.log(0.01) * t / self.param_dur_s)
                    * math.sin(2.0 * math.pi * self.param_freq * t))
        if kind == P.TRANSIENT_TABLE:
            data = self.table[3]
            total = 0.0
            for offset, w in self._tw:
                total += w * data[offset + k]
            return total
        if kind == P.TRANSIENT_REARM:
            return self._active_buf[k]
        return 0.0

    def _table_weights(self, v: float, g: float) -> list[tuple[int, float]]:
        """Bilinear velocity x grip weights, same rules as ``stimuli.HfamLibrary.weights`` (section 4.4.2)."""
        vels, grips, n_s, _, gain, max_extra = self.table
        scale = gain
        last = len(vels) - 1
        if v <= vels[0]:
            i0 = i1 = 0
            wv = 0.0
            scale *= v / vels[0]
        elif v >= vels[last]:
            i0 = i1 = last
            wv = 0.0
            scale *= min(v / vels[last], max_extra)
        else:
            i1 = bisect.bisect_right(vels, v)
            i0 = i1 - 1
            wv = (v - vels[i0]) / (vels[i1] - vels[i0])
        glast = len(grips) - 1
        if not g == g or g <= grips[0]:
            j0 = j1 = 0
            wg = 0.0
        elif g >= grips[glast]:
            j0 = j1 = glast
            wg = 0.0
        else:
            j1 = bisect.bisect_right(grips, g)
            j0 = j1 - 1
            wg = (g - grips[j0]) / (grips[j1] - grips[j0])
        n_g = len(grips)
        pairs = [((i0 * n_g + j0) * n_s, scale * (1 - wv) * (1 - wg)), ((i0 * n_g + j1) * n_s, scale * (1 - wv) * wg),
                 ((i1 * n_g + j0) * n_s, scale * wv * (1 - wg)), ((i1 * n_g + j1) * n_s, scale * wv * wg)]
        return [p for p in pairs if p[1] != 0.0]
