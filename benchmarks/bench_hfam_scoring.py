"""HFAM scoring benchmark: one scored cell and a whole grid of the shipped library on the sim.

One scored cell (``stimuli.hfam.scoring.score_cell``) plays two simulated taps (one to measure the incoming
speed, one with the transient looked up at it) and compares the second with a real-sample reference; a grid is
``score_library`` over speeds x grips (its references included). ``python -m stimuli score-hfam`` scores
five such grids (84 cells plus the floors' taps) and rebuilds two libraries.
"""

from __future__ import annotations

from pathlib import Path

from benchmarks.timing import median_time
from stimuli.hfam import scoring as S
from stimuli.library import HfamLibrary

LIBRARY = Path(__file__).resolve().parent.parent / "stimuli" / "libraries" / "wood_on_foam_sim.npz"


def main() -> None:
    lib = HfamLibrary.load(LIBRARY)
    s = S.ScoreSettings()
    factory = S.default_device_factory(s.seed)
    n = int(round((s.eval_s + s.max_lag_s) * lib.fs_hz)) + 1
    ref = S.real_reference(0.1, 2.0, None, s, factory, n)           # warm-up: compiles the tap
    S.score_cell(lib, 0.1, 2.0, ref, None, "default", s, factory)
    cell = median_time(lambda: S.score_cell(lib, 0.1, 2.0, ref, None, "default", s, factory), 7)
    grid = median_time(lambda: S.score_library(lib, S.OPEN_LOOP_SPEEDS_M_S, S.GRIPS_N, s), 3)
    n_cells = len(S.OPEN_LOOP_SPEEDS_M_S) * len(S.GRIPS_N)
    print(f"score_cell (2 taps at 0.1 m/s, 2 N + comparison): median {cell * 1e3:.0f} ms")
    print(f"score_library {len(S.OPEN_LOOP_SPEEDS_M_S)} speeds x {len(S.GRIPS_N)} grips ({n_cells} cells, "
          f"{len(S.OPEN_LOOP_SPEEDS_M_S)} references): median {grid:.2f} s")


if __name__ == "__main__":
    main()
