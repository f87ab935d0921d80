"""Haptic rendering: the servo loop, scenes and collision detection, contact events, transient overlay.

Public API (contract in docs/architecture.md, "renderer")::

    from renderer import ServoLoop, RendererConfig, RunResult, ContactEvent
"""

from .config import RendererConfig, config_from_dict, load_config, load_scene
from .loop import LOG_CHANNELS, ContactEvent, RunResult, ServoLoop
from .scene import Box, Plane, Scene, Sphere, Wall, parse_scene

__all__ = ["ServoLoop", "RendererConfig", "RunResult", "ContactEvent", "LOG_CHANNELS", "load_config",
           "config_from_dict", "load_scene", "Scene", "Wall", "Plane", "Sphere", "Box", "parse_scene",
           "run_in_process"]


def run_in_process(*args, **kwargs):
    """Run a servo loop in its own process (see :func:`renderer.process.run_in_process`)."""
    from .process import run_in_process as _run

    return _run(*args, **kwargs)
