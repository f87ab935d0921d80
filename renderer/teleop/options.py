"""Names and option parsing shared by the teleoperation parsers (cli_teleop) and commands (commands).

Plain data and a parser only, so ``--help`` imports nothing heavy.
"""

from __future__ import annotations

import math

#: ``devices.sim.teleop.ENVIRONMENTS`` (sorted names) and ``renderer.teleop.session.CONTROLLERS``
ENVIRONMENT_NAMES = ("foam", "hard", "texture", "wood", "wood_on_foam")
CONTROLLER_NAMES = ("pd", "pd+hfam", "pf", "pf+cimm")

#: ``devices.sim.teleop.SLAVE_HANDLE_DAMPING_N_S_M`` (the calibrated damping of the slave's unheld handle) and
#: ``renderer.teleop.session.SERVO_BANDWIDTH_HZ`` (the servo rule's natural frequency), as plain numbers for the
#: parsers' defaults (a test checks they match)
SLAVE_HANDLE_DAMPING_N_S_M = 3.2
SERVO_BANDWIDTH_HZ = 8.0

# sweep conditions: name -> (controller, extra TeleopConfig fields)
SWEEP_CONDITIONS = {
    "pf": ("pf", {}),
    "pf+cimm": ("pf+cimm", {}),
    "pf+b": ("pf", {"b_Ns_m": 3.0}),
    "pf+K_mu": ("pf", {"k_mu_hz": 30.0}),
    "pf+K_lambda": ("pf", {"k_lambda_hz": 20.0}),
}


def parse_lambdas(text: str) -> list[float]:
    """Parse the ``--lambda`` values of ``teleop-sweep``.

    Parameters
    ----------
    text : str
        ``a:b`` (step 1), ``a:b:step`` or ``a,b,c``.

    Returns
    -------
    list of float
        The force-feedback gains lambda (1), each finite and >= 0.

    Raises
    ------
    ValueError
        Naming ``--lambda`` and the text, for any other form.
    """
    try:
        if ":" in text:
            parts = [float(x) for x in text.split(":")]
            a, b = parts[0], parts[1]
            step = parts[2] if len(parts) > 2 else 1.0
            if step <= 0 or b < a:
                raise ValueError
            # numpy.arange(a, b + step / 2, step) rounded to 6 decimals, without numpy (a --help imports this)
            vals = [round(a + k * step, 6) for k in range(math.ceil((b + step / 2 - a) / step))]
        else:
            vals = [float(x) for x in text.split(",")]
    except (ValueError, IndexError):
        raise ValueError(f"--lambda: expected a:b, a:b:step or a,b,c, got {text!r}") from None
    if not vals or any(not math.isfinite(v) or v < 0 for v in vals):
        raise ValueError(f"--lambda: values must be finite and >= 0, got {text!r}")
    return [float(v) for v in vals]
