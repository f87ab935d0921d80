"""The servo timing of a hardware session: the check before it, and whether its windows met it.

Before a hardware session the study runs ``renderer timing-check`` through the session's own device (motor off,
zero current, ``protocol.timing_check_s`` seconds, the servo's real-time policy and process layout): the
period error figures and the link's round trip and gaps against the protocol's thresholds. A failing verdict
refuses the session before any trial unless ``--accept-timing`` is given; either way the check's record
(figures, policy, verdict, override) goes into ``session.json`` (``timing_check``) and ``schedule.jsonl``. At
the end, :func:`window_summary` of every tapping window's verdict goes into ``session.json``
(``servo_timing``), which the analysis report lists per session.
"""

from __future__ import annotations

from renderer.timing_check import run_check
from renderer.timing_verdict import TimingThresholds


def thresholds(protocol) -> TimingThresholds:
    """The protocol's timing thresholds (``ProtocolConfig.timing_*``)."""
    return TimingThresholds(period_error_p99_us=protocol.timing_p99_us,
                            period_error_p999_us=protocol.timing_p999_us,
                            max_period_ms=protocol.timing_max_period_ms,
                            link_rtt_p99_ms=protocol.timing_link_rtt_p99_ms,
                            link_gap_ms=protocol.timing_link_gap_ms)


def pre_session_check(device_spec: str, protocol, accept: bool) -> dict:
    """Run the timing check through the session's device; refuse a failing verdict unless ``accept``.

    Parameters
    ----------
    device_spec : str
        The session's device string (``serial:...``).
    protocol : study.session.config.ProtocolConfig
        ``timing_check_s`` and the thresholds.
    accept : bool
        ``--accept-timing``: start even on a failing verdict (recorded as ``accepted_override``).

    Returns
    -------
    dict
        The check's record (``renderer.timing_check.run_check``) plus ``accepted_override``.

    Raises
    ------
    ValueError
        The verdict failed and ``accept`` is false: the message names what failed and the flag.
    """
    rec = run_check(duration_s=protocol.timing_check_s, device=device_spec, thresholds=thresholds(protocol),
                    watchdog_s=protocol.servo_watchdog_s)
    failed = rec["verdict"]["met"] is False
    rec["accepted_override"] = bool(failed and accept)
    if failed and not accept:
        raise ValueError(f"servo timing check failed on {device_spec} ({'; '.join(rec['verdict']['failed'])}): "
                         "the haptics would not be what the protocol claims; no session was started. Find what "
                         "loads this machine (`python -m renderer timing-check` shows the figures; docs/study.md, "
                         "'Servo timing'), or pass --accept-timing to run anyway (recorded in session.json)")
    return rec


def window_summary(verdicts: list) -> dict:
    """Whether the session's paced tapping windows met the thresholds.

    Parameters
    ----------
    verdicts : list of dict
        Each window's ``timing["timing_verdict"]`` (renderer.timing_verdict.verdict) and figures, as
        ``{"verdict": ..., "period_error_p99_us": ..., "period_error_p999_us": ..., "period_max_us": ...}``.

    Returns
    -------
    dict
        ``windows`` (judged), ``met`` (how many met), ``all_met`` (None when none was judged), worst
        ``period_error_p99_us``, ``period_error_p999_us`` and ``period_max_us``.
    """
    judged = [v for v in verdicts if v.get("verdict", {}).get("met") is not None]
    out = {"windows": len(judged), "met": sum(1 for v in judged if v["verdict"]["met"]),
           "all_met": (all(v["verdict"]["met"] for v in judged) if judged else None)}
    for key in ("period_error_p99_us", "period_error_p999_us", "period_max_us"):
        out[f"worst_{key}"] = max((float(v.get(key, 0.0)) for v in judged), default=None)
    return out


def merge_summaries(before: dict | None, now: dict) -> dict:
    """One :func:`window_summary` of a session resumed in parts: counts added, worst figures kept."""
    if not before:
        return now
    out = {"windows": before.get("windows", 0) + now["windows"], "met": before.get("met", 0) + now["met"]}
    flags = [v for v in (before.get("all_met"), now["all_met"]) if v is not None]
    out["all_met"] = all(flags) if flags else None
    for key in ("worst_period_error_p99_us", "worst_period_error_p999_us", "worst_period_max_us"):
        vals = [v for v in (before.get(key), now.get(key)) if v is not None]
        out[key] = max(vals) if vals else None
    return out
