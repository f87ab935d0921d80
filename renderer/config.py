"""Renderer configuration: a frozen dataclass validated on creation, loadable from TOML or JSON.

File format (TOML shown; JSON uses the same keys)::

    stiffness_N_m = 680.0        # proportional gain k, eq. 2.1
    damping_N_s_m = 0.0          # virtual damping on entry only (section 2.2.2)
    rate_hz = 10000              # omit for the device's native servo rate
    rearm_margin_m = 0.002
    [scene]                      # omit for a single horizontal wall at wall_height_m
    objects = [ { shape = "wall", height_m = 0.0 },
                { shape = "sphere", center_m = [0, 0, -0.05], radius_m = 0.02 } ]

Every key of :class:`RendererConfig` may appear at the top level; unknown keys,
non-finite numbers, negative stiffness/damping and ``rate_hz <= 0`` are
rejected with a ``ValueError`` naming the file and key.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import tomllib
from dataclasses import dataclass
from typing import Any, Mapping

from plumbing.fileio import read_text_utf8
from plumbing.validation import require_int, require_number

from .scene import Scene, Wall, parse_scene

PACING_MODES = ("sleep_spin", "spin")
MAX_TRANSIENT_LIMIT_S = 10.0  # upper bound of max_transient_s: the transient buffer is allocated up front
#: the most taps of one ``renderer run`` on a sim device. The simulated hand's plan is streamed (a fixed window
#: of ticks, devices.sim.device.PLAN_WINDOW_TICKS) and the log is a ring of ``log_capacity_s``, so neither grows
#: with the taps; what does is the run's record of its contact events (one ContactEvent a tap, kept for
#: events.csv, run.json and the table: ~1 kB a tap), which this bounds to ~100 MB (and ~22 h of simulated time)
MAX_RUN_TAPS = 100_000
#: the longest ``renderer run`` (s): one day, so that no run goes on for ever by a typo (``--duration-s 1e9``)
MAX_RUN_DURATION_S = 86400.0


def check_run_size(taps: int, duration_s: float | None) -> None:
    """Refuse a run whose time or memory would be unbounded, naming the limit.

    Parameters
    ----------
    taps : int
        ``--taps`` (sim devices): 1..:data:`MAX_RUN_TAPS`.
    duration_s : float or None
        ``--duration-s``: None or up to :data:`MAX_RUN_DURATION_S`.

    Raises
    ------
    ValueError
        Naming the option, the value and the limit.
    """
    if not 1 <= taps <= MAX_RUN_TAPS:
        raise ValueError(f"--taps must be 1..{MAX_RUN_TAPS}, got {taps} (every tap's contact event is kept in memory "
                         f"for events.csv, ~1 kB per tap; run several runs for more taps)")
    if duration_s is not None and not duration_s <= MAX_RUN_DURATION_S:
        raise ValueError(f"--duration-s must be at most {MAX_RUN_DURATION_S:g} s (one day), got {duration_s:g}")


@dataclass(frozen=True)
class RendererConfig:
    """Parameters of the servo loop (SI units).

    Attributes
    ----------
    stiffness_N_m : float
        Proportional gain k of eq. 2.1 (>= 0). Table 4.1: 340 / 680 / 1020.
    wall_height_m : float
        Height of the default horizontal wall (used when ``scene`` is None).
    rate_hz : float or None
        Servo rate; None = the device's native ``servo_rate_hz``.
    damping_N_s_m : float
        Virtual damping b applied only while entering (``F -= b v`` when
        moving into the surface), section 2.2.2. 0 disables it.
    rearm_margin_m : float
        The contact latch re-arms only after the proxy has left the surface
        by this distance (and the transient has finished): one tap, one event.
    rearm_hold_s : float
        ... and has stayed beyond the margin this long (a loosely held stylus
        bounces off the surface for a few tens of ms; section 4.5.5 "double impact").
    motor_enabled : bool
        False: command zero current but still detect and log contact events
        (real-sample trials).
    transient_gain : float
        Multiplies every transient (>= 0).
    scene : Scene or None
        Scene for collision detection; None = ``Wall(wall_height_m)``.
    velocity_window_s : float
        Sliding least-squares window of the per-tick velocity estimate (logged, damping).
    impact_window_s, impact_min_window_s : float
        Longest and shortest window (ending at the crossing tick) of the incoming-velocity
        estimate (quadratic least squares, renderer.velocity).
    impact_counts : float
        The impact window is sized so the handle travelled about this many encoder counts.
    max_transient_s : float
        Transient buffer length (at most :data:`MAX_TRANSIENT_LIMIT_S`); a transient whose
        ``max_samples`` exceeds it is rejected before the loop starts.
    current_continuous_A, current_peak_A, current_amplifier_A : float or None
        Optional lower limits than the device's (proportional channel, transient
        channel, sum). None = the device's value; larger than the device's is an error.
    thermal_attenuate_frac, thermal_end_frac : float
        Transients are scaled down linearly once the modelled winding temperature
        rise exceeds ``attenuate_frac * winding_max_temp_rise_K`` and ended at
        ``end_frac * winding_max_temp_rise_K``.
    initial_temp_rise_K : float
        Winding temperature rise at the start of the run (carry it over between runs).
    watchdog_overrun_s : float
        On hardware (not simulated devices), a tick period longer than nominal by
        more than this zeroes the output and stops the run.
    overrun_tolerance_s : float or None
        Period error counted as an overrun; None = half a period.
    max_bad_samples : int
        Consecutive invalid sensor samples (NaN/inf/out of range) before the run stops.
    position_limit_m : float
        |position| beyond this is an invalid sensor sample.
    log_capacity_s : float
        Preallocated log length; longer runs keep the most recent ``log_capacity_s``.
    pacing : str
        Real-time pacing: "sleep_spin" (sleep, then busy-wait the last
        ``spin_margin_s``) or "spin" (busy-wait, 100 % of a core).
    spin_margin_s : float
        Busy-wait time before each deadline in "sleep_spin" mode.
    max_catchup_s : float
        Under pacing, a loop that fell behind (the OS descheduled it) runs
        late ticks back to back until it is on schedule again; if it is
        further behind than this, it skips ahead (those ticks are lost).
    until_every : int
        The ``until`` callback of :meth:`ServoLoop.run` is evaluated every this many ticks.
    instability_window_s : float
        Leak time constant (s) of the wall's passivity observer (Hannaford & Ryu 2002): the net work the
        proportional wall did on the handle, forgotten over about this long.
    instability_energy_frac : float
        The loop stops ("unstable", zero output) once that net work exceeds this fraction of the most
        energy the wall can store below its current limit, ``F_c^2 / (2 k)`` (``F_c`` = continuous
        current limit x force per amp). A stable wall gives back what it stored plus a sampling leak of
        order ``k T v^2`` per tap, a few percent of it (docs/renderer.md); a wall that chatters or
        diverges generates it again every cycle.
    """

    stiffness_N_m: float = 680.0
    wall_height_m: float = 0.0
    rate_hz: float | None = None
    damping_N_s_m: float = 0.0
    rearm_margin_m: float = 0.002
    rearm_hold_s: float = 0.05
    motor_enabled: bool = True
    transient_gain: float = 1.0
    scene: Scene | None = None
    velocity_window_s: float = 0.002
    impact_window_s: float = 0.010
    impact_min_window_s: float = 0.002
    impact_counts: float = 100.0
    max_transient_s: float = 0.25
    current_continuous_A: float | None = None
    current_peak_A: float | None = None
    current_amplifier_A: float | None = None
    thermal_attenuate_frac: float = 0.7
    thermal_end_frac: float = 0.9
    initial_temp_rise_K: float = 0.0
    watchdog_overrun_s: float = 0.02
    overrun_tolerance_s: float | None = None
    max_bad_samples: int = 10
    position_limit_m: float = 0.25
    log_capacity_s: float = 60.0
    pacing: str = "sleep_spin"
    spin_margin_s: float = 80e-6
    max_catchup_s: float = 0.1
    until_every: int = 16
    instability_window_s: float = 1.0
    instability_energy_frac: float = 1.0

    def __post_init__(self) -> None:
        def num(key: str, **rule):
            require_number(key, getattr(self, key), **rule)

        num("stiffness_N_m", minimum=0.0)
        num("wall_height_m")
        num("rate_hz", minimum=0.0, strict=True, optional=True)
        num("damping_N_s_m", minimum=0.0)
        num("rearm_margin_m", minimum=0.0)
        num("rearm_hold_s", minimum=0.0)
        num("transient_gain", minimum=0.0)
        for key in ("velocity_window_s", "impact_window_s", "impact_min_window_s", "impact_counts", "max_transient_s", "watchdog_overrun_s",
                    "position_limit_m", "log_capacity_s", "spin_margin_s", "max_catchup_s",
                    "instability_window_s", "instability_energy_frac"):
            num(key, minimum=0.0, strict=True)
        if self.max_transient_s > MAX_TRANSIENT_LIMIT_S:  # the buffer is preallocated: 1e9 s would ask for TiB
            raise ValueError(f"max_transient_s must be at most {MAX_TRANSIENT_LIMIT_S:g} s (a transient buffer of "
                             f"that length), got {self.max_transient_s!r}")
        for key in ("current_continuous_A", "current_peak_A", "current_amplifier_A", "overrun_tolerance_s"):
            num(key, minimum=0.0, strict=True, optional=True)
        num("thermal_attenuate_frac", minimum=0.0, strict=True)
        num("thermal_end_frac", minimum=0.0, strict=True)
        if not self.thermal_attenuate_frac < self.thermal_end_frac <= 1.0:
            raise ValueError("thermal_attenuate_frac < thermal_end_frac <= 1 required, got "
                             f"{self.thermal_attenuate_frac}, {self.thermal_end_frac}")
        num("initial_temp_rise_K", minimum=0.0)
        for key in ("max_bad_samples", "until_every"):
            require_int(key, getattr(self, key), minimum=1)
        if self.impact_min_window_s > self.impact_window_s:
            raise ValueError(f"impact_min_window_s={self.impact_min_window_s} exceeds impact_window_s="
                             f"{self.impact_window_s}")
        if not isinstance(self.motor_enabled, bool):
            raise ValueError(f"motor_enabled must be true or false, got {self.motor_enabled!r}")
        if self.pacing not in PACING_MODES:
            raise ValueError(f"pacing must be one of {PACING_MODES}, got {self.pacing!r}")
        if self.scene is not None and not isinstance(self.scene, Scene):
            raise ValueError(f"scene must be a renderer.scene.Scene, got {type(self.scene).__name__}")

    @property
    def effective_scene(self) -> Scene:
        """The configured scene, or a single wall at ``wall_height_m``."""
        return self.scene if self.scene is not None else Scene((Wall(self.wall_height_m),))

    def to_dict(self) -> dict:
        """JSON-ready dict (the scene as ``{"objects": [...]}``)."""
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            out[f.name] = value.to_dict() if isinstance(value, Scene) else value
        return out

    def replace(self, **changes) -> "RendererConfig":
        """A copy with ``changes`` applied (validated like a new config)."""
        return dataclasses.replace(self, **changes)


CONFIG_KEYS = tuple(f.name for f in dataclasses.fields(RendererConfig))


def config_from_dict(data: Mapping[str, Any], where: str = "config", base_dir: str = ".") -> RendererConfig:
    """Validate a mapping of :class:`RendererConfig` keys (``scene`` as a table) into a config.

    Raises
    ------
    ValueError
        ``"<where>: unknown key 'x'"`` or ``"<where>: <key> must be ..."``.
    """
    if not isinstance(data, Mapping):
        raise ValueError(f"{where}: expected a table of settings")
    kwargs = {}
    for key, value in data.items():
        if key not in CONFIG_KEYS:
            raise ValueError(f"{where}: unknown key {key!r} (known: {', '.join(CONFIG_KEYS)})")
        if key == "scene":
            value = parse_scene(value, where=f"{where}: scene", base_dir=base_dir)
        elif isinstance(value, int) and not isinstance(value, bool) and key not in ("max_bad_samples", "until_every"):
            try:
                value = float(value)
            except OverflowError:
                raise ValueError(f"{where}: {key} must be a finite number, got an integer too large for a "
                                 "float") from None
        kwargs[key] = value
    try:
        return RendererConfig(**kwargs)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def load_config(path: str | pathlib.Path, **overrides) -> RendererConfig:
    """Load a TOML (``.toml``) or JSON (``.json``) renderer config/scene file.

    ``overrides`` (e.g. from the command line) replace file values and are validated too.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        Parse errors (with line) and invalid keys/values, naming the file and key.
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"renderer config file not found: {path}")
    text = read_text_utf8(path, "renderer config")
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            data = tomllib.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: invalid JSON at line {exc.lineno}: {exc.msg}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: invalid TOML: {exc}") from None
    except RecursionError:   # nested 10^5 deep: one line, not a traceback
        raise ValueError(f"{path}: nested too deeply (tables and lists go at most a few hundred levels deep)") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a renderer config must be a table/object of settings, got "
                         f"{type(data).__name__} {data!r:.60}")
    data = dict(data)
    data.update(overrides)
    return config_from_dict(data, where=str(path), base_dir=str(path.parent))


def load_scene(path: str | pathlib.Path) -> Scene:
    """Load just a scene (``{"objects": [...]}`` or a config file with a ``scene`` table)."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"scene file not found: {path}")
    text = read_text_utf8(path, "scene file")
    try:
        data = json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: invalid JSON at line {exc.lineno}: {exc.msg}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: invalid TOML: {exc}") from None
    except RecursionError:   # nested 10^5 deep: one line, not a traceback
        raise ValueError(f"{path}: nested too deeply (tables and lists go at most a few hundred levels deep)") from None
    if isinstance(data, dict) and "scene" in data:
        return config_from_dict(data, where=str(path), base_dir=str(path.parent)).effective_scene
    return parse_scene(data, where=str(path), base_dir=str(path.parent))
