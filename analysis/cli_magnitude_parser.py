"""``python -m analysis magnitude``'s parser (:mod:`analysis.cli_scaling_parser`)."""

from analysis.cli_scaling_parser import register_magnitude as register

__all__ = ["register"]
