"""Kill a simulated session at a durable step, resume it, compare with an uninterrupted one (shared by the tests
and the benchmarks ``study_kill`` and ``psy_session``).

A warm process forks a child that runs the session with ``STUDY_CRASH_AT=k`` (the k-th durable step of its
life, :func:`study.session.store.crash_point`), so the child dies by a real SIGKILL exactly there; a second
forked child runs ``--resume`` to the end. Forking a warm process (imports and numba compiled once) makes a
case cost one short session instead of two interpreter start-ups.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import sys
import time
import traceback
from pathlib import Path

import study.session.store as store
from study.__main__ import main as study_main

#: the forced-choice sessions' quick timing (short windows: a session takes seconds)
QUICK = """
tap_window_s = 0.6
homing_after_s = 0.3
homing_before_max_s = 0.1
"""
ADAPTIVE_DETECTION = QUICK + """
[experiment]
kind = "detection"
sample = "pulse_firm"
method = "updown"
intensity_scale = "log10"
catch_rate = 0.2
catch_intensity = 0.0

[experiment.staircases.A]
start = 4.0
step_down = [0.3, 0.15]
max_trials = {n}

[experiment.staircases.B]
start = 0.5
step_down = [0.3, 0.15]
max_trials = {n}
"""
REAL_VIRTUAL = QUICK + """
[experiment]
kind = "real-virtual-2afc"
real_sample = "wood_on_foam"
renderings = ["firm", "sinusoid_firm"]
trials_per_level = {n}
"""

PROTOCOL = """
tap_window_s = 0.4
familiarization_window_s = 0.4
familiarization_max_windows = 3
homing_after_s = 0.3
homing_before_max_s = 0.1
"""
SAMPLES = "wood,firm"
REPETITIONS = 2
SEED = 5
RATING_KEY = ("phase", "trial", "attempt", "sample", "valid", "rating", "rejected", "overpowered", "saturated",
       "n_taps", "ends_familiarization")


def rating_args(work: Path, out: Path, resume: bool, subject: str = "K") -> list[str]:
    """Command line of a session (the schedule depends on seed and subject id: every case uses subject K)."""
    out = str(out)
    if resume:
        return ["run", "--quiet", "--subject", subject, "--out", out, "--resume"]
    return ["run", "--quiet", "--device", "sim", "--participant", "simulated", "--subject", subject,
            "--seed", str(SEED), "--out", out, "--protocol", str(work / "protocol.toml"),
            "--samples", SAMPLES, "--repetitions", str(REPETITIONS)]


def forked(argv: list[str], env: dict, stdout: Path | None = None, stderr: Path | None = None) -> int:
    """Run ``study`` ``main(argv)`` in a forked child; returns its wait status as -signal or exit code.

    ``stdout``, ``stderr``: files that receive what the child prints there (default: its standard output is
    thrown away, its errors go where this process's go).
    """
    pid = os.fork()
    if pid == 0:  # child
        code = 70
        opened = []
        try:
            store._CRASH_COUNT = 0
            os.environ.pop("STUDY_CRASH_AT", None)
            os.environ.pop("STUDY_CRASH_LOG", None)
            os.environ.update(env)
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, 1)
            # a test runner may have replaced sys.stdout/sys.stderr (pytest's capture): the files take both
            # the descriptors and the Python streams
            for path, fd, name in ((stdout, 1, "stdout"), (stderr, 2, "stderr")):
                if path is not None:
                    os.dup2(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644), fd)
                    opened.append(open(fd, "w", closefd=False))
                    setattr(sys, name, opened[-1])
            code = study_main(argv)
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
        except BaseException:
            traceback.print_exc()
        finally:
            for stream in opened:   # os._exit flushes nothing
                stream.flush()
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    return -os.WTERMSIG(status) if os.WIFSIGNALED(status) else os.WEXITSTATUS(status)


def read_rows(folder: Path) -> list[dict]:
    """The rows of ``folder/trials.csv`` as dicts of strings."""
    with open(folder / "trials.csv", newline="") as fh:
        return list(csv.DictReader(fh))


class KillHarness:
    """A warm process, a reference session and the kill/resume cases (see the module doc)."""

    def __init__(self, work: Path) -> None:
        self.work = Path(work)
        (self.work / "protocol.toml").write_text(PROTOCOL)
        log = self.work / "steps.log"

        # the reference runs in this process: imports and numba compilation are then inherited by every fork
        t0 = time.perf_counter()
        store._CRASH_COUNT = 0
        os.environ["STUDY_CRASH_LOG"] = str(log)
        try:
            code = study_main(rating_args(self.work, self.work / "ref", False))
        finally:
            os.environ.pop("STUDY_CRASH_LOG", None)
        self.reference_s = time.perf_counter() - t0
        if code != 0:
            raise RuntimeError(f"the reference session failed with {code}")
        self.steps = log.read_text().splitlines()
        self.reference = [tuple(r[k] for k in RATING_KEY) for r in read_rows(self.work / "ref" / "K")]

    def case(self, step: int, index: int) -> dict:
        """Kill a fresh session at durable step ``step`` (1-based), resume it, compare with the reference."""
        data = self.work / f"case{index:04d}"
        folder = data / "K"
        killed = forked(rating_args(self.work, data, False), {"STUDY_CRASH_AT": str(step)})
        result = {"step": step, "where": self.steps[step - 1].split(" ", 1)[1], "killed": killed}
        if killed != -signal.SIGKILL:
            result["error"] = f"the session was not killed (exit {killed})"
            return result
        if not folder.exists():  # killed before the subject folder was renamed into place: start again
            resumed = forked(rating_args(self.work, data, False), {})
            result["restarted"] = True
        elif json.loads((folder / "session.json").read_text())["finished_at"]:
            resumed = 0  # killed after the last write: the session is complete, --resume rightly refuses
            result["finished"] = True
        else:
            resumed = forked(rating_args(self.work, data, True), {})
        result["resumed"] = resumed
        if resumed != 0:
            result["error"] = f"--resume exited {resumed}"
            return result
        rows = [tuple(r[k] for k in RATING_KEY) for r in read_rows(folder)]
        if rows != self.reference:
            keys = [r[:3] for r in rows]
            result["error"] = (f"{len(rows)} rows vs {len(self.reference)} in the reference; duplicates "
                               f"{len(keys) - len(set(keys))}")
            return result
        traces = sorted(p.name for p in (folder / "traces").glob("*.npz"))
        if len(traces) != len(rows):
            result["error"] = f"{len(traces)} traces for {len(rows)} rows"
        leftovers = [p.name for p in folder.rglob("*.tmp")] + [p.name for p in data.glob(".*starting*")]
        if leftovers:
            result["error"] = f"temporary files left: {leftovers}"
        return result


# -- forced-choice sessions --------------------------------------------------------------------------------

FORCED_CHOICE_KEY = ("trial", "attempt", "condition", "staircase", "intensity", "is_catch", "target_interval", "sample_1",
       "sample_2", "response", "correct", "n_taps_1", "n_taps_2")
# (not the percepts: they differ in the last digits after a resume, the sim device's state after a restart)


def session_args(protocol: Path, out: Path, subject: str, seed: int, resume: bool = False, *extra) -> list:
    """``python -m study run`` arguments of a simulated psychophysics session (or its ``--resume``)."""
    if resume:
        return ["run", "--quiet", "--subject", subject, "--out", str(out), "--resume"]
    return ["run", "--quiet", "--device", "sim", "--participant", "simulated", "--subject", subject,
            "--seed", str(seed), "--out", str(out), "--protocol", str(protocol), *extra]


def state_lines(folder: Path) -> list:
    """The staircase state lines of a subject folder (``[]`` for constant stimuli)."""
    path = folder / "staircase_state.jsonl"
    return [json.loads(ln) for ln in path.read_text().splitlines()] if path.exists() else []


class ForcedChoiceKillHarness:
    """A warm process, an uninterrupted reference session and kill/resume cases at chosen durable steps."""

    def __init__(self, work: Path, protocol_text: str, seed: int = 4, key: tuple = FORCED_CHOICE_KEY,
                 extra: tuple = ()) -> None:
        self.key = key   # the columns compared (another kind's trials.csv: its own)
        self.work = Path(work)
        self.protocol = self.work / "protocol.toml"
        self.protocol.write_text(protocol_text)
        self.seed = seed
        self.extra = tuple(str(x) for x in extra)   # more ``study run`` arguments of a new session
        log = self.work / "steps.log"
        store._CRASH_COUNT = 0
        os.environ["STUDY_CRASH_LOG"] = str(log)
        try:
            code = study_main(session_args(self.protocol, self.work / "ref", "K", seed, False, *self.extra))
        finally:
            os.environ.pop("STUDY_CRASH_LOG", None)
        if code != 0:
            raise RuntimeError(f"the reference session failed with {code}")
        self.steps = log.read_text().splitlines()
        self.reference = [tuple(r[k] for k in self.key) for r in read_rows(self.work / "ref" / "K")]
        self.reference_states = state_lines(self.work / "ref" / "K")

    def step_of(self, name: str) -> int:
        """The 1-based number of the durable step called ``name`` (e.g. ``row written: trial 2/1``)."""
        return next(int(n) for n, w in (s.split(" ", 1) for s in self.steps) if w == name)

    def case(self, step: int, index: int) -> dict:
        """Kill a fresh session at durable step ``step``, resume it, compare with the reference."""
        out = self.work / f"case{index:03d}"
        folder = out / "K"
        killed = forked(session_args(self.protocol, out, "K", self.seed, False, *self.extra),
                        {"STUDY_CRASH_AT": str(step)})
        result = {"step": step, "where": self.steps[step - 1].split(" ", 1)[1], "killed": killed}
        if killed != -signal.SIGKILL:
            result["error"] = f"the session was not killed (exit {killed})"
            return result
        before = (folder / "trials.csv").read_bytes() if folder.exists() else b""
        result["rows_before"] = max(0, before.count(b"\n") - 1)
        if not folder.exists():
            resumed = forked(session_args(self.protocol, out, "K", self.seed, False, *self.extra), {})
        elif json.loads((folder / "session.json").read_text())["finished_at"]:
            resumed = 0
        else:
            resumed = forked(session_args(self.protocol, out, "K", self.seed, resume=True), {})
        result["resumed"] = resumed
        if resumed != 0:
            result["error"] = f"--resume exited {resumed}"
            return result
        after = (folder / "trials.csv").read_bytes()
        if not after.startswith(before[:before.rfind(b"\n") + 1]):
            result["error"] = "rows on disk before the kill changed"
        rows = [tuple(r[k] for k in self.key) for r in read_rows(folder)]
        if rows != self.reference:
            result["error"] = f"{len(rows)} rows differ from the reference's {len(self.reference)}"
        if state_lines(folder) != self.reference_states:
            result["error"] = "staircase_state.jsonl differs from the reference's"
        if list(folder.rglob("*.tmp")):
            result["error"] = "temporary files left"
        result["folder"] = folder
        return result
