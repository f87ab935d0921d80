"""Settings every test shares."""

import os
import signal

# The simulated closed loop runs JIT-compiled in every test, whatever builds the user's cache holds, and no
# test starts a background build: tests/renderer/test_sim_aot.py builds the ahead-of-time loop itself and
# checks it against the JIT one tick for tick (renderer.sim_aot). HFAM_SIM_AOT=nobuild runs the suite on
# an existing build instead.
os.environ.setdefault("HFAM_SIM_AOT", "off")

# A suite started in the background by a non-interactive shell (``make test &``, some CI runners) inherits
# SIGINT ignored, and so would every command a test starts: Python then installs no KeyboardInterrupt
# handler and the Ctrl-C tests would send a signal nobody hears. A handler here is reset to the default
# in the children on exec, so they meet Ctrl-C as a user's terminal would deliver it.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


import pytest  # noqa: E402 (after the settings above, which must come first)


@pytest.fixture(scope="session")
def default_demo(tmp_path_factory):
    """The sim demo with its default settings (``make demo``'s taps, no figures), run once per session.

    Shared by the fidelity tests (tests/renderer/demo/test_demo_fidelity.py) and the README's printed table
    (tests/integration/test_readme_demo_table.py). Its own cache folder: built once (~15-40 s), then the taps.
    """
    from renderer.demo import config as demo_config, sim_demo
    from stimuli.hfam.pipeline import Progress

    out = tmp_path_factory.mktemp("default_demo")
    cfg = demo_config.DemoConfig()
    res = sim_demo.run_sim_demo(cfg, out, tmp_path_factory.mktemp("default_demo_cache"), figures=False,
                                progress=Progress(5, quiet=True))
    res.cfg, res.out = cfg, out
    return res


@pytest.fixture(scope="session")
def fake_hd(tmp_path_factory):
    """libfakehd.so, a fake OpenHaptics HD library (tests/devices/hardware/contract/fake_hd/fake_hd.c), compiled
    once: the Touch adapter's tests and its ``renderer run`` load it through ``$HFAM_OPENHAPTICS_LIB``."""
    import subprocess
    from pathlib import Path

    from plumbing import sysdeps

    from tests.support.needs import need

    need("cc")
    src = Path(__file__).resolve().parent / "devices" / "hardware" / "contract" / "fake_hd" / "fake_hd.c"
    out = tmp_path_factory.mktemp("fakehd") / "libfakehd.so"
    r = subprocess.run(["cc", "-shared", "-fPIC", "-O2", "-o", str(out), str(src), "-lpthread", "-lm"],
                       capture_output=True, text=True, timeout=60, env=sysdeps.tool_env())
    assert r.returncode == 0, r.stderr
    return out
