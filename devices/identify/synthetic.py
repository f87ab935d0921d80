"""Synthetic swept-sine recordings from known LTI models (tests, benchmarks, offline checks)."""

from __future__ import annotations

import numpy as np

from ..model import ZpkModel
from .recording import Recording
from .sweep import SweepConfig, swept_sine


def synthetic_recording(accel_model: ZpkModel, position_model: ZpkModel | None, sweep: SweepConfig, *,
                        polarity: int = 1, accel_noise_m_s2: float = 0.0, accel_lsb_m_s2: float = 0.0,
                        position_noise_m: float = 0.0, position_lsb_m: float = 0.0, grip_N: float = 0.0,
                        seed: int = 0, trial: int = 0) -> Recording:
    """A recording of ``sweep`` through known models, with sensor noise and quantization.

    Parameters
    ----------
    accel_model, position_model : ZpkModel
        Current -> acceleration and current -> position (the latter may be
        None: position then stays zero plus noise).
    sweep : SweepConfig
    polarity : {1, -1}
    accel_noise_m_s2, position_noise_m : float
        Standard deviation of white Gaussian sensor noise.
    accel_lsb_m_s2, position_lsb_m : float
        Quantization step (0: none), applied after the noise (ADC / encoder).
    grip_N : float
        Constant grip written to the grip column.
    seed, trial : int

    Returns
    -------
    Recording
    """
    rng = np.random.default_rng(seed)
    u = swept_sine(sweep, polarity)
    t = np.arange(u.size) / sweep.fs_hz
    a = accel_model.simulate(u, sweep.fs_hz) + accel_noise_m_s2 * rng.standard_normal(u.size)
    x = (position_model.simulate(u, sweep.fs_hz) if position_model is not None else np.zeros_like(u))
    x = x + position_noise_m * rng.standard_normal(u.size)
    if accel_lsb_m_s2 > 0:
        a = np.round(a / accel_lsb_m_s2) * accel_lsb_m_s2
    if position_lsb_m > 0:
        x = np.round(x / position_lsb_m) * position_lsb_m
    meta = {"polarity": polarity, "grip_target_N": grip_N, "trial": trial, "device": "synthetic"}
    return Recording(sweep, t, u, a, x, np.full(u.size, float(grip_N)), meta)
