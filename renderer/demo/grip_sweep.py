"""Experiment: which part of the simulated hand carries grip into a hard contact? (thesis 3.4.6, 3.5.2, 4.4.1, 4.4.3)

Two thesis statements pull the grip dependence of the simulated hand in opposite directions:

* section 4.4.1: "Contact accelerations are generally independent of grip force" -- a real sample's taps at 1 N
  and 3 N should match its 2 N tap over the contact's first 10-20 ms
  (:func:`renderer.demo.fidelity.grip_independence`, median NRMSE <= 0.3, peak within +/- 25 %);
* section 4.4.3, Figure 4.13: "if the system were to blindly apply the medium grip current transient regardless
  of grip force, the acceleration would be too large for softer grips and too weak for firmer grip forces" --
  the device's current -> acceleration response depends on grip.

The simulated person (``devices.sim.person.Person``) holds the handle through a fingertip: the stylus-to-fingertip
contact (``fingertip_*``: the flesh, grip independent, section 3.5.2's "handle and mechanism vibrating against
the flesh of the user's hand", which "was found not to change significantly with variations in grip force"),
the fingertip's mass, then the grip impedance of Table 3.1 scaled linearly with grip (section 3.5.2's wrist model,
[84]) to the arm. This module measures both claims for:

* :data:`ISOLATION`: each element of the grip impedance made grip independent in turn,
  ``k_u (g / g_nom)^alpha_k`` and ``b_u (g / g_nom)^alpha_b`` (alpha 1: linear in grip, 0: independent), on the
  hand without a fingertip (the grip impedance on the handle itself, as before the fingertip) and on the default
  person: which part carries grip into the contact;
* :data:`FINGERTIPS`: the fingertip contact's stiffness and damping around the default's.

The sim's 2 N hand is the same in every row of a sweep (the scaling is 1 at the nominal grip), so one HFAM library
(the demo's) serves them all. Not a product feature: the measured tables are in docs/sim.md ("The hand in hard
contact") and ``tests/renderer/demo/test_grip_sweep.py`` asserts their corners.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from devices.sim import Person, SimDevice, preset_params

from . import fidelity
from . import metrics as dm
from .cache import build_or_load
from .config import DemoConfig
from .renderings import REAL, REAL_FOAM, REAL_WOOD, RENDERINGS
from .runs import ALIGN, POST_S, PRE_S, FixedGripTransient, tap_sim

#: the no-grip-compensation rendering of the demo (the medium-grip HFAM transient at every grip, over firm)
FIXED_GRIP = next(r for r in RENDERINGS if r.transient == "hfam_fixed_grip")
#: the real samples whose grip independence section 4.4.1 claims
REAL_SAMPLES = (REAL_WOOD, REAL, REAL_FOAM)


@dataclass(frozen=True)
class HandScaling:
    """How the grip impedance follows grip: ``k_u (g/g_nom)^alpha_k``, ``b_u (g/g_nom)^alpha_b``.

    Attributes
    ----------
    alpha_k, alpha_b : float
        Exponents (1: linear in grip, the sim's default after [84]; 0: independent of grip).
    """

    alpha_k: float = 1.0
    alpha_b: float = 1.0

    def __post_init__(self):
        for name in ("alpha_k", "alpha_b"):
            val = getattr(self, name)
            if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
                raise ValueError(f"HandScaling: {name} must be a finite number, got {val!r}")

    @property
    def label(self) -> str:
        """``alpha_k / alpha_b`` as printed in the table."""
        return f"{self.alpha_k:g} / {self.alpha_b:g}"


def device_params():
    """The demo's device (its default ``PipelineSettings.device``, the one-dof testbed)."""
    return preset_params(DemoConfig().pipeline.device.partition(":")[2] or "joystick")


def params_at_grip(base, grip_N: float, scaling: HandScaling):
    """Sim parameters whose (linear-in-grip) kernel gives ``scaling``'s impedance at ``grip_N``.

    The kernel computes ``k_u g / g_nom``; scaling the file's ``k_u_N_m`` by
    ``(g/g_nom)^(alpha_k - 1)`` makes that ``k_u (g/g_nom)^alpha_k`` at this grip
    (likewise ``b_u``). One parameter set per grip: the grip is held constant
    during a tap.

    Parameters
    ----------
    base : devices.sim.SimParams
        The sim parameters (``[user]`` at the nominal grip).
    grip_N : float
        The grip the device will be held with (N, > 0).
    scaling : HandScaling

    Returns
    -------
    devices.sim.SimParams
    """
    u = base.user
    r = float(grip_N) / u["nominal_grip_N"]
    return base.replace(user={"k_u_N_m": u["k_u_N_m"] * r ** (scaling.alpha_k - 1.0),
                              "b_u_Ns_m": u["b_u_Ns_m"] * r ** (scaling.alpha_b - 1.0)})


def tap_grips(scaling: HandScaling, library, velocities_m_s, grips_N, base=None, seed: int = 7,
              stop_time_s: float | None = None, person=None) -> dict:
    """Tap the real samples and the fixed-grip HFAM rendering at every velocity x grip.

    Parameters
    ----------
    scaling : HandScaling
    library : stimuli.HfamLibrary
        The HFAM library whose medium-grip transient is played (the demo's).
    velocities_m_s, grips_N : sequence of float
        Tap speeds (m/s) and grips (N); the grips must include the 2 N reference.
    base : devices.sim.SimParams or None
        Sim parameters (default: the demo's device, :func:`device_params`).
    seed : int
        Sensor-noise seed (one device per grip, seeded ``seed + index``).
    stop_time_s : float or None
        The tap's stop time (:func:`renderer.demo.runs.tap_sim`; None: its default, the demo's).
    person : Person or callable or None
        The person holding the device (a :class:`devices.sim.Person`, or grip (N) -> Person; None: the default
        person).

    Returns
    -------
    dict
        (rendering name, velocity, grip) -> [TapTrace], as the demo's traces.
    """
    base = device_params() if base is None else base
    opts = {} if stop_time_s is None else {"stop_time_s": stop_time_s}
    fixed = FixedGripTransient(library, 2.0)
    traces = {}
    for k, g in enumerate(grips_N):
        with SimDevice(params_at_grip(base, g, scaling), seed=seed + k) as dev:
            hand = {} if person is None else {"hand": person(g) if callable(person) else person}
            for v in velocities_m_s:
                for r in REAL_SAMPLES:
                    traces[(r.name, v, g)] = [tap_sim(dev, r, None, v, g, library.fs_hz, **opts, **hand)]
                traces[(FIXED_GRIP.name, v, g)] = [tap_sim(dev, FIXED_GRIP, fixed, v, g, library.fs_hz, **opts,
                                                           **hand)]
    return traces


def _rms_bp(x, fs_hz: float) -> float:
    """Band-passed (20-1000 Hz) RMS of a contact window from impact to ``POST_S`` after it (m/s^2)."""
    n_pre, n_eval = int(round(PRE_S * fs_hz)), int(round(POST_S * fs_hz))
    return float(np.sqrt(np.mean(dm.bandpass(np.asarray(x, float), fs_hz)[n_pre:n_pre + n_eval] ** 2)))


def figure_4_13_ratios(traces: dict, fs_hz: float, grip_N: float, reference_grip_N: float = 2.0) -> dict:
    """Figure 4.13 on the sim: the medium-grip transient at ``grip_N`` against at the reference grip.

    Parameters
    ----------
    traces : dict
        From :func:`tap_grips`.
    fs_hz : float
    grip_N, reference_grip_N : float

    Returns
    -------
    dict
        ``peak`` and ``rms``: per velocity, peak |acceleration| and band-passed RMS at ``grip_N`` divided by
        those at ``reference_grip_N`` (lists, velocity order); ``nrmse``: the trace at ``grip_N`` against the
        one at the reference grip, as the grip claim compares real taps
        (:func:`renderer.demo.metrics.compare`); ``peak_median``, ``rms_median``, ``nrmse_median``.
    """
    peak, rms, nr = [], [], []
    for v in sorted({v for (n, v, _g) in traces if n == FIXED_GRIP.name}):
        a, ref = traces.get((FIXED_GRIP.name, v, grip_N)), traces.get((FIXED_GRIP.name, v, reference_grip_N))
        if not a or not ref or not a[0].found or not ref[0].found:
            continue
        peak.append(dm.contact_metrics(a[0].accel, fs_hz, PRE_S, POST_S)[0]
                    / dm.contact_metrics(ref[0].accel, fs_hz, PRE_S, POST_S)[0])
        rms.append(_rms_bp(a[0].accel, fs_hz) / _rms_bp(ref[0].accel, fs_hz))
        nr.append(dm.compare(a[0].accel, ref[0].accel, fs_hz, PRE_S, POST_S, **ALIGN).nrmse)
    med = (lambda x: float(np.median(x)) if x else math.nan)  # noqa: E731
    return {"peak": peak, "rms": rms, "nrmse": nr, "peak_median": med(peak), "rms_median": med(rms),
            "nrmse_median": med(nr)}


def measure(scaling: HandScaling, library, velocities_m_s=(0.05, 0.08, 0.11, 0.15), grips_N=(1.0, 2.0, 3.0),
            **options) -> dict:
    """Both sides for one setting: the section 4.4.1 grip claim and the Figure 4.13 ratios.

    Parameters
    ----------
    scaling : HandScaling
    library : stimuli.HfamLibrary
    velocities_m_s, grips_N : sequence of float
        Default: the demo's operating-point speeds (section 4.5.4) and grips.
    **options
        Passed to :func:`tap_grips`.

    Returns
    -------
    dict
        ``scaling``; per real sample (``wood``, ``wood_on_foam``, ``foam``): ``nrmse_<s>`` (median, as
        fidelity.csv) and ``peak_dev_<s>`` (largest |peak ratio - 1|); ``fig413_low`` / ``fig413_high``:
        :func:`figure_4_13_ratios` at the lowest and highest grip; ``fig413_nrmse``: the median NRMSE of the
        medium transient's response at both against at 2 N (the grip claim's metric over the same pairs).
    """
    traces = tap_grips(scaling, library, velocities_m_s, grips_N, **options)
    out = {"scaling": scaling}
    for r in REAL_SAMPLES:
        gi = fidelity.grip_independence(traces, r.name, library.fs_hz, 2.0)
        key = r.name.removeprefix("real_")
        out[f"nrmse_{key}"], out[f"peak_dev_{key}"] = gi["median_nrmse"], gi["worst_peak_dev"]
    out["fig413_low"] = figure_4_13_ratios(traces, library.fs_hz, min(grips_N))
    out["fig413_high"] = figure_4_13_ratios(traces, library.fs_hz, max(grips_N))
    out["fig413_nrmse"] = float(np.median(out["fig413_low"]["nrmse"] + out["fig413_high"]["nrmse"]))
    return out


def meets(row: dict, fig413_band: tuple[float, float] = (0.5, 1.0)) -> tuple[bool, bool]:
    """Whether a :func:`measure` row meets (grip claim, Figure 4.13).

    The grip claim: every real sample's median NRMSE <= 0.3 and peaks within +/- 25 %. Figure
    4.13: the medium transient at the firmest grip gives a peak ratio inside ``fig413_band`` (the range the
    thesis's saturation pattern implies, docs/sim.md) and at the softest grip a ratio above 1.
    """
    keys = [r.name.removeprefix("real_") for r in REAL_SAMPLES]
    grip = all(row[f"nrmse_{k}"] <= 0.3 and row[f"peak_dev_{k}"] <= 0.25 for k in keys)
    lo, hi = fig413_band
    fig = lo < row["fig413_high"]["peak_median"] < hi and row["fig413_low"]["peak_median"] > 1.0
    return grip, fig


def format_table(rows) -> str:
    """The sweep as a Markdown table (one line per setting)."""
    lines = ["| hand | NRMSE wood / w-on-foam / foam (20 ms) | worst peak dev. | "
             "Fig. 4.13 peak 1 N / 3 N (RMS) | Fig. 4.13 NRMSE | grip claim | Fig. 4.13 |",
             "|---|---|---|---|---|---|---|"]
    for row in rows:
        grip, fig = meets(row)
        lo, hi = row["fig413_low"], row["fig413_high"]
        lines.append(f"| {row.get('label', row['scaling'].label)} | {row['nrmse_wood']:.2f} / {row['nrmse_wood_on_foam']:.2f} / "
                     f"{row['nrmse_foam']:.2f} | "
                     f"{100 * max(row['peak_dev_wood'], row['peak_dev_wood_on_foam'], row['peak_dev_foam']):.0f} % | "
                     f"{lo['peak_median']:.2f} / {hi['peak_median']:.2f} ({lo['rms_median']:.2f} / "
                     f"{hi['rms_median']:.2f}) | {row['fig413_nrmse']:.2f} | "
                     f"{'yes' if grip else 'no'} | {'yes' if fig else 'no'} |")
    return "\n".join(lines)


#: which element of the grip impedance carries grip: both linear in grip (section 3.5.2), the stiffness alone, the
#: damping alone, neither
ISOLATION = (HandScaling(1.0, 1.0), HandScaling(1.0, 0.0), HandScaling(0.0, 1.0), HandScaling(0.0, 0.0))
#: the hand without a fingertip: Table 3.1's grip impedance on the handle itself (the person before the fingertip)
NO_FINGERTIP = Person(fingertip_mass_kg=0.0)
#: the fingertip contacts of docs/sim.md's table: (mass kg, stiffness N/m, damping N s/m); the default person's
#: first (5 g, section 3.5.2's 70 Hz on the flesh, Table 3.1's 23 N s/m), then its damping from a finger pad's
#: (Hajian & Howe 1997: 1-2 N s/m) up, and its stiffness halved and doubled
FINGERTIPS = ((0.005, 6240.0, 23.0), (0.005, 6240.0, 1.5), (0.005, 6240.0, 6.0), (0.005, 6240.0, 11.5),
              (0.005, 3120.0, 23.0), (0.005, 12480.0, 23.0), (0.01, 6240.0, 23.0))


def demo_library(cache_base=None):
    """The default demo's HFAM library (built, or loaded from the demo's cache) and its tap stop time (s)."""
    cfg = DemoConfig()
    return build_or_load(cfg.pipeline, cache_base).library, cfg.pipeline.tap_stop_time_s


def isolation(library=None, stop_time_s=None) -> list[dict]:
    """:func:`measure` for every :data:`ISOLATION` scaling, on the hand without a fingertip and on the default
    person (``label`` says which): docs/sim.md's isolation table.

    Reproduce it with ``python -c "from renderer.demo import grip_sweep as g; print(g.format_table(g.isolation()))"``
    (about 0.5 s per row after the demo's cache is built).
    """
    if library is None:
        library, stop_time_s = demo_library()
    rows = []
    for name, person in (("no fingertip", NO_FINGERTIP), ("fingertip (default)", None)):
        for s in ISOLATION:
            rows.append({**measure(s, library, stop_time_s=stop_time_s, person=person),
                         "label": f"{name}, alpha_k / alpha_b {s.label}"})
    return rows


def fingertip_sweep(library=None, stop_time_s=None, fingertips=FINGERTIPS) -> list[dict]:
    """:func:`measure` for every fingertip contact of ``fingertips`` (mass kg, stiffness N/m, damping N s/m), the
    grip impedance linear in grip: docs/sim.md's fingertip table."""
    if library is None:
        library, stop_time_s = demo_library()
    rows = []
    for m, k, b in fingertips:
        person = Person(fingertip_mass_kg=m, fingertip_stiffness_N_m=k, fingertip_damping_Ns_m=b)
        rows.append({**measure(HandScaling(), library, stop_time_s=stop_time_s, person=person),
                     "label": f"fingertip {m * 1e3:g} g, {k:g} N/m, {b:g} N s/m"})
    return rows
