"""Array layout of the servo law (``renderer.law``): indices, tick outcome bits, log columns; no numba.

``renderer.law`` (the compiled law) and ``renderer.loop`` (which builds the arrays, reads the outcome
bits and the log) share these. They live apart from the law so that a simulated run whose loop was
compiled ahead of time (``renderer.sim_aot``) starts without importing numba (~0.3 s). The arrays
are described in ``renderer.law``'s module doc.
"""

from __future__ import annotations

# the simulated device's Python-side vector that run_sim advances (devices.sim.SimDevice.fused_state)
from devices.sim.layout import (  # noqa: F401 -- re-exported for renderer.law
    D_ACC,
    D_GRIP,
    D_HELD,
    D_LAST,
    D_LIMIT,
    D_PERIOD,
    D_POS,
    D_REJECTED,
    D_STATUS,
    D_T,
    D_TICK,
    D_USER_TICK,
    HOT_STATUS,
    N_DEV,
)

# ---- constants
(C_K, C_DAMP, C_MARGIN, C_HOLD_N, C_KF, C_INV_KF, C_MOTOR, C_TGAIN, C_IC, C_IPK, C_IAMP, C_HEAT, C_ALPHA,
 C_T_ATT, C_T_END, C_INV_SPAN, C_PLIM, C_ALIM, C_GMIN, C_GMAX, C_MAX_BAD, C_WV, C_NRING, C_C_SHIFT,
 C_C_SCALE, C_CAP, C_NOBJ, C_TBUF, C_PO_DECAY, C_PO_LIMIT, C_PO_FC, C_FS, C_SAME_MAX) = range(33)
C_OBJ = 40
OBJ_STRIDE = 8

# ---- state
(W_TEMP, W_GTH, W_ARMED, W_OUT_N, W_TJ, W_TLEN, W_EV_ON, W_EV_PEN, W_EV_ACC, W_EV_CLIP, W_LAST_POS,
 W_LAST_ACC, W_LAST_GRIP, W_NBAD, W_BAD_TOTAL, W_S0, W_S1, W_PI, W_PO, W_PNEW, W_N, W_LI, W_CODE, W_VEL,
 W_D, W_NZ, W_FLAGS, W_CLOSED_PEN, W_CLOSED_ACC, W_CLOSED_CLIP, W_T, W_GRIP, W_PO_E, W_PO_F, W_PO_X, W_PO_U,
 W_TRING, W_SAME) = range(38)
W_RING = 40

# tick outcome bits: an impact fired, an open event closed, or a stop (sensors, disconnect, an active wall)
CODE_OK, CODE_IMPACT, CODE_CLOSED, CODE_SENSOR, CODE_DISCONNECTED, CODE_UNSTABLE = 0, 1, 2, 4, 8, 16
STATUS_SENSOR_INVALID, STATUS_DISCONNECTED = 16, 32

LOG_COLUMNS = ("t_s", "position_m", "velocity_m_s", "penetration_m", "force_prop_N", "force_transient_N",
               "current_A", "clipped", "accel_m_s2", "grip_N", "temp_rise_K", "sensor_flags")
N_LOG = len(LOG_COLUMNS)

# ---- homing (renderer.law.run_homing, for renderer.homing.HomingController on the simulated device): one
# vector of the PD's constants (set once per run) and its state (read and written, tick after tick)
(H_HOME, H_SURFACE, H_ARMED_LEVEL, H_KP, H_KD, H_INV_FPA, H_IMAX, H_ALPHA, H_INV_DT, H_N, H_NMIN, H_TOL,
 H_VTOL, H_PLIM, H_ALIM, H_MAX_BAD, H_FMAX, H_FPA, H_RUN_DIST, H_RUN_SPEED, H_DECAY, H_ELIMIT, H_HEAT,
 H_THERM_ALPHA, H_UNTIL_SETTLED, H_CHECK_EVERY,
 H_TICK, H_X_PREV, H_X, H_V, H_DX, H_ERR, H_F_PREV, H_AWAY, H_AWAY_MAX, H_ARMED, H_CONTACTS, H_TEMP, H_E,
 H_PEAK, H_STORED, H_BAD_ROW, H_BAD_TOTAL) = range(43)
N_HOMING = 43
# why run_homing returned: its ticks ran out (the chunk or the run: H_TICK says which), a stop of the
# module doc of renderer.homing, or a tick whose until() the caller checks (H_CHECK_EVERY)
(HOME_RAN, HOME_DISCONNECTED, HOME_SENSOR, HOME_UNSTABLE, HOME_RUNAWAY, HOME_CHECK, HOME_SETTLED) = range(7)
