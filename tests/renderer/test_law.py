"""The compiled servo law (renderer.law): one law for the per-tick loop and the compiled simulated loop.

The per-tick loop (``ServoLoop(compiled_sim=False)``: what hardware and paced simulations run) and the
compiled loop (law and physics in ``renderer.law.run_sim``) must give the same currents, forces, events
and stop reasons tick for tick on the same simulated taps; the law's collision must agree with the
scene's own penetration functions.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import stimuli
from devices.base import Status
from devices.sim import ScriptedTrajectory, SimDevice, TapTrajectory
from devices.sim import kernel as SK
from plumbing.jitcache import njit  # stamped with the law's sources: an edited layout recompiles the wrappers below
from renderer import RendererConfig, ServoLoop
from renderer import law as LAW
from renderer.scene import SHAPE_CODES, Box, Plane, Scene, Sphere, Wall

SCENE3 = Scene((Wall(0.0), Sphere((0.0, 0.0, -0.1), 0.09), Box((0.0, 0.0, -0.05), (0.02, 0.02, 0.045))))


def _run(compiled: bool, transient=None, scene=None, traj=None, until=None, seed=3):
    dev = SimDevice(seed=seed)
    dev.set_user(traj if traj is not None else TapTrajectory(0.12, n_taps=5), grip_N=2.0)
    cfg = RendererConfig() if scene is None else RendererConfig(scene=scene)
    loop = ServoLoop(dev, cfg, transient, compiled_sim=compiled)
    res = loop.run(until=until or (lambda lp: dev.trajectory_done), max_ticks=200_000)
    return res, dev


def _same(a, b):
    for name in a.log:
        if name in ("wall_ns", "compute_ns"):
            continue
        assert np.array_equal(a.log[name], b.log[name]), name
    assert [dataclasses.asdict(e) for e in a.events] == [dataclasses.asdict(e) for e in b.events]
    assert a.stop_reason == b.stop_reason and a.timing["ticks"] == b.timing["ticks"]


@pytest.mark.parametrize("transient", [None, stimuli.Pulse(), stimuli.DecayingSinusoid()],
                         ids=["wall", "pulse", "sinusoid"])
def test_compiled_loop_equals_per_tick_loop(transient):
    a, da = _run(False, transient)
    b, db = _run(True, transient)
    assert b.timing.get("realtime_factor", 0) > 0 and len(a.events) == 5
    assert np.max(np.abs(a.log["current_A"])) > 0.1          # the taps did push back
    _same(a, b)
    # the device ends in the same state: tick, pending current, sample; its vector has the law's layout
    assert len(db.fused_state()) == LAW.N_DEV and db.fused_state()[LAW.D_TICK] == db._tick
    assert da._tick == db._tick and da.last_command_A == db.last_command_A
    assert da.read().position_m == db.read().position_m and da.true_state() == db.true_state()


def test_compiled_loop_equals_per_tick_loop_in_a_scene():
    a, _ = _run(False, stimuli.Pulse(), scene=SCENE3)
    b, _ = _run(True, stimuli.Pulse(), scene=SCENE3)
    assert len(a.events) == 5
    _same(a, b)


def test_compiled_loop_follows_a_device_changed_by_the_callback():
    # the until callback swaps the sample under the stylus half way: the compiled loop must pick it up
    def until_for(dev_box):
        def until(lp):
            dev = dev_box[0]
            if lp.ticks >= 20_000 and dev.sample_name != "wood":
                dev.set_sample("wood")
            return dev.trajectory_done
        return until

    out = []
    for compiled in (False, True):
        box = [None]
        dev = SimDevice(seed=5)
        box[0] = dev
        dev.set_user(TapTrajectory(0.1, n_taps=4), grip_N=2.0)
        res = ServoLoop(dev, RendererConfig(), stimuli.Pulse(), compiled_sim=compiled).run(until=until_for(box))
        out.append(res)
    _same(*out)


def test_compiled_loop_follows_a_new_user_and_a_command_from_the_callback():
    # between its chunks the compiled loop keeps the device's arrays and state vector while the device says
    # nothing changed (SimDevice.fused_version): a new hand plan and a command given by the callback must
    # still reach it, as they reach the per-tick loop's next read()
    def until_for(dev):
        done = []

        def until(lp):
            if lp.ticks >= 3_000 and not done:
                done.append(lp.ticks)
                dev.set_user(TapTrajectory(0.15, n_taps=2), grip_N=2.5)
                dev.command(0.2)
            return bool(done) and dev.trajectory_done
        return until

    out = []
    for compiled in (False, True):
        dev = SimDevice(seed=7)
        dev.set_user(TapTrajectory(0.1, n_taps=3), grip_N=2.0)
        res = ServoLoop(dev, RendererConfig(until_every=4), stimuli.Pulse(), compiled_sim=compiled).run(
            until=until_for(dev), max_ticks=200_000)
        out.append((res, dev))
    (a, da), (b, db) = out
    assert a.stop_reason == "until" and len(a.events) >= 3
    _same(a, b)
    assert da._tick == db._tick and da.true_state() == db.true_state()


def test_compiled_loop_stops_on_invalid_sensors_like_the_per_tick_loop():
    # a hand path that leaves the position limit: held samples, then the stop, with zero current
    far = ScriptedTrajectory([0.0, 0.2, 2.2], [0.01, 0.01, 0.6])
    out = []
    for compiled in (False, True):
        dev = SimDevice(seed=1)
        dev.set_user(far, grip_N=2.0)
        res = ServoLoop(dev, RendererConfig(), compiled_sim=compiled).run(duration_s=2.2)
        out.append((res, dev))
    (a, da), (b, db) = out
    assert a.stop_reason == "sensor" and "invalid sensor samples" in a.error
    assert a.error == b.error
    _same(a, b)
    assert da.last_command_A == 0.0 and db.last_command_A == 0.0


def test_law_collision_matches_the_scene_shapes():
    shapes = [Wall(0.01), Plane((0.0, 0.01, 0.02), (0.3, -0.2, 1.0)), Sphere((0.01, 0.0, -0.05), 0.06),
              Sphere((0.0, 0.0, 0.0), 0.02), Box((0.0, 0.0, -0.05), (0.02, 0.02, 0.045)),
              Box((0.03, 0.0, 0.0), (0.02, 0.01, 0.01))]
    zs = np.concatenate([np.linspace(-0.2, 0.2, 401), [0.0, -0.05, 0.01]])
    for shape in shapes + [Scene(tuple(shapes))]:
        objs = shape.objects if isinstance(shape, Scene) else (shape,)
        c = np.zeros(LAW.C_OBJ + LAW.OBJ_STRIDE * len(objs))
        c[LAW.C_NOBJ] = len(objs)
        for j, obj in enumerate(objs):
            o = LAW.C_OBJ + LAW.OBJ_STRIDE * j
            c[o] = SHAPE_CODES[obj.shape]
            c[o + 1:o + 1 + len(obj.numbers())] = obj.numbers()
        for z in zs:
            d_ref, nz_ref = shape.penetration_1d(float(z))
            d, nz = _penetration(c, float(z))
            assert d == d_ref and nz == nz_ref, (shape, z)
        assert math.isfinite(d)


@njit(cache=True)
def _penetration(c, z):
    """The law's compiled collision (inlined into law_tick), called through a compiled wrapper."""
    return LAW.penetration(c, z)


def test_the_sim_command_rule_is_the_devices_and_matches_status_bits():
    assert (SK.STATUS_FAULT, SK.STATUS_CLIPPING) == (int(Status.FAULT), int(Status.CLIPPING))
    assert (LAW.HOT_STATUS, LAW.STATUS_SENSOR_INVALID, LAW.STATUS_DISCONNECTED) == (
        int(Status.OVER_TEMPERATURE), int(Status.SENSOR_INVALID), int(Status.DISCONNECTED))
    for cmd in (0.3, -0.3, 4.0, 7.5, -9.0, float("nan"), float("inf"), -float("inf")):
        py = SK.command_rule(cmd, 4.0)
        nb = _command_rule(cmd, 4.0)
        assert py == nb or (py[1:] == nb[1:] and py[0] == nb[0] == 0.0), cmd
    dev = SimDevice()
    dev.command(float("nan"))
    assert dev.rejected_commands == 1 and dev.last_command_A == 0.0 and dev.read().status & Status.FAULT
    dev.command(99.0)
    assert dev.last_command_A == dev.info.current_amplifier_A and dev.read().status & Status.CLIPPING


@njit(cache=True)
def _command_rule(i, limit):
    return SK.command_rule_nb(i, limit)
