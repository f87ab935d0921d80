"""SIGKILL a simulated study session at seeded random durable steps over its whole life, then ``--resume``.

Each case: a warm parent process forks a child that runs the session with ``STUDY_CRASH_AT=k`` (the k-th
durable step of its life: start-up folder, session.json, trials.csv header, plan, each trace, row and event,
phase boundaries included; see :func:`study.session.store.crash_point`), so the child dies by a real SIGKILL exactly
there; a second forked child runs ``--resume`` to the end. The finished folder must equal an uninterrupted
reference run of the same seed attempt by attempt (phase, trial, attempt, sample, validity, rating, taps):
no row lost, none duplicated, no extra familiarization window, and exactly the protocol's counts.

Forking a warm process (imports and numba compiled once) makes a case cost one short session instead of
two interpreter start-ups. ``python -m benchmarks study_kill`` runs 200 cases and prints the counts.
"""

from __future__ import annotations

import random
import sys
import tempfile
import time
from pathlib import Path

from tests.support.kills import KillHarness

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
