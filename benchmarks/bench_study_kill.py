"""SIGKILL a simulated study session at seeded random durable steps over its whole life, then ``--resume``.

Each case: a warm parent process forks a child that runs the session with ``STUDY_CRASH_AT=k`` (the k-th
durable step of its life: start-up folder, session.json, trials.csv header, plan, each trace, row and event,
phase boundaries included; see :func:`study.data.crash_point`), so the child dies by a real SIGKILL exactly
there; a second forked child runs ``--resume`` to the end. The finished folder must equal an uninterrupted
reference run of the same seed attempt by attempt (phase, trial, attempt, sample, validity, rating, taps):
no row lost, none duplicated, no extra familiarization window, and exactly the protocol's counts.

Forking a warm process (imports and numba compiled once) makes a case cost one short session instead of
two interpreter start-ups. ``python -m benchmarks study_kill`` runs 200 cases and prints the counts.
"""

from __future__ import annotations

import csv
import json
import os
import random
import signal
import sys
import tempfile
import time
import traceback
from pathlib import Path

import study.data as data
from study.__main__ import main as study_main

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
KEY = ("phase", "trial", "attempt", "sample", "valid", "rating", "rejected", "overpowered", "saturated",
       "n_taps", "ends_familiarization")


def _args(work: Path, out: Path, resume: bool, subject: str = "K") -> list[str]:
    """Command line of a session (the schedule depends on seed and subject id: every case uses subject K)."""
    out = str(out)
    if resume:
        return ["run", "--quiet", "--subject", subject, "--out", out, "--resume"]
    return ["run", "--quiet", "--device", "sim", "--participant", "simulated", "--subject", subject,
            "--seed", str(SEED), "--out", out, "--protocol", str(work / "protocol.toml"),
            "--samples", SAMPLES, "--repetitions", str(REPETITIONS)]


def _forked(argv: list[str], env: dict) -> int:
    """Run ``study`` ``main(argv)`` in a forked child; returns its wait status as -signal or exit code."""
    pid = os.fork()
    if pid == 0:  # child
        code = 70
        try:
            data._CRASH_COUNT = 0
            os.environ.pop("STUDY_CRASH_AT", None)
            os.environ.pop("STUDY_CRASH_LOG", None)
            os.environ.update(env)
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, 1)
            code = study_main(argv)
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
        except BaseException:
            traceback.print_exc()
        finally:
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
        data._CRASH_COUNT = 0
        os.environ["STUDY_CRASH_LOG"] = str(log)
        try:
            code = study_main(_args(self.work, self.work / "ref", False))
        finally:
            os.environ.pop("STUDY_CRASH_LOG", None)
        self.reference_s = time.perf_counter() - t0
        if code != 0:
            raise RuntimeError(f"the reference session failed with {code}")
        self.steps = log.read_text().splitlines()
        self.reference = [tuple(r[k] for k in KEY) for r in read_rows(self.work / "ref" / "K")]

    def case(self, step: int, index: int) -> dict:
        """Kill a fresh session at durable step ``step`` (1-based), resume it, compare with the reference."""
        data = self.work / f"case{index:04d}"
        folder = data / "K"
        killed = _forked(_args(self.work, data, False), {"STUDY_CRASH_AT": str(step)})
        result = {"step": step, "where": self.steps[step - 1].split(" ", 1)[1], "killed": killed}
        if killed != -signal.SIGKILL:
            result["error"] = f"the session was not killed (exit {killed})"
            return result
        if not folder.exists():  # killed before the subject folder was renamed into place: start again
            resumed = _forked(_args(self.work, data, False), {})
            result["restarted"] = True
        elif json.loads((folder / "session.json").read_text())["finished_at"]:
            resumed = 0  # killed after the last write: the session is complete, --resume rightly refuses
            result["finished"] = True
        else:
            resumed = _forked(_args(self.work, data, True), {})
        result["resumed"] = resumed
        if resumed != 0:
            result["error"] = f"--resume exited {resumed}"
            return result
        rows = [tuple(r[k] for k in KEY) for r in read_rows(folder)]
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


def run_cases(work: Path, n: int, seed: int = 1) -> tuple[KillHarness, list[dict]]:
    """Reference run, then ``n`` cases at seeded random steps (always including the first and last step)."""
    harness = KillHarness(work)
    rng = random.Random(seed)
    total = len(harness.steps)
    steps = [1, total] + [rng.randint(1, total) for _ in range(max(0, n - 2))]
    return harness, [harness.case(s, i) for i, s in enumerate(steps[:n])]


def main(n: int = 200) -> None:
    """Run ``n`` kill/resume cases and print the counts (raises if any case differs from the reference)."""
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        harness, results = run_cases(Path(tmp), n)
        wall = time.perf_counter() - t0
    bad = [r for r in results if "error" in r]
    kinds = {}
    for r in results:
        kinds[r["where"].split(":")[0]] = kinds.get(r["where"].split(":")[0], 0) + 1
    print(f"   durable steps in one session: {len(harness.steps)}; reference rows {len(harness.reference)}; "
          f"reference session {harness.reference_s:.1f} s")
    print(f"   cases: {len(results)} ({len(set(r['step'] for r in results))} distinct steps); "
          f"by kind: {kinds}")
    print(f"   restarted (killed before the folder existed): {sum(bool(r.get('restarted')) for r in results)}")
    print(f"   failures: {len(bad)}; wall {wall:.0f} s ({wall / max(1, len(results)):.1f} s per case)")
    for r in bad[:10]:
        print(f"     step {r['step']} ({r['where']}): {r['error']}")
    if bad:
        raise AssertionError(f"{len(bad)} of {len(results)} kill cases failed")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 200)
