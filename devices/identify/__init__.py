"""Device identification (thesis section 3.4): swept-sine recording, ETFE, automatic LTI fitting,
grip-dependent model sets, Bode figures and time-domain validation.

Typical use::

    from devices.identify import SweepConfig, record_condition, etfe, fit_etfes, FitOptions
    recs = record_condition(dev, SweepConfig(fs_hz=dev.info.servo_rate_hz), grip_N=2.0, trials=4)
    result = fit_etfes([etfe(recs, "accel_m_s2")], FitOptions(weight="high"))
    result.model.save("accel.json")

Command line: ``python -m devices identify`` and ``python -m devices fit`` (see docs/models.md).
"""

from .etfe import Etfe, detrend_ramp, etfe
from .fit import FitError, FitOptions, FitResult, combine_curves, fit_errors, fit_etfes, fit_frequency_response
from .modelset import ModelSet, load_model_set
from .pipeline import IdentifyConfig, identify_device
from .record import record_condition, record_trial
from .recording import COLUMNS, Recording, read_recording, write_recording
from .sweep import SweepConfig, swept_sine
from .validate import nrmse, validate_model

__all__ = ["Etfe", "detrend_ramp", "etfe", "FitError", "FitOptions", "FitResult", "combine_curves", "fit_errors",
           "fit_etfes", "fit_frequency_response", "ModelSet", "load_model_set", "IdentifyConfig",
           "identify_device", "record_condition", "record_trial", "COLUMNS", "Recording", "read_recording",
           "write_recording", "SweepConfig", "swept_sine", "nrmse", "validate_model"]
