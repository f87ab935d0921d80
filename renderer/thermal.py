"""First-order motor-winding thermal model (thesis section 4.4.2, ref. [38]).

The winding temperature rise ``T`` (K above ambient) obeys

    tau dT/dt = R_th * R_w * i(t)^2 - T

with winding resistance ``R_w`` (ohm), thermal resistance ``R_th`` (K/W) and
time constant ``tau`` (s) from :class:`devices.base.DeviceInfo`. The servo
loop integrates it exactly for a zero-order-hold current over one period:
``T <- T + (R_th R_w i^2 - T)(1 - exp(-dt/tau))``.

Transients are attenuated linearly from full strength at
``attenuate_frac * T_max`` to zero at ``end_frac * T_max`` (where they are
ended). The proportional channel is additionally limited to
:func:`safe_continuous_current` so that steady contact alone can never
push ``T`` past ``T_max``.
"""

from __future__ import annotations

import math

import numpy as np


def step_coefficients(info, dt_s: float) -> tuple[float, float]:
    """``(heat, alpha)``: steady-state rise per A^2 (K/A^2) and the per-tick blend ``1 - exp(-dt/tau)``."""
    heat = info.winding_resistance_ohm * info.thermal_resistance_K_W
    alpha = -math.expm1(-dt_s / info.thermal_time_constant_s)
    return heat, alpha


def safe_continuous_current(info, limit_A: float, margin: float = 0.95) -> float:
    """Continuous current (A) whose steady-state rise stays below ``margin * T_max``.

    Returns ``min(limit_A, sqrt(margin * T_max / (R_w R_th)))``.
    """
    heat = info.winding_resistance_ohm * info.thermal_resistance_K_W
    return min(limit_A, math.sqrt(margin * info.winding_max_temp_rise_K / heat))


def simulate_temperature(current_A, info, fs_hz: float, initial_K: float = 0.0):
    """Temperature rise (K) after each sample of a current record (numpy, offline/tests)."""
    heat, alpha = step_coefficients(info, 1.0 / fs_hz)
    out = np.empty(len(current_A))
    t = initial_K
    for k, i in enumerate(np.asarray(current_A, dtype=float)):
        t += (heat * i * i - t) * alpha
        out[k] = t
    return out
