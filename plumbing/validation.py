"""Checks for the numbers in parameter dataclasses, shared by every package's config classes.

The config dataclasses (sweep, renderer, homing, HFAM build, study protocol, ...) are loaded
from TOML/JSON and validated at the boundary, in ``__post_init__``. These helpers give every
one of them the same rule and the same message: the field, what it must be, and the value
found, with a prefix naming the config (``"homing."``, ``"sweep "``, ``"BuildSettings."``) so
the user can find it in the file. ``bool`` is never accepted as a number (``True`` as a
duration is a typo, not a value).
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import fields
from pathlib import Path

from .fileio import read_text_utf8


def is_finite_number(value) -> bool:
    """An int or float (not bool) that is finite; an integer too large for a float (a JSON number with
    hundreds of digits) is not, instead of raising OverflowError."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def shown_value(value) -> str:
    """``repr(value)`` for a message, except an integer too large for a float, which is said in words."""
    if isinstance(value, int) and not isinstance(value, bool) and not is_finite_number(value):
        return "an integer too large for a float"
    return repr(value)


_is_number = is_finite_number


def require_number(name: str, value, *, minimum: float | None = None, strict: bool = False,
                   maximum: float | None = None, optional: bool = False, prefix: str = "",
                   strict_maximum: bool = False):
    """Check one finite number, optionally bounded; return it.

    Parameters
    ----------
    name : str
        Field name, as in the config file (``"stiffness_N_m"``).
    value : object
        The value found.
    minimum, maximum : float or None
        Inclusive bounds (``minimum`` exclusive when ``strict``).
    strict : bool
        Require ``value > minimum`` instead of ``>=``.
    strict_maximum : bool
        Require ``value < maximum`` instead of ``<=``.
    optional : bool
        Accept ``None`` (returned as is).
    prefix : str
        Put before the name in the message (``"homing."``).

    Returns
    -------
    int, float or None
        ``value``, unchanged.

    Raises
    ------
    ValueError
        ``"<prefix><name> must be a finite number, got <value>"``, or ``"... must be > 0, got ..."``.
    """
    if value is None and optional:
        return None
    if not _is_number(value):
        raise ValueError(f"{prefix}{name} must be a finite number, got {shown_value(value)}")
    if minimum is not None and (value <= minimum if strict else value < minimum):
        raise ValueError(f"{prefix}{name} must be {'>' if strict else '>='} {minimum}, got {value!r}")
    if maximum is not None and (value >= maximum if strict_maximum else value > maximum):
        raise ValueError(f"{prefix}{name} must be {'<' if strict_maximum else '<='} {maximum}, got {value!r}")
    return value


def require_choice(name: str, value, choices, *, prefix: str = ""):
    """Check that ``value`` is one of ``choices``; return it.

    Raises
    ------
    ValueError
        ``"<prefix><name> must be one of a, b, c, got <value>"``.
    """
    if value not in choices:
        raise ValueError(f"{prefix}{name} must be one of {', '.join(map(str, choices))}, got {value!r}")
    return value


def require_positive(obj, *names: str, prefix: str = "") -> None:
    """Check that each named field of ``obj`` is a positive finite number.

    Parameters
    ----------
    obj : object
        The config instance (fields read with ``getattr``).
    *names : str
        Field names.
    prefix : str
        Put before each name in the message (``"sweep "``, ``"homing."``).

    Raises
    ------
    ValueError
        ``"<prefix><name> must be a positive finite number, got <value>"`` for the first that is not.
    """
    for name in names:
        value = getattr(obj, name)
        if not (_is_number(value) and value > 0):
            raise ValueError(f"{prefix}{name} must be a positive finite number, got {value!r}")


def require_int(name: str, value, *, minimum: int | None = None, maximum: int | None = None,
                prefix: str = "") -> int:
    """Check an integer (not a bool) within inclusive bounds; return it.

    Raises
    ------
    ValueError
        ``"<prefix><name> must be an integer >= <minimum>, got <value>"`` (or ``<minimum>..<maximum>``).
    """
    ok = isinstance(value, int) and not isinstance(value, bool)
    ok = ok and (minimum is None or value >= minimum) and (maximum is None or value <= maximum)
    if not ok:
        if minimum is not None and maximum is not None:
            rule = f"an integer {minimum}..{maximum}"
        elif minimum is not None:
            rule = f"an integer >= {minimum}"
        elif maximum is not None:
            rule = f"an integer <= {maximum}"
        else:
            rule = "an integer"
        raise ValueError(f"{prefix}{name} must be {rule}, got {value!r}")
    return value


