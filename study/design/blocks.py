"""The order of a session's condition blocks: the protocol's fixed ``order``, the participant's row of a
counterbalancing design (``design = "design.csv"``, :mod:`study.design.assign`), or a seeded random order."""

from __future__ import annotations

from pathlib import Path

from ..session.rng import session_rng
from .assign import order_for

#: the block order's word in the session's seeds (:mod:`study.session.rng`); part of the recorded sessions'
#: meaning, never changed
BLOCK_STREAM = 50


def block_order(conditions: list[str], order: tuple, design: str, subject: str, seed: int,
                where: str) -> tuple[int, list[str]]:
    """``(sequence, order)``: the design's sequence number (0 without a design) and the conditions in the order
    their blocks run.

    Parameters
    ----------
    conditions : list of str
        The experiment's conditions, as its protocol names them.
    order : tuple of str
        A fixed order for every participant (empty: none); a resumed session gives the order it recorded.
    design : str
        A design.csv (``python -m study design``); empty: none.
    subject, seed
        The session's; with neither ``order`` nor ``design`` the order is a seeded permutation.
    where : str
        The settings' source, for messages.
    """
    if order:
        if sorted(order) != sorted(conditions):
            raise ValueError(f"{where}: order {list(order)} must list each condition once: {conditions}")
        return 0, list(order)
    if design:
        return order_for(Path(design), subject, conditions, where)
    rng = session_rng(seed, subject, BLOCK_STREAM, 1)
    return 0, [conditions[i] for i in rng.permutation(len(conditions))]
