"""Haptic rendering: the servo loop, scenes and collision detection, contact events, transient overlay.

Public API (contract in docs/architecture.md, "renderer")::

    from renderer import ServoLoop, RendererConfig, RunResult, ContactEvent

The names are loaded on first use (PEP 562 ``__getattr__``), so ``python -m renderer --help`` does not
import the servo loop.
"""

from plumbing.lazy import lazy_exports

_EXPORTS = {
    "RendererConfig": "config", "config_from_dict": "config", "load_config": "config", "load_scene": "config",
    "LOG_CHANNELS": "loop", "ContactEvent": "loop", "RunResult": "loop", "ServoLoop": "loop",
    "run_in_process": "process", "ServoLoop3": "loop3", "RunResult3": "loop3", "ContactEvent3": "loop3",
    "Box": "scene", "Plane": "scene", "Scene": "scene", "Sphere": "scene", "Wall": "scene", "parse_scene": "scene",
}

__all__ = ["ServoLoop", "RendererConfig", "RunResult", "ContactEvent", "LOG_CHANNELS", "load_config",
           "config_from_dict", "load_scene", "Scene", "Wall", "Plane", "Sphere", "Box", "parse_scene",
           "run_in_process", "ServoLoop3", "RunResult3", "ContactEvent3"]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
