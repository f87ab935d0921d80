"""``python -m analysis adjustment``'s parser (:mod:`analysis.cli_scaling_parser`)."""

from analysis.cli_scaling_parser import register_adjustment as register

__all__ = ["register"]
