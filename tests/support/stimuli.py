"""Test device models and synthetic tap recordings (the stimuli tests, the HFAM build's, the output checks')."""

from __future__ import annotations

import math

import numpy as np

from devices.model import ZpkModel
from stimuli.recordings import Tap

FS_HZ = 10000.0


def pair(f_hz: float, zeta: float) -> list[complex]:
    """Conjugate pole/zero pair of s^2 + 2 zeta w s + w^2 in rad/s."""
    w = 2 * math.pi * f_hz
    wd = w * math.sqrt(1 - zeta * zeta)
    return [complex(-zeta * w, wd), complex(-zeta * w, -wd)]


def _scaled(zeros, poles, at_hz: float, magnitude: float, **kw) -> ZpkModel:
    """Model with gain chosen so |H(j 2 pi at_hz)| = magnitude (m/s^2 per A)."""
    m = ZpkModel(zeros, poles, 1.0, **kw)
    k = magnitude / abs(m.frequency_response([at_hz])[0])
    return ZpkModel(zeros, poles, k, **kw)


def minimum_phase_model(grip_N: float = 2.0, resonance_hz: float = 129.0, delay_s: float = 1.5e-4) -> ZpkModel:
    """Held handle: accel/current with a hand spring (zeros at 0), resonance near 129 Hz, relative degree 2."""
    zeros = [0.0, -2 * math.pi * 5.0]
    poles = pair(resonance_hz, 0.15) + pair(30.0, 0.7) + [-2 * math.pi * 1500.0]
    return _scaled(zeros, poles, 200.0, 30.0, delay_s=delay_s, grip_N=grip_N)


def rhp_zero_model(grip_N: float = 4.0) -> ZpkModel:
    """Non-minimum-phase variant: an extra right-half-plane zero at 1.2 kHz (relative degree 2)."""
    zeros = [0.0, -2 * math.pi * 5.0, 2 * math.pi * 1200.0]
    poles = pair(129.0, 0.15) + pair(30.0, 0.7) + [-2 * math.pi * 1500.0]
    return _scaled(zeros, poles, 200.0, 30.0, grip_N=grip_N)


def synthetic_accel(v: float, t: np.ndarray) -> np.ndarray:
    """Wood-on-foam-like contact transient: two decaying modes whose amplitude grows with v."""
    a = 400.0 * v * np.exp(-t / 0.008) * np.sin(2 * np.pi * (140.0 + 150.0 * v) * t)
    a += 120.0 * v * np.exp(-t / 0.004) * np.sin(2 * np.pi * 320.0 * t)
    return np.where(t > 0, a, 0.0)


def synthetic_taps(velocities, fs_hz: float = FS_HZ, pre_s: float = 0.005, post_s: float = 0.1,
                   noise: float = 0.0, seed: int = 0) -> list[Tap]:
    rng = np.random.default_rng(seed)
    t = np.arange(-int(round(pre_s * fs_hz)), int(round(post_s * fs_hz)) + 1) / fs_hz
    return [Tap(i, float(v), t, synthetic_accel(v, t) + noise * rng.standard_normal(t.size))
            for i, v in enumerate(velocities)]


def write_taps_csv(path, taps) -> None:
    rows = ["tap,incoming_velocity_m_s,t_s,accel_m_s2"]
    for tp in taps:
        rows += [f"{tp.tap},{float(tp.v_in_m_s)!r},{float(t)!r},{float(a)!r}" for t, a in zip(tp.t_s, tp.accel_m_s2)]
    path.write_text("\n".join(rows) + "\n")
