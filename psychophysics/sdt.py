"""Signal detection for yes/no data: sensitivity d' and criterion c (Macmillan & Creelman 2005, ch. 1-2).

    d' = z(H) - z(F)          c = -(z(H) + z(F)) / 2

with ``H`` the hit rate (a "yes" to a stimulus) and ``F`` the false-alarm rate (a "yes" to a blank, a catch
trial), ``z`` the inverse of the standard normal distribution. A rate of 0 or 1 has no finite z: the counts
are corrected the log-linear way (Hautus 1995, *Behav. Res. Methods* 27:46-51), ``(k + 0.5) / (n + 1)``
for every rate, which biases d' less than replacing only the extreme rates by ``1/(2n)``; ``"none"`` leaves
the rates as they are (infinite d' where a rate is 0 or 1).
"""

from __future__ import annotations

import numpy as np
from scipy import special

#: rate corrections
CORRECTIONS = ("loglinear", "none")
#: z(0.75) * sqrt(2), the d' of 75 % correct in a two-interval forced choice (Pc = Phi(d' / sqrt 2), Macmillan &
#: Creelman 2005, ch. 7): two percepts of log-SD sigma are told apart 75 % of the time at a log-ratio of this * sigma
Z75_SQRT2 = float(special.ndtri(0.75)) * 2.0 ** 0.5


def dprime(hits, n_signal, false_alarms, n_noise, correction: str = "loglinear") -> dict:
    """Sensitivity d' and criterion c of yes/no counts (module docstring), broadcasting over the arguments.

    Parameters
    ----------
    hits : array_like
        "Yes" answers to the stimulus (per level, say).
    n_signal : array_like
        Stimulus trials.
    false_alarms : array_like
        "Yes" answers to blanks (catch trials).
    n_noise : array_like
        Blank trials.
    correction : {'loglinear', 'none'}

    Returns
    -------
    dict of ndarray
        ``dprime``, ``criterion``, ``hit_rate`` and ``false_alarm_rate`` (the rates used, corrected).
    """
    if correction not in CORRECTIONS:
        raise ValueError(f"correction must be one of {', '.join(CORRECTIONS)}, got {correction!r}")
    h, ns, f, nn = (np.asarray(v, dtype=float) for v in (hits, n_signal, false_alarms, n_noise))
    if np.any(ns <= 0) or np.any(nn <= 0):
        raise ValueError("d' needs at least one stimulus trial and one blank (catch) trial")
    if np.any((h < 0) | (h > ns)) or np.any((f < 0) | (f > nn)):
        raise ValueError("counts of 'yes' answers must lie between 0 and the number of trials")
    if correction == "loglinear":
        hr, fr = (h + 0.5) / (ns + 1.0), (f + 0.5) / (nn + 1.0)
    else:
        hr, fr = h / ns, f / nn
    zh, zf = special.ndtri(hr), special.ndtri(fr)
    return {"dprime": zh - zf, "criterion": -(zh + zf) / 2.0, "hit_rate": hr, "false_alarm_rate": fr}
