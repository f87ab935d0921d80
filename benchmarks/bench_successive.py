"""Successive isolation on the simulated joystick, all stages (target < 60 s), and the worst parameter error
against Table 3.1."""

from __future__ import annotations

import statistics
import time

from devices.identify.successive import identify_successive
from devices.sim import default_params


def main() -> None:
    true = default_params().to_dict()
    times, worst = [], None
    for k in range(3):
        t0 = time.perf_counter()
        r = identify_successive("sim", seed=k, log=lambda m: None)
        times.append(time.perf_counter() - t0)
        found = r.params.to_dict()
        errs = {f"{sec}.{key}": abs(found[sec][key] - v) / abs(v) for sec in ("mechanics", "user")
                for key, v in true[sec].items() if isinstance(v, float) and v != 0}
        worst = max(errs.items(), key=lambda kv: kv[1])
        if k == 0:
            per_stage = ", ".join(f"{s.stage} {s.elapsed_s:.2f}" for s in r.stages)
    med = statistics.median(times)
    print(f"   successive isolation, all 8 stages on sim: median {med:.2f} s (target < 60 s, ratio {med / 60:.3f}); "
          f"{r.ticks} device ticks; worst parameter error {worst[1] * 100:.2f} % ({worst[0]})")
    print(f"   per stage (s): {per_stage}")


if __name__ == "__main__":
    main()
