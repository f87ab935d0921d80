"""A package's public names loaded on first use (PEP 562), so that importing the package stays light.

Every package whose ``__init__`` names things from heavy modules (numpy, scipy, numba behind them) uses
this one helper instead of writing its own ``__getattr__``::

    from plumbing.lazy import lazy_exports

    _EXPORTS = {"ServoLoop": "loop", "RendererConfig": "config"}   # name -> module of this package
    __all__ = list(_EXPORTS)
    __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

A name is imported from ``<package>.<module>`` the first time it is asked for and then kept in the
package's namespace, so later look-ups cost nothing. ``python -m <package> --help`` therefore imports
none of the modules behind the names (``tests/integration/test_commands.py``).
"""

from __future__ import annotations

import importlib
import sys
from typing import Callable


def lazy_exports(package: str, exports: dict[str, str]) -> tuple[Callable[[str], object], Callable[[], list]]:
    """The ``__getattr__`` and ``__dir__`` of a package whose public names load on first use.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    exports : dict of str -> str
        Public name -> the module (relative to ``package``, without the dot) that defines it.

    Returns
    -------
    (callable, callable)
        ``__getattr__(name)`` (raises ``AttributeError`` naming the package for any other name) and
        ``__dir__()`` (the package's own names and every export).
    """

    def __getattr__(name: str):
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f".{module}", package), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list:
        return sorted(set(vars(sys.modules[package])) | set(exports))

    return __getattr__, __dir__
