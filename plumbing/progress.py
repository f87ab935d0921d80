"""Progress of long steps: a tqdm bar on a terminal, plain lines otherwise (logs, pipes, CI).

Used by the study session (phase, trial n of N, elapsed, estimated time left) and
other long steps. On a terminal the bar is tqdm's (``file=stderr``); when stderr
is not a terminal each update prints one line, at most every ``min_interval_s``
(and always for the last step).
"""

from __future__ import annotations

import sys
import time

from tqdm import tqdm


def format_s(seconds: float) -> str:
    """``"42 s"``, ``"3 min 05 s"``: a duration for people."""
    seconds = max(0.0, float(seconds))
    if seconds < 60:
        return f"{seconds:.0f} s"
    m, s = divmod(int(round(seconds)), 60)
    return f"{m} min {s:02d} s"


class Progress:
    """Progress of ``total`` steps of a named task.

    Parameters
    ----------
    total : int
        Number of steps.
    desc : str
        What is being done (``"study S01"``).
    unit : str
        One step (``"trial"``).
    stream : file, optional
        Where to write (default ``sys.stderr``).
    min_interval_s : float
        Plain-line mode: least time between two lines, s.
    initial : int
        Steps already done before this process (a resumed session); the estimate uses only the new ones.
    """

    def __init__(self, total: int, desc: str, unit: str = "step", stream=None, min_interval_s: float = 2.0,
                 initial: int = 0):
        self.initial = int(initial)
        self.total = max(0, int(total))
        self.desc = desc
        self.unit = unit
        self.stream = stream if stream is not None else sys.stderr
        self.min_interval_s = float(min_interval_s)
        self.done = self.initial
        self.t0 = time.monotonic()
        self._last_line = -1e9
        tty = getattr(self.stream, "isatty", lambda: False)()
        self.bar = tqdm(total=self.total, desc=desc, unit=unit, file=self.stream, leave=True,
                        dynamic_ncols=True, initial=self.initial) if tty else None

    def eta_s(self) -> float | None:
        """Estimated time left in s (mean time per finished step times the steps left), or None before the first."""
        if self.done <= self.initial:
            return None
        return (time.monotonic() - self.t0) / (self.done - self.initial) * max(0, self.total - self.done)

    def update(self, done: int | None = None, status: str = "", total: int | None = None) -> None:
        """Set the number of finished steps (default: one more), a status text and, if it changed, the total."""
        if total is not None and int(total) != self.total:
            self.total = int(total)
            if self.bar is not None:
                self.bar.total = self.total
        new = self.done + 1 if done is None else int(done)
        if self.bar is not None:
            self.bar.set_postfix_str(status, refresh=False)
            self.bar.update(new - self.done)
            self.done = new
            return
        self.done = new
        now = time.monotonic()
        if now - self._last_line < self.min_interval_s and self.done < self.total:
            return
        self._last_line = now
        eta = self.eta_s()
        left = f", about {format_s(eta)} left" if eta is not None else ""
        print(f"{self.desc}: {self.done} of {self.total} {self.unit}s done{f' ({status})' if status else ''}; "
              f"elapsed {format_s(now - self.t0)}{left}", file=self.stream, flush=True)

    def close(self) -> None:
        """End the bar (terminal mode)."""
        if self.bar is not None:
            self.bar.close()
