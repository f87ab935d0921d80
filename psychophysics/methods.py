"""The adaptive methods by name: build one from a protocol table (TOML dict) or from a saved state.

A protocol's method table names the method and its parameters (the constructor's keyword arguments; see
docs/psychophysics.md for each one with its default)::

    method = "updown"            # or "weighted", "quest+", "psi"
    start = 4.0
    step_down = [0.4, 0.2, 0.1]  # log10 units, after 0, 1, 2+ reversals
    n_down = 2
    max_trials = 80

Every error names the key, with the table's name as prefix (``"staircase.A.step_down must be ..."``).
"""

from __future__ import annotations

from .adaptive import AdaptiveMethod, build
from .names import METHOD_NAMES
from .quest import Psi, QuestPlus
from .staircase import UpDown, WeightedUpDown

#: method name (protocol ``method``, ``--method``, a state's ``method``: :data:`psychophysics.names.METHOD_NAMES`)
#: -> class
METHODS: dict[str, type[AdaptiveMethod]] = dict(zip(METHOD_NAMES, (UpDown, WeightedUpDown, QuestPlus, Psi)))
if any(name != cls.name for name, cls in METHODS.items()):  # a state names its method by the class's own name
    raise RuntimeError(f"psychophysics.names.METHOD_NAMES {METHOD_NAMES} do not name {list(METHODS.values())}")


def _class(name, prefix: str) -> type[AdaptiveMethod]:
    if name not in METHODS:
        raise ValueError(f"{prefix}method must be one of {', '.join(METHODS)}, got {name!r}")
    return METHODS[name]


def method_from_table(table: dict, prefix: str = "") -> AdaptiveMethod:
    """Build an adaptive method from a protocol table.

    Parameters
    ----------
    table : dict
        ``{"method": name, <constructor keyword>: value, ...}`` (from TOML).
    prefix : str
        Where the table is, for messages (``"staircase.A."``).

    Returns
    -------
    AdaptiveMethod

    Raises
    ------
    ValueError
        Not a table, an unknown method or key, a missing or bad value: one message naming the key.
    """
    if not isinstance(table, dict):
        raise ValueError(f"{prefix or 'the method '}must be a table, got {type(table).__name__}")
    if "method" not in table:
        raise ValueError(f"{prefix}method is missing (one of {', '.join(METHODS)})")
    cls = _class(table["method"], prefix)
    return build(cls, {k: v for k, v in table.items() if k != "method"}, prefix)


def method_from_state(state: dict) -> AdaptiveMethod:
    """Rebuild any adaptive method from its :meth:`~psychophysics.adaptive.AdaptiveMethod.state` (replayed exactly).

    Raises
    ------
    ValueError
        Not a state, an unknown method, or one that does not replay.
    """
    if not isinstance(state, dict):
        raise ValueError(f"an adaptive method's state must be a JSON object, got {type(state).__name__}")
    return _class(state.get("method"), "state ").from_state(state)
