"""The command-line grammar shared by every command (``hfam-<package> <command>``).

Rules: one flag name per concept everywhere; singular for one value, plural for a
list (``--grip-N 2``, ``--grips-N 0,1,2``); every flag with a unit ends in it
(``-m-s``, ``-N``, ``-N-m``, ``-s``, ``-hz``, ``-A``, ``-db``, ``-deg``);
``--out`` for what a command writes and ``--force`` to replace it; each
``--help`` ends with an example. Old spellings are accepted for one release
with a deprecation notice on stderr (:func:`add_renamed`).
"""

from __future__ import annotations

import argparse
import math
import sys


class _RenamedStore(argparse._StoreAction):
    """A store action that also answers to old spellings, saying so on stderr."""

    def __call__(self, parser, namespace, values, option_string=None):
        if option_string is not None and option_string not in self.option_strings:
            print(f"warning: {option_string} is deprecated; use {self.option_strings[0]} (the old spelling is "
                  "accepted until the next release)", file=sys.stderr)
        super().__call__(parser, namespace, values, option_string)


def add_renamed(parser: argparse.ArgumentParser, name: str, *old: str, **kwargs) -> argparse.Action:
    """Add option ``name`` that also accepts the deprecated spellings ``old`` (hidden from ``--help``).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    name : str
        The flag's name under the grammar (e.g. ``"--velocities-m-s"``).
    *old : str
        Earlier spellings (e.g. ``"--velocity"``): still parsed, with a notice on stderr.
    **kwargs
        As for :meth:`argparse.ArgumentParser.add_argument` (give ``dest`` to keep the attribute name).

    Returns
    -------
    argparse.Action
        The added action.
    """
    action = parser.add_argument(name, *old, action=_RenamedStore, **kwargs)
    action.option_strings = [name]        # help and usage show the new name; parsing still knows the old ones
    return action


def examples(*lines: str) -> str:
    """An ``--help`` epilog: ``examples:`` then one indented command per line (use with RawDescriptionHelpFormatter)."""
    return "examples:\n" + "\n".join(f"  {ln}" for ln in lines)


class Formatter(argparse.HelpFormatter):
    """Wraps descriptions as usual but keeps an ``examples:`` epilog line by line."""

    def _fill_text(self, text, width, indent):
        if text.startswith("examples:"):
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


def with_examples(parser: argparse.ArgumentParser, *lines: str) -> argparse.ArgumentParser:
    """End ``parser``'s ``--help`` with ``examples:`` and the given command lines; returns the parser."""
    parser.epilog = examples(*lines)
    if parser.formatter_class is argparse.HelpFormatter:
        parser.formatter_class = Formatter
    return parser


def float_list(text: str) -> tuple[float, ...]:
    """An argparse ``type`` for a comma-separated list of numbers (``"0.2,0.75,1.25"``); empty items are skipped.

    Raises
    ------
    argparse.ArgumentTypeError
        Naming the text when an item is not a number (argparse prints it as one usage error line).
    """
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


# -- argparse types: a bad value is one usage error line naming the flag ---------------------------------------

def positive(flag: str):
    """An argparse ``type``: a finite number > 0 (``--duration-s 2.5``).

    Raises
    ------
    argparse.ArgumentTypeError
        ``"<flag> must be a number, got '...'"`` or ``"<flag> must be > 0, got '...'"``.
    """
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} must be a number, got {text!r}") from None
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"{flag} must be > 0, got {text!r}")
        return value
    return parse


def positive_list(flag: str):
    """An argparse ``type``: comma-separated numbers, each finite and > 0 (the message names ``flag``)."""
    item = positive(flag)
    return lambda text: [item(part.strip()) for part in text.split(",")]


def vector3(flag: str):
    """An argparse type: three finite numbers ``x,y,z`` (a point in m or a direction), named by ``flag``."""
    def parse(text: str) -> tuple[float, float, float]:
        try:
            vec = tuple(float(x) for x in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} must be three numbers x,y,z, got {text!r}") from None
        if len(vec) != 3 or not all(math.isfinite(v) for v in vec):
            raise argparse.ArgumentTypeError(f"{flag} must be three finite numbers x,y,z, got {text!r}")
        return vec
    return parse


def integer(flag: str, low: int, high: int):
    """An argparse ``type``: a whole number in ``low..high`` (``"<flag> must be low..high, got '...'"``)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} must be an integer, got {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{flag} must be {low}..{high}, got {text!r}")
        return value
    return parse


def within(flag: str, limit: float, unit: str):
    """An argparse ``type``: a finite number within ``+-limit`` (``"<flag> must be within +-<limit> <unit>"``)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} must be a number, got {text!r}") from None
        if not (math.isfinite(value) and abs(value) <= limit):
            raise argparse.ArgumentTypeError(f"{flag} must be within +-{limit:g} {unit}, got {text!r}")
        return value
    return parse


def positive_numbers(what: str, unit: str, items: str = "numbers", none: bool = False):
    """An argparse ``type``: comma-separated numbers > 0 (empty items skipped), at least one unless ``none``.

    Parameters
    ----------
    what : str
        What the numbers are, in the message (``"speeds"``: "speeds must be > 0 m/s").
    unit : str
        Their unit.
    items : str
        What a list item is, in the message of a list that does not parse ("expected comma-separated <items>").
    none : bool
        Accept ``none`` (and an empty list) for no values at all.
    """
    def parse(text: str) -> list[float]:
        if none and text.strip().lower() == "none":
            return []
        try:
            values = [float(x) for x in text.split(",") if x.strip()]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected comma-separated {items}, got {text!r}") from None
        if (not values and not none) or any(not v > 0 for v in values):
            raise argparse.ArgumentTypeError(f"{what} must be > 0 {unit}, got {text!r}")
        return values
    return parse


def auto_or(flag: str, convert, what: str):
    """An argparse ``type``: ``auto``, or a value ``convert`` accepts (``int``, ``float``); else
    ``"<flag> must be 'auto' or <what>, got '...'"``."""
    def parse(text: str):
        if text == "auto":
            return "auto"
        try:
            return convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} must be 'auto' or {what}, got {text!r}") from None
    return parse
