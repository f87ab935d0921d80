"""Whether a servo run's timing met the thresholds the protocol claims: figures and verdict.

Thresholds (docs/renderer.md, "Timing check"): the period error ``|period - 1/rate|`` at p99 <= 20 us and at
p99.9 <= 50 us, and no period above ``max(1 ms, 2 nominal periods)`` (at 10 kHz: no period above 1 ms, a 10-tick
gap). Over a hardware link also: command -> state round trip p99 <= 2 ms, no gap between two answered
commands above 10 ms, no lost frame and no CRC error. Numpy only: ``renderer.loop`` imports it for run.json.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from plumbing.validation import require_positive


@dataclass(frozen=True)
class TimingThresholds:
    """The timing verdict's thresholds (all > 0).

    Attributes
    ----------
    period_error_p99_us, period_error_p999_us : float
        Highest allowed p99 and p99.9 of ``|period - 1/rate|`` (us).
    max_period_ms : float
        Highest allowed single period (ms); a rate whose two periods exceed it is allowed two periods.
    link_rtt_p99_ms : float
        Highest allowed p99 command -> state round trip over a hardware link (ms).
    link_gap_ms : float
        Highest allowed gap between two answered commands over a hardware link (ms).
    """

    period_error_p99_us: float = 20.0
    period_error_p999_us: float = 50.0
    max_period_ms: float = 1.0
    link_rtt_p99_ms: float = 2.0
    link_gap_ms: float = 10.0

    def __post_init__(self) -> None:
        require_positive(self, *(f.name for f in dataclasses.fields(self)), prefix="timing threshold ")

    def to_dict(self) -> dict:
        """The thresholds as a plain dict (run.json, session.json)."""
        return dataclasses.asdict(self)


DEFAULT_THRESHOLDS = TimingThresholds()

#: histogram bin edges of the period error (us): fine near zero, coarse in the tail
HIST_EDGES_US = (0, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 10000, 20000, 50000, np.inf)


def period_figures(wall_ns: np.ndarray, rate_hz: float, overrun_tolerance_s: float | None = None) -> dict:
    """Period statistics of a paced run from the wall-clock time of each tick's read.

    Parameters
    ----------
    wall_ns : ndarray of int, shape (n,)
        Wall-clock time of each tick (ns, any origin), as ``log.npz``'s ``wall_ns``.
    rate_hz : float
        Nominal servo rate (Hz).
    overrun_tolerance_s : float, optional
        A period longer than nominal by more than this is an overrun (default half a period, as the loop).

    Returns
    -------
    dict
        ``periods`` (n - 1), ``period_p50_us``, ``period_max_us``, ``period_error_p50_us``,
        ``period_error_p99_us``, ``period_error_p999_us``, ``period_error_max_us``, ``overruns``,
        ``histogram`` (``edges_us`` and ``counts`` of the error, :data:`HIST_EDGES_US`).
    """
    w = np.asarray(wall_ns, dtype=np.int64)
    periods = np.diff(w) / 1000.0 if len(w) > 1 else np.zeros(0)
    nominal = 1e6 / float(rate_hz)
    err = np.abs(periods - nominal)
    tol = 0.5 / rate_hz if overrun_tolerance_s is None else overrun_tolerance_s

    def pct(q):
        return float(np.percentile(err, q)) if len(err) else 0.0

    counts, _ = np.histogram(err, bins=np.asarray(HIST_EDGES_US, dtype=float))
    return {"periods": int(len(periods)), "rate_hz": float(rate_hz),
            "period_p50_us": float(np.median(periods)) if len(periods) else 0.0,
            "period_max_us": float(periods.max()) if len(periods) else 0.0,
            "period_error_p50_us": pct(50), "period_error_p99_us": pct(99), "period_error_p999_us": pct(99.9),
            "period_error_max_us": float(err.max()) if len(err) else 0.0,
            "overruns": int(np.count_nonzero(periods > nominal + tol * 1e6)),
            "histogram": {"edges_us": [float(e) for e in HIST_EDGES_US[:-1]] + ["inf"],
                          "counts": [int(c) for c in counts]}}


def verdict(figures: dict, thresholds: TimingThresholds = DEFAULT_THRESHOLDS, link: dict | None = None) -> dict:
    """The verdict of one paced run (or timing check) against ``thresholds``.

    Parameters
    ----------
    figures : dict
        At least ``rate_hz``, ``period_error_p99_us``, ``period_error_p999_us``, ``period_max_us`` and
        ``periods`` (as :func:`period_figures` or run.json's timing give them).
    thresholds : TimingThresholds
    link : dict, optional
        A hardware link's ``link_stats()`` (run.json ``link``): its round trip, gaps, losses and CRC errors
        join the verdict.

    Returns
    -------
    dict
        ``met`` (True, False, or None when there is nothing to judge: fewer than 1000 periods), ``failed``
        (one sentence per threshold missed), ``thresholds`` (the dict used).
    """
    th = thresholds
    out = {"met": None, "failed": [], "thresholds": th.to_dict()}
    if int(figures.get("periods", 0)) < 1000:
        return out
    failed = out["failed"]
    p99, p999 = figures["period_error_p99_us"], figures["period_error_p999_us"]
    if p99 > th.period_error_p99_us:
        failed.append(f"period error p99 {p99:.1f} us > {th.period_error_p99_us:g} us")
    if p999 > th.period_error_p999_us:
        failed.append(f"period error p99.9 {p999:.1f} us > {th.period_error_p999_us:g} us")
    bound_us = max(th.max_period_ms * 1000.0, 2e6 / float(figures["rate_hz"]))
    if figures["period_max_us"] > bound_us:
        failed.append(f"longest period {figures['period_max_us'] / 1000:.2f} ms > {bound_us / 1000:g} ms")
    if link:
        rtt = link.get("rtt_p99_s")
        if rtt is not None and rtt * 1000 > th.link_rtt_p99_ms:
            failed.append(f"link round trip p99 {rtt * 1000:.2f} ms > {th.link_rtt_p99_ms:g} ms")
        gap = link.get("longest_gap_s")
        if gap is not None and gap * 1000 > th.link_gap_ms:
            failed.append(f"link gap {gap * 1000:.1f} ms > {th.link_gap_ms:g} ms")
        for key, what in (("losses", "lost frames"), ("crc_errors", "CRC errors")):
            if int(link.get(key) or 0):
                failed.append(f"{int(link[key])} {what} on the link")
    out["met"] = not failed
    return out
