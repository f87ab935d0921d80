"""Recorded real taps for the HFAM library builder (the CSV written by ``python -m devices record``).

The format and its validating reader belong to :mod:`devices.recording`; this
module only adds what the builder needs on top of it.
"""

from __future__ import annotations

from devices.recording import COLUMNS, Tap, read_taps

__all__ = ["COLUMNS", "MIN_SAMPLES", "Tap", "read_tap_csv"]

MIN_SAMPLES = 4  # the builder smooths and differentiates each tap: fewer samples carry no transient


def read_tap_csv(path) -> tuple[float, list[Tap]]:
    """Read a tap recording for the library builder.

    Validated by :func:`devices.recording.read_taps` (which keeps each tap's id
    from the file, so the builder can report dropped taps by id), plus the
    builder's own needs.

    Returns
    -------
    fs_hz : float
        Sample rate common to all taps.
    taps : list of Tap
        In file order.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        Naming the file (and tap, column and line) for any problem found by
        :func:`devices.recording.read_taps`, a tap with fewer than
        ``MIN_SAMPLES`` samples, or fewer than two distinct incoming velocities.
    """
    fs_hz, taps = read_taps(path)
    for tp in taps:
        if tp.t_s.size < MIN_SAMPLES:
            raise ValueError(f"{path}: tap {tp.tap}: only {tp.t_s.size} samples (need {MIN_SAMPLES})")
    if len({tp.v_in_m_s for tp in taps}) < 2:
        raise ValueError(
            f"{path}: all taps have the same incoming velocity ({taps[0].v_in_m_s} m/s); "
            "a library needs a range of velocities"
        )
    return fs_hz, taps
