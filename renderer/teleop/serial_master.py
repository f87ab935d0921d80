"""Teleoperation with a real master over the serial link; slave and environment stay simulated on the host.

The host loop runs at the master's streaming rate (1 kHz with the firmware emulator): read the master
state, advance the simulated slave + controller by one tick in the compiled kernel (external-master
mode), command the master's current. Round trips (command sent -> state received) are timed. When the
link dies the master output is zero and the slave holds its position (``P_LINK_LOST_TICK``).
"""

from __future__ import annotations

import math
import time

import numpy as np

from devices.base import DeviceError, Status
from devices.sim import teleop_kernel as K
from devices.sim.teleop import CimmModel, Testbed

from .session import SessionResult, TeleopConfig, controller_params


def run_serial_session(dev, tb: Testbed, cfg: TeleopConfig, duration_s: float, *, cimm: CimmModel | None = None,
                       hold_after_loss_s: float = 0.2) -> tuple[SessionResult, dict]:
    """Run position-force teleoperation with ``dev`` (an open Device) as the master.

    Parameters
    ----------
    dev : devices.base.Device
        Open master device in streaming mode; ``tb.servo_rate_hz`` must equal its servo rate.
    tb : Testbed
        Slave, environment and sensors (its master parameters are unused).
    cfg : TeleopConfig
    duration_s : float

    Returns
    -------
    result : SessionResult
    timing : dict
        ``rate_hz`` (achieved), ``round_trip_p50_ms``, ``round_trip_p99_ms``, ``late_ticks`` (ticks whose
        read + compute + command took longer than one period), ``link_lost_tick`` (or None).
    """
    fs = tb.servo_rate_hz
    if abs(dev.info.servo_rate_hz - fs) > 1e-6 * fs:
        raise ValueError(f"master runs at {dev.info.servo_rate_hz} Hz but the teleoperator at {fs} Hz")
    n = int(round(duration_s * fs))
    p = tb.pack(cimm if cfg.controller == "pf+cimm" else None)
    controller_params(p, tb, cfg)
    kf = dev.info.force_per_amp_N_A
    p[K.P_KF_M] = kf
    p[K.P_IMAX_M] = dev.info.current_amplifier_A
    st = dev.read()
    s = tb.initial_state(st.position_m, cfg.mu)
    rs = np.array([np.uint64(0x9E3779B97F4A7C15)], dtype=np.uint64)
    path = np.zeros(n + int(hold_after_loss_s * fs) + 1)
    stroke = np.zeros_like(path)
    out = np.zeros((len(path), K.N_OUT))
    rtt = np.full(len(path), np.nan)
    t_next = time.perf_counter()
    late = 0
    lost = None
    fault, fault_tick = 0, -1
    k = 0
    t_first = time.perf_counter()
    t_sent = t_first  # set after every command; read on the next tick
    while k < n or (lost is not None and k < lost + int(hold_after_loss_s * fs)):
        if k >= len(path):
            break
        t_tick = time.perf_counter()
        if lost is None:
            if k > 0:
                try:
                    st = dev.read()
                except DeviceError:
                    st = None
                rtt[k] = time.perf_counter() - t_sent
                if st is None or st.status & Status.DISCONNECTED:
                    lost = k
                    p[K.P_LINK_LOST_TICK] = float(k)
            if st is not None and lost is None:
                out[k, K.O_XM] = st.position_m
                out[k, K.O_AM] = st.accel_m_s2
            else:
                out[k, K.O_XM] = out[k - 1, K.O_XM]
        else:
            out[k, K.O_XM] = out[k - 1, K.O_XM]
        fault, fault_tick = K.run_session(p, s, rs, path, stroke, out, k, k + 1, 1)
        i_m = out[k, K.O_IM] if fault == 0 and lost is None else 0.0
        if lost is None:
            t_sent = time.perf_counter()
            dev.command(float(i_m) if math.isfinite(i_m) else 0.0)
        if time.perf_counter() - t_tick > 1.0 / fs:
            late += 1
        if fault:
            break
        k += 1
        t_next += 1.0 / fs
        while time.perf_counter() < t_next:
            pass
    if lost is None:
        try:
            dev.command(0.0)
        except DeviceError:
            pass
    wall = time.perf_counter() - t_first
    valid = rtt[np.isfinite(rtt)]
    timing = {"rate_hz": k / wall if wall > 0 else float("nan"),
              "round_trip_p50_ms": float(np.percentile(valid, 50) * 1e3) if len(valid) else None,
              "round_trip_p99_ms": float(np.percentile(valid, 99) * 1e3) if len(valid) else None,
              "late_ticks": late, "ticks": k, "link_lost_tick": lost}
    res = SessionResult(out[:max(k, 1)], fs, np.array([], dtype=np.int64), int(fault), int(fault_tick),
                        {"master_clip_ticks": int(s[K.S_CLIP_M]), "slave_clip_ticks": int(s[K.S_CLIP_S]),
                         "hfam_clip_ticks": 0, "nan_ticks": int(s[K.S_NAN])})
    return res, timing
