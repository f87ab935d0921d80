"""Settings every test shares."""

import os

# The simulated closed loop runs JIT-compiled in every test, whatever builds the user's cache holds, and no
# test starts a background build: tests/renderer/test_sim_aot.py builds the ahead-of-time loop itself and
# checks it against the JIT one tick for tick (renderer.sim_aot). HFAM_SIM_AOT=nobuild runs the suite on
# an existing build instead.
os.environ.setdefault("HFAM_SIM_AOT", "off")
