"""Array layout of the 3-D servo law (``renderer.law3``): indices, tick outcome bits, log columns; no numba.

``renderer.law3`` (the compiled law) and ``renderer.loop3`` (which builds the arrays, reads the outcome
bits and the log) share these. They live apart from the law so that a 3-D simulated run whose loop was
compiled ahead of time (``renderer.sim_aot``) starts without importing numba (~0.3 s). The arrays are
described in ``renderer.law3``'s module doc.
"""

from __future__ import annotations

from .proxy_layout import N_PS

# ---- constants
(C_FC, C_FPK, C_INV_KF, C_MARGIN, C_HOLD_N, C_MOTOR, C_PLIM, C_MAX_BAD, C_WV, C_NRING, C_C_SHIFT, C_C_SCALE,
 C_CAP, C_TBUF, C_PO_DECAY, C_PO_LIMIT, C_HEAT, C_ALPHA, C_T_ATT, C_T_END, C_INV_SPAN, C_DEV_FPK, C_HOLD_K,
 C_HOLD_B, C_HOLD_ON, C_AMIN, C_AMAX, C_GMIN, C_GMAX, C_FS, C_SAME_MAX) = range(31)
N_C = 32
# ---- state
(W_ARMED, W_OUT_N, W_TJ, W_TLEN, W_GTH, W_EV_ON, W_EV_PEN, W_EV_ACC, W_EV_CLIP, W_CLOSED_PEN, W_CLOSED_ACC,
 W_CLOSED_CLIP, W_LX, W_LY, W_LZ, W_LAST_ACC, W_LAST_GRIP, W_NBAD, W_BAD_TOTAL, W_PI, W_PO, W_PNEW, W_N, W_LI,
 W_CODE, W_VX, W_VY, W_VZ, W_T, W_GRIP, W_PO_E, W_PO_F, W_PO_X, W_PO_U, W_TEMP, W_FLAGS, W_ENX, W_ENY, W_ENZ,
 W_LNX, W_LNY, W_LNZ, W_LSX, W_LSY, W_LSZ, W_EV_OBJ, W_HX, W_HY, W_S0X, W_S1X, W_S0Y, W_S1Y, W_S0Z, W_S1Z,
 W_PO_Y, W_PO_Z, W_TRING, W_SAME) = range(58)
W_PS = 64                       # the proxy's state (renderer.proxy_layout.PS_*)
W_RING = W_PS + N_PS            # three double-written rings (x, y, z), 2 nring each
CODE_OK, CODE_IMPACT, CODE_CLOSED, CODE_SENSOR, CODE_DISCONNECTED, CODE_UNSTABLE = 0, 1, 2, 4, 8, 16
STATUS_SENSOR_INVALID, STATUS_DISCONNECTED = 16, 32

LOG_COLUMNS = ("t_s", "x_m", "y_m", "z_m", "proxy_x_m", "proxy_y_m", "proxy_z_m", "penetration_m", "normal_x",
               "normal_y", "normal_z", "force_x_N", "force_y_N", "force_z_N", "force_wall_N", "force_transient_N",
               "contact_object", "clipped", "accel_m_s2", "grip_N", "temp_rise_K", "sensor_flags", "transient_x_N",
               "transient_y_N", "transient_z_N")
N_LOG = len(LOG_COLUMNS)
#: the log's integer channels and their dtype in a run's result and log.npz (the others are float64): the
#: contacted object's index (-1: none), the saturation bits, the sensor flags
LOG_INT_DTYPES = {"contact_object": "i2", "clipped": "u1", "sensor_flags": "u1"}
