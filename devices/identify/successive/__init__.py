"""Successive isolation (thesis sec. 3.5): a physically parameterized nonlinear model (eq. 3.32-3.35, the
hysteresis of sec. 3.5.3) identified stage by stage, one module per stage::

    from devices.identify.successive import identify_successive, save_result
    result = identify_successive("sim")          # or a device factory / an open Device
    result.params                                # SimParams: SimDevice(result.params)
    save_result(result, "models/joystick")       # model.json (sim:<file>), report, one figure per stage

Stages: timing, amplifier, motor, cables, drum, linkage, handle, user (``STAGE_NAMES``). See docs/models.md.
"""

from .common import StageError, StageResult
from .procedure import STAGE_NAMES, SuccessiveResult, format_result, identify_successive, save_result

__all__ = ["identify_successive", "save_result", "format_result", "SuccessiveResult", "StageResult", "StageError",
           "STAGE_NAMES"]
