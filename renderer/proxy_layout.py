"""Array layout of the god-object proxy (``renderer.proxy``): the proxy's state vector; no numba.

``renderer.proxy`` (compiled) and ``renderer.law3`` / ``renderer.loop3`` (which build the arrays) share
these. They live apart from the proxy so that a 3-D simulated run whose loop was compiled ahead of time
(``renderer.sim_aot``) starts without importing numba (~0.3 s).
"""

from __future__ import annotations

#: how far outside the surface the proxy rests (m): far below an encoder count, far above rounding at 0.1 m
EPS_M = 1e-9
#: barycentric slack of the segment-triangle test: a segment through a shared edge hits one of its triangles
BARY_TOL = 1e-9

# ---- proxy state: position; constraints met; object; its normal, shaded normal and surface point;
# sliding (friction); the object it touched the tick before (+1, 0 for none)
(PS_PX, PS_PY, PS_PZ, PS_NC, PS_OBJ, PS_NX, PS_NY, PS_NZ, PS_SNX, PS_SNY, PS_SNZ, PS_SX, PS_SY, PS_SZ,
 PS_SLIP, PS_WAS) = range(16)
N_PS = 16
