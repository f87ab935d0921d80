"""The apparatus on a 3-DOF device: the catalog's samples as blocks on a table, tapped from above.

A study on ``sim:3d`` (``sim:3d-delta``, ``sim:3d-serial``) renders the same trials as on the 1-DOF device,
with the 3-D renderer (``renderer.ServoLoop3``): every sample of the session's catalog is a block on a
virtual table (:func:`table_scene`: a plane with a little friction, the blocks in a grid, the layout the
operator page draws), each sample's servo loop renders the whole table with the presented block carrying
the sample's stiffness and contact transient. The simulated participant taps the presented block from
above: its hand is put over the block's centre and taps straight down (``Sim3Device.set_user`` with the
block's top as the target), so contact events carry the normal speed ``v_n``, the grip and the
penetration as on the 1-DOF device, and the object the proxy touched. Between trials the hand moves to
the next presented block (a simulation: the endpoint is placed there, as a person's hand would be).

Homing holds the endpoint ``home_height_m`` above the presented block along the tap axis
(:class:`TapAxis`: the 1-DOF homing law on the 3-DOF device's tap axis). A real sample (wood, foam) is the
sim's physical sample under the block's top with the motor off, as on the 1-DOF device. The tap window's
log keeps the 1-DOF channels the study's files and the perception model read (``position_m``: height
above the presented surface; ``force_prop_N``: the wall force's magnitude; ``current_A``: the commanded
force along the tap over the force constant) beside the 3-D ones (``x_m``, ``y_m``, ``z_m``,
``contact_object``).
"""

from __future__ import annotations

import math

from devices.base import Device
from devices.sim import TapTrajectory
from renderer import RendererConfig, ServoLoop3
from renderer.homing import HomingConfig, HomingController
from renderer.loop3 import surface_point_above
from renderer.scene import Box, Plane, Scene, SurfaceProps
from renderer.scene3 import pack_scene

from .apparatus import REFERENCE_VELOCITIES_M_S, Apparatus, TapResult
from .rater import REFERENCE_SAMPLE, Reference, tap_features

#: the table: its height (m, device frame), stiffness (N/m) and friction (static, dynamic)
TABLE_Z_M = -0.03
TABLE_STIFFNESS_N_M = 1020.0
TABLE_MU = (0.4, 0.3)
#: the blocks: height (m), the grid's largest pitch and the span it fits in (m, inside a 10 cm workspace)
BLOCK_HEIGHT_M = 0.01
MAX_PITCH_M = 0.03
GRID_SPAN_M = 0.088
#: the tap's direction: straight down
DOWN = (0.0, 0.0, -1.0)


def block_name(sample: str) -> str:
    """The block a sample is rendered on: its own, or for a stimulus derived from a catalog sample
    (``firm@stiffness_N_m=950``, an adaptive method's or a discrimination's level) its base sample's."""
    return sample.split("@", 1)[0]


def table_scene(blocks, presented: str | None = None) -> Scene:
    """Samples as blocks on a table (module doc), one block per entry, in order, in a grid.

    Parameters
    ----------
    blocks : dict
        Block name -> the stimuli.CatalogSample it stands for, one block per entry.
    presented : str or None
        The block that carries the loop's stiffness and transient (its ``SurfaceProps`` leave them to the
        loop); the other blocks have their own sample's stiffness and no transient. Real samples' blocks
        (the motor is off while one is presented) have the table's stiffness.

    Returns
    -------
    renderer.scene.Scene
        Objects ``table`` and one block named after each entry.
    """
    n = max(1, len(blocks))
    cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    pitch = min(MAX_PITCH_M, GRID_SPAN_M / max(cols, rows))
    half = 0.4 * pitch
    objects = [Plane((0.0, 0.0, TABLE_Z_M), (0.0, 0.0, 1.0),
                     SurfaceProps(name="table", stiffness_N_m=TABLE_STIFFNESS_N_M, mu_static=TABLE_MU[0],
                                  mu_dynamic=TABLE_MU[1]))]
    for k, (name, smp) in enumerate(blocks.items()):
        r, c = divmod(k, cols)
        centre = ((c - 0.5 * (cols - 1)) * pitch, (0.5 * (rows - 1) - r) * pitch, TABLE_Z_M + 0.5 * BLOCK_HEIGHT_M)
        if name == presented:
            props = SurfaceProps(name=name)
        else:
            k_own = smp.stiffness_N_m if smp.kind == "virtual" else TABLE_STIFFNESS_N_M
            props = SurfaceProps(name=name, stiffness_N_m=float(k_own), transient="none")
        objects.append(Box(centre, (half, half, 0.5 * BLOCK_HEIGHT_M), props))
    return Scene(tuple(objects), source="study table")