def load_dataclass_file(path, cls, what: str, overrides: dict | None = None, where: str = "command line"):
    """Build the frozen dataclass ``cls`` from a TOML (``.toml``) or JSON file: the config files' one loader.

    Every error names the file (or ``where``) and the key: a parse error, unknown key(s) (listing the valid
    ones), or a value the dataclass's ``__post_init__`` refuses (its checks use the helpers above).

    Parameters
    ----------
    path : str, Path or None
        The file; None: only ``overrides`` (and the dataclass defaults).
    cls : type
        Frozen dataclass whose field names are the valid keys.
    what : str
        What the file is, for messages ("protocol", "participant").
    overrides : dict or None
        Values that win over the file's (entries that are None are ignored).
    where : str
        Where ``overrides`` come from (without a file: all the values), for messages (e.g. a resumed
        session's ``session.json: protocol``). A refused value is blamed on the file only when the file's
        values alone are refused too.

    Returns
    -------
    cls
        The validated instance.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        Naming the file for a parse error, unknown key(s) (listing the valid
        ones) or a value ``cls`` refuses.
    """
    data: dict = {}
    if path is not None:
        p = Path(path)
        if p.exists() and not p.is_file():  # e.g. --protocol /dev/null: it is there, but holds no settings
            raise ValueError(f"{what} file {p} is not a regular file ({'a folder' if p.is_dir() else 'a device or pipe'}"
                             "); give a TOML or JSON file")
        if not p.is_file():
            raise FileNotFoundError(f"{what} file {p} not found")
        text = read_text_utf8(p, f"{what} file")
        try:
            data = tomllib.loads(text) if p.suffix == ".toml" else json.loads(text)
        except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
            raise ValueError(f"{p}: cannot parse ({exc})") from None
        except RecursionError:   # e.g. a JSON array nested 10^5 deep: one line, not a traceback
            raise ValueError(f"{p}: cannot parse (nested too deeply: tables and lists go at most a few hundred "
                             "levels deep)") from None
        if not isinstance(data, dict):
            raise ValueError(f"{p}: a {what} file must hold a table/object of settings, got {type(data).__name__}")
    return dataclass_from_layers(cls, data, overrides, what, str(path) if path is not None else where, where)


def dataclass_from_layers(cls, data: dict, overrides: dict | None, what: str, where: str,
                          overrides_where: str = "command line"):
    """Build ``cls`` from a file's ``data`` with ``overrides`` (e.g. command-line flags; None entries ignored)
    winning; an error names where the refused value came from.

    Parameters
    ----------
    cls : type
        Frozen dataclass whose field names are the valid keys.
    data : dict
        The file's values (may be empty).
    overrides : dict or None
        Values that win over ``data``.
    what : str
        What they are, for messages ("protocol").
    where : str
        Where ``data`` comes from (the file).
    overrides_where : str
        Where ``overrides`` come from, for messages.

    Returns
    -------
    cls

    Raises
    ------
    ValueError
        As :func:`dataclass_from_dict`, naming ``overrides_where`` when the file's values alone are
        accepted (so an override is what was refused) and ``where`` otherwise.
    """
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    try:
        return dataclass_from_dict(cls, {**data, **given}, what, where)
    except ValueError:
        if not given or not data or not _accepted(cls, data):
            raise
    # the file alone is accepted: an override is the value refused
    return dataclass_from_dict(cls, {**data, **given}, what, overrides_where)


def _accepted(cls, data: dict) -> bool:
    """Whether ``cls(**data)`` builds (``data``'s keys all fields of ``cls``)."""
    try:
        dataclass_from_dict(cls, data, "", "")
    except ValueError:
        return False
    return True


def dataclass_from_dict(cls, data: dict, what: str, where: str):
    """Build the frozen dataclass ``cls`` from ``data`` (e.g. a section of a file); errors name ``where``.

    Parameters
    ----------
    cls : type
        Frozen dataclass whose field names are the valid keys.
    data : dict
        The values.
    what : str
        What they are, for messages ("protocol", "homing").
    where : str
        Where they come from (a file, ``"session.json: protocol"``, ``"command line"``).

    Returns
    -------
    cls

    Raises
    ------
    ValueError
        ``"<where>: unknown <what> key(s) [...]; valid keys: [...]"`` or ``"<where>: <the dataclass's message>"``.
    """
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"{where}: unknown {what} key(s) {unknown}; valid keys: {sorted(known)}")
    try:
        return cls(**data)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None
