"""Settings every test shares."""

import gc
import os
import signal

# The simulated closed loop runs JIT-compiled in every test, whatever builds the user's cache holds, and no
# test starts a background build: tests/renderer/test_sim_aot.py builds the ahead-of-time loop itself and
# checks it against the JIT one tick for tick (renderer.sim_aot). HFAM_SIM_AOT=nobuild runs the suite on
# an existing build instead.
os.environ.setdefault("HFAM_SIM_AOT", "off")

# One BLAS thread in the test processes and in every process they start, as the commands have
# (plumbing.dispatch; a user's own setting stays): `make test` runs a worker per core, and OpenBLAS's worker for
# the other core spins after each call waiting for work, on the core the other test worker needs. Measured on
# 2 cores: the successive-isolation, model and report tests took 81 s of CPU with OpenBLAS's default, 63 s
# with one thread, and less wall time. Set before anything imports numpy (its BLAS reads it once, on load).
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

# A suite started in the background by a non-interactive shell (``make test &``, some CI runners) inherits
# SIGINT ignored, and so would every command a test starts: Python then installs no KeyboardInterrupt
# handler and the Ctrl-C tests would send a signal nobody hears. A handler here is reset to the default
# in the children on exec, so they meet Ctrl-C as a user's terminal would deliver it.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
# Likewise SIGHUP under ``nohup``: ignored, it would stay ignored in every command a test starts, and the
# commands rightly keep an ignored SIGHUP (plumbing.stopsignals), so the SIGHUP tests would see nothing happen.
# This process keeps ignoring it (a handler that does nothing); its children start with the default.
if hasattr(signal, "SIGHUP") and signal.getsignal(signal.SIGHUP) is signal.SIG_IGN:
    signal.signal(signal.SIGHUP, lambda signum, frame: None)


import importlib.util  # noqa: E402 (after the settings above, which must come first)

import pytest  # noqa: E402

from tests.support import cpuprofile, parallel  # noqa: E402
from tests.support.demo import default_pipeline_cache  # noqa: E402
from tests.support.shared import shared_folder, shared_value  # noqa: E402

_warmup: list = []


@pytest.hookimpl(trylast=True)  # after the tmp_path plugin has set up the base folder
def pytest_configure(config):
    cpuprofile.register(config)
    if parallel.controller_or_alone(config):
        # before any xdist worker exists: the workers wait for it (tests/support/parallel.py)
        _warmup.extend(parallel.start_jit_warmup(config))


@pytest.hookimpl(tryfirst=True)
def pytest_runtestloop(session):
    if not session.config.pluginmanager.has_plugin("dsession"):   # not the xdist controller, which runs no test
        parallel.wait_for_jit_warmup(session.config)


def pytest_terminal_summary(terminalreporter, config):
    line = parallel.report_jit_warmup(_warmup, config) if _warmup else None
    if line:
        terminalreporter.write_line(line, yellow=True)


if importlib.util.find_spec("xdist") is not None:
    def pytest_xdist_make_scheduler(config, log):
        return parallel.make_scheduler(config, log)

    def pytest_xdist_auto_num_workers(config):
        return parallel.auto_workers()


#: Ctrl-C and the stop signals: their handling, as every test must leave it
_STOP_SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))


def _signal_state():
    """(handler of each stop signal, the stop signals blocked in this thread)."""
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, ()) if hasattr(signal, "pthread_sigmask") else ()
    return {s: signal.getsignal(s) for s in _STOP_SIGNALS}, sorted(set(blocked) & set(_STOP_SIGNALS))


@pytest.fixture(autouse=True)
def _signals_left_as_found():
    """Each test leaves Ctrl-C, SIGTERM and SIGHUP as it found them. A handler, an ignore or a block left behind
    passes on to every command the worker starts later (an ignored or blocked signal survives exec): such a
    command then never hears the SIGTERM a later test sends it. Restored, and the test that left it fails."""
    before = _signal_state()
    yield
    after = _signal_state()
    if after != before:
        handlers, blocked = before
        for sig, handler in handlers.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        if hasattr(signal, "pthread_sigmask"):
            signal.pthread_sigmask(signal.SIG_UNBLOCK, set(_STOP_SIGNALS) - set(blocked))
        pytest.fail(f"the test changed the stop signals' handling and left it so: before {before}, after {after}")


@pytest.fixture(scope="session")
def default_demo(tmp_path_factory):
    """The sim demo with its default settings (``make demo``'s taps, no figures), run once per test run.

    Shared by the fidelity tests (tests/renderer/demo/test_demo_fidelity.py, test_grip_sweep.py) and the
    README's printed table (tests/integration/test_readme_demo_table.py), on whichever xdist worker they run
    (tests/support/shared.py). The pipeline (~15 s) comes from the run's shared cache of the default pipeline
    (tests/support/demo.py), then the taps.
    """
    from renderer.demo import config as demo_config, sim_demo
    from stimuli.hfam.pipeline import Progress

    cache = default_pipeline_cache(tmp_path_factory)

    def run(folder):
        cfg = demo_config.DemoConfig()
        res = sim_demo.run_sim_demo(cfg, folder / "out", cache, figures=False, progress=Progress(5, quiet=True))
        res.cfg, res.out = cfg, folder / "out"
        return res

    return shared_value(tmp_path_factory, "default_demo", run)


@pytest.fixture(scope="session")
def fake_hd(tmp_path_factory):
    """libfakehd.so, a fake OpenHaptics HD library (tests/devices/hardware/contract/fake_hd/fake_hd.c), compiled
    once per test run for every worker (tests/support/shared.py): the Touch adapter's tests and its
    ``renderer run`` load it through ``$HFAM_OPENHAPTICS_LIB``."""
    import subprocess
    from pathlib import Path

    from plumbing import sysdeps

    from tests.support.needs import need

    need("cc")
    src = Path(__file__).resolve().parent / "devices" / "hardware" / "contract" / "fake_hd" / "fake_hd.c"

    def build(folder):
        r = subprocess.run(["cc", "-shared", "-fPIC", "-O2", "-o", str(folder / "libfakehd.so"), str(src),
                            "-lpthread", "-lm"], capture_output=True, text=True, timeout=60, env=sysdeps.tool_env())
        assert r.returncode == 0, r.stderr

    return shared_folder(tmp_path_factory, "fakehd", build) / "libfakehd.so"


@pytest.fixture(autouse=True)
def _lsl_outlets_end_with_their_test():
    """A test's retired Lab Streaming Layer outlets (plumbing.lsl keeps them until the process ends, so that
    liblsl sends their last samples) are dropped after it: in this long-lived process, a later test's inlets
    otherwise stopped receiving a servo process's streams."""
    yield
    import sys  # noqa: PLC0415 (the module is read only if a test loaded it)
    lsl = sys.modules.get("plumbing.lsl")
    if lsl is not None:
        lsl._RETIRED.clear()


@pytest.hookimpl(trylast=True)
def pytest_collection_finish(session):
    # every test module is imported now, and with them numpy, scipy, pandas and matplotlib: keep their ~10^6
    # long-lived objects out of the cyclic collector's full passes, which would walk them again and again
    # (as the commands do, plumbing.dispatch)
    gc.collect()
    gc.freeze()
