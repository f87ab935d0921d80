"""Latin squares and Williams designs: orders of ``n`` conditions for a sequence of participants.

A **Latin square** of order ``n`` is ``n`` orders (rows) in which every condition stands once in every position
(column): position is balanced across participants. Here the cyclic square, row ``i`` = ``(i, i+1, ..., i+n-1)
mod n``, which exists for every ``n``.

A **Williams design** (Williams 1949, *Aust. J. Sci. Res.* A2: 149-168) is a Latin square that is also balanced
for first-order carry-over: every condition is immediately preceded by every other condition equally often.
For even ``n`` one square does it: the first row is ``0, 1, n-1, 2, n-2, 3, ...`` (the zig-zag), row ``i`` adds
``i`` mod ``n``; each ordered pair of different conditions is adjacent exactly once. For odd ``n`` no single
square can be balanced; the standard construction takes that square and its mirror image (every row
reversed): ``2n`` orders in which each ordered pair is adjacent exactly twice (Jones & Kenward 2015, *Design
and analysis of cross-over trials*, section 4.2).

:func:`carryover_counts` and :func:`position_counts` count what a design balances; the tests count them for
2-12 conditions.
"""

from __future__ import annotations

import numpy as np

#: the designs by name (``python -m study design --design``)
DESIGNS = ("williams", "latin")


def latin_square(n: int) -> list[list[int]]:
    """The cyclic Latin square of order ``n`` (>= 1): row ``i`` is ``[(i + j) % n for j in range(n)]``."""
    _check_n(n)
    return [[(i + j) % n for j in range(n)] for i in range(n)]


def williams_design(n: int) -> list[list[int]]:
    """A Williams design for ``n`` (>= 1) conditions: ``n`` orders for even ``n``, ``2n`` for odd ``n`` (module
    docstring); conditions are ``0 .. n-1``."""
    _check_n(n)
    first, lo, hi = [0], 1, n - 1
    while len(first) < n:
        first.append(lo)
        lo += 1
        if len(first) < n:
            first.append(hi)
            hi -= 1
    square = [[(c + i) % n for c in first] for i in range(n)]
    if n % 2:
        square += [row[::-1] for row in square]
    return square


def design(name: str, n: int) -> list[list[int]]:
    """The design called ``name`` (:data:`DESIGNS`) for ``n`` conditions."""
    if name == "williams":
        return williams_design(n)
    if name == "latin":
        return latin_square(n)
    raise ValueError(f"design must be one of {', '.join(DESIGNS)}, got {name!r}")


def carryover_counts(orders, n: int) -> np.ndarray:
    """``counts[a, b]``: how often condition ``b`` immediately follows condition ``a`` over all ``orders``."""
    counts = np.zeros((n, n), dtype=int)
    for row in orders:
        for a, b in zip(row[:-1], row[1:]):
            counts[a, b] += 1
    return counts


def position_counts(orders, n: int) -> np.ndarray:
    """``counts[c, p]``: how often condition ``c`` stands at position ``p`` (0-based) over all ``orders``."""
    counts = np.zeros((n, n), dtype=int)
    for row in orders:
        for p, c in enumerate(row):
            counts[c, p] += 1
    return counts


def is_williams(orders, n: int) -> bool:
    """Whether ``orders`` balance position (each condition equally often at each position) and first-order
    carry-over (each ordered pair of different conditions adjacent equally often)."""
    pos = position_counts(orders, n)
    carry = carryover_counts(orders, n)
    off = carry[~np.eye(n, dtype=bool)]
    return bool(np.all(pos == pos[0, 0]) and (n == 1 or (np.all(off == off[0]) and not np.any(np.diag(carry)))))


def _check_n(n) -> None:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"the number of conditions must be an integer >= 1, got {n!r}")