class TapAxis(Device):
    """A 3-DOF simulated device seen along its tap axis: the 1-DOF device the homing law drives.

    ``read()`` is the tap axis's own state (``position_m``: the height above the tapped surface along the
    tap); ``command(i)`` pushes ``i`` times the force constant along the tap axis (``command_force``),
    advancing the simulation one period as the 1-DOF device's ``command`` does; ``zero()`` zeroes it.
    """

    def __init__(self, device3) -> None:
        super().__init__()
        self.device3 = device3
        self.info = device3.tap.info
        self._kf = self.info.force_per_amp_N_A
        self._is_open = True

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def read(self):
        """The tap axis's state sample (the 1-DOF device's)."""
        return self.device3.tap.read()

    def _send_current(self, current_A: float) -> None:
        u = self.device3.frame
        f = current_A * self._kf
        self.device3.command_force(u[3] * f, u[4] * f, u[5] * f)

    def _send_zero(self) -> None:
        self.device3.zero()


class Apparatus3(Apparatus):
    """:class:`study.session.apparatus.Apparatus` on a 3-DOF simulated device (module doc).

    Same parameters; ``device`` is a ``devices.sim.Sim3Device``. Attributes: ``blocks`` (block name ->
    the sample it stands for), ``scene`` (the table), ``packed`` (its arrays), ``targets`` (per block: the
    top of its block, m, device frame).
    """

    def __init__(self, device, catalog, protocol, library_dir=None, sim_participant=None, realtime=None) -> None:
        if not (device.info.simulated and hasattr(device, "tap")):
            raise ValueError(f"{device.info.name}: studies on a 3-axis device run on the 3-DOF simulated device "
                             "(sim:3d) only")
        self._device3 = device
        self.blocks = {}                 # block name -> the catalog sample it stands for
        for smp in catalog:
            self.blocks.setdefault(block_name(smp.name), smp)
        self._layout()
        self.target = None
        super().__init__(device, catalog, protocol, library_dir=library_dir, sim_participant=sim_participant,
                         realtime=realtime)
        # homing along the tap axis, above the presented block (the 1-DOF homing law, TapAxis)
        self.homing = HomingController(TapAxis(device), HomingConfig(
            home_height_m=protocol.home_height_m, kp_N_m=protocol.homing_kp_N_m, kd_N_s_m=protocol.homing_kd_N_s_m),
                                       safety_config=RendererConfig(watchdog_overrun_s=protocol.servo_watchdog_s))
        self._aim(next(iter(self.blocks), None))

    def _layout(self) -> None:
        self.scene = table_scene(self.blocks)
        self.packed = pack_scene(self.scene, TABLE_STIFFNESS_N_M, self._device3.info.specs())
        self.targets = {name: surface_point_above(self.packed, name)[0] for name in self.packed.names[1:]}

    def add_sample(self, sample) -> None:
        """The servo loop of a sample: the table with its block presented (checked now). A sample of a block
        the table does not have yet (an adaptive method's stimulus of another base sample) gets one: the
        table is laid out again and every loop made again for it."""
        if sample.name in self.loops:
            return
        block = block_name(sample.name)
        if block not in self.blocks:
            self.blocks[block] = sample
            self._layout()
            for name in list(self.loops):
                self.loops[name] = self._make_loop(self.samples[name])
        self.loops[sample.name] = self._make_loop(sample)
        self.samples[sample.name] = sample

    def _make_loop(self, sample) -> ServoLoop3:
        transient = sample.make_transient(library_dir=self.library_dir) if sample.kind == "virtual" else None
        cfg = RendererConfig(stiffness_N_m=sample.stiffness_N_m if sample.kind == "virtual" else 0.0,
                             motor_enabled=sample.kind == "virtual", log_capacity_s=self._capacity_s,
                             until_every=4 if sample.kind == "real" else 16,
                             watchdog_overrun_s=self.protocol.servo_watchdog_s,
                             scene=table_scene(self.blocks, presented=block_name(sample.name)))
        loop = ServoLoop3(self.device, cfg, transient)
        loop.prepare()   # raises ValueError now (a library unusable on this device), not mid-session
        return loop

    def _aim(self, name) -> None:
        """Point the tap axis at the block of sample ``name`` (the hand then taps it from above)."""
        if name is None:
            return
        self.target = self.targets[block_name(name)]
        dev = self._device3
        if tuple(dev.frame[:3]) != tuple(self.target):
            dev.set_frame(self.target, DOWN)

    def set_sample(self, name: str) -> None:
        """Select the sample and move the hand over its block (module doc)."""
        super().set_sample(name)
        self._aim(name)

    def _tap_device(self):
        return self._device3.tap

    def _give_hand(self, traj, grip, hand) -> None:
        self._device3.set_user(traj, grip, hand=hand, target_m=self.target, direction=DOWN)

    def hand_position(self) -> tuple[float, float, float]:
        """Where the endpoint is (m, device frame): for the operator page."""
        st = self._device3.read()
        return float(st.x_m), float(st.y_m), float(st.position_m)

    def table_view(self) -> dict:
        """What the operator page draws (``study/session/web/operator.js``): the blocks' outlines seen from
        above (mm, device frame), the presented sample, and the hand: where the endpoint is, the block (or
        the table) under it and its height above that surface (mm)."""
        x, y, z = self.hand_position()
        blocks, over, top = [], "table", TABLE_Z_M
        for j, name in enumerate(self.packed.names):
            b = self.packed.bounds[j]
            if b is None:
                continue
            (x0, y0, _), (x1, y1, z1) = b
            blocks.append({"name": name, "x0_mm": 1000.0 * x0, "y0_mm": 1000.0 * y0, "x1_mm": 1000.0 * x1,
                           "y1_mm": 1000.0 * y1})
            if x0 <= x <= x1 and y0 <= y <= y1:
                over, top = name, float(z1)
        return {"blocks": blocks, "presented": block_name(self.current.name) if self.current is not None else None,
                "hand": {"x_mm": 1000.0 * x, "y_mm": 1000.0 * y, "z_mm": 1000.0 * z, "over": over,
                         "height_mm": 1000.0 * (z - top)}}

    def tap_window(self, window_s: float, first_tap_timeout_s: float, on_clip=None) -> TapResult:
        """As :meth:`Apparatus.tap_window`, with the 1-DOF channels added to the 3-D log (module doc)."""
        tap = super().tap_window(window_s, first_tap_timeout_s, on_clip)
        tap.log = self.one_dof_channels(tap.log)
        return tap

    def one_dof_channels(self, log: dict) -> dict:
        """``log`` (a 3-D run's) with ``position_m``, ``force_prop_N`` and ``current_A`` (module doc)."""
        u = self._device3.frame[3:6]
        t = self.target
        out = dict(log)
        out["position_m"] = u[0] * (log["x_m"] - t[0]) + u[1] * (log["y_m"] - t[1]) + u[2] * (log["z_m"] - t[2])
        out["force_prop_N"] = log["force_wall_N"]
        out["current_A"] = (u[0] * log["force_x_N"] + u[1] * log["force_y_N"] + u[2] * log["force_z_N"]) \
            / self.info.force_per_amp_N_A
        return out

    def record_reference(self, reference_sample: str = REFERENCE_SAMPLE) -> Reference:
        """As :meth:`Apparatus.record_reference`: the rater's real reference sample (the real wood) tapped from
        above, motor off, at the block of the catalog's real sample (else the first block)."""
        dev = self._device3
        real = [name for name, smp in self.blocks.items() if smp.kind == "real" and smp.real_sample == reference_sample]
        block = real[0] if real else next(iter(self.blocks), None)
        self._aim(block)
        dev.set_sample(reference_sample)
        dev.motor_enabled = False
        grip = self.sim_participant.grip_N if self.sim_participant else 2.0
        traj = TapTrajectory(list(REFERENCE_VELOCITIES_M_S), len(REFERENCE_VELOCITIES_M_S),
                             approach_height_m=self.protocol.home_height_m)
        dev.set_user(traj, grip, target_m=self.target, direction=DOWN)
        # the tapped block is the real sample (no wall: stiffness 0, so the passivity observer sees no energy)
        loop = ServoLoop3(dev, RendererConfig(stiffness_N_m=0.0, motor_enabled=False,
                                              scene=table_scene(self.blocks, presented=block),
                                              log_capacity_s=traj.duration_s + 1.0))
        check = self.stop_check
        try:
            result = loop.run(duration_s=traj.duration_s + 0.2, until=None if check is None else (lambda lp: check()))
        finally:
            dev.motor_enabled = True
            dev.set_sample("placeholder")
        events = result.events
        feats = tap_features(result.log["t_s"], result.log["accel_m_s2"], [e.t_s for e in events],
                             float(result.timing.get("log_rate_hz", self.fs_hz)))
        self.reference = Reference.fit([e.incoming_velocity_m_s for e in events], feats)
        return self.reference


def make_apparatus(device, catalog, protocol, **kw) -> Apparatus:
    """The apparatus for ``device``: :class:`Apparatus3` on a 3-axis device, else :class:`Apparatus`."""
    cls = Apparatus3 if device.info.axes == 3 else Apparatus
    return cls(device, catalog, protocol, **kw)
