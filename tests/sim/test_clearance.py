"""Skipping MuJoCo's collision detection while the robot is clear of everything changes nothing."""

from __future__ import annotations

import mujoco
import numpy as np

from simnav.robot import load_robot
from simnav.sim import SimConfig, Simulator, simulator
from simnav.sim.clearance import ContactClearance
from simnav.sim.native import STATE
from simnav.sim.simulator import _NO_SHADOW
from simnav.world import load_world
from tests.conftest import box_room_spec

LIDAR_ONLY = ["sensors.camera.rate_hz=0.001"]


def _drive(sim: Simulator, steps: int) -> tuple[list, list, list]:
    """Seeded commands with stretches straight ahead (into walls and people): the history of base poses, the
    contact events and the lidar ranges."""
    rng = np.random.default_rng(5)
    scans = []
    for k in range(steps):
        v, w = (0.7, 0.0) if k % 40 < 12 else tuple(rng.uniform(-1, 1, 2) * (0.7, 1.0))
        scans += [r.ranges_m for r in sim.step(v, w) if r.sensor == "laser_front"]
    events = [(e.stamp_s, e.kind, e.other, e.position_world.tolist(), e.depth_m) for e in sim.contact_events]
    return list(sim._history), events, scans


def test_skipping_collision_detection_changes_nothing(monkeypatch):
    world, robot = load_world("office"), load_robot("giraff", LIDAR_ONLY)
    config = SimConfig(pedestrians=6, wanderers=1)
    with Simulator(world, robot, config, seed=2) as sim:
        decisions = []
        clear_steps = sim._clearance.clear_steps
        monkeypatch.setattr(sim._clearance, "clear_steps",
                            lambda *a: decisions.append((clear_steps(*a), a[1])) or decisions[-1][0])
        skipping = _drive(sim, 600)
    monkeypatch.undo()
    with Simulator(world, robot, config, seed=2) as sim:
        monkeypatch.setattr(sim._clearance, "clear_steps", lambda *a: 0)
        detecting = _drive(sim, 600)
    clear = [steps for steps, _ in decisions]
    assert min(clear) == 0 and any(0 < steps < horizon for steps, horizon in decisions)  # none, some, all
    assert any(steps == horizon for steps, horizon in decisions)
    assert skipping[1], "the run makes contacts"
    assert skipping[0] == detecting[0] and skipping[1] == detecting[1]
    for a, b in zip(skipping[2], detecting[2], strict=True):
        np.testing.assert_array_equal(a, b)


def test_clear_only_away_from_everything():
    with Simulator(box_room_spec(), load_robot("giraff", LIDAR_ONLY)) as sim:
        clearance, middle, still = sim._clearance, np.array([3.0, 2.0, 0.0]), np.zeros(3)
        assert clearance.usable
        assert clearance.clear_steps(sim.data, 10, middle, still) == 10  # 1.95 m from any wall
        assert clearance.clear_steps(sim.data, 10, np.array([5.95 - 0.37, 2.0, 0.0]), still) == 0  # touching
        assert 0 < clearance.clear_steps(sim.data, 10, np.array([5.95 - 0.4, 2.0, 0.0]), still) < 10
        # 30 m/s: the 1.95 m less the footprint's 0.37 m are crossed within 10 steps of 5 ms
        assert 0 < clearance.clear_steps(sim.data, 10, middle, np.array([30.0, 0.0, 0.0])) < 10
        assert 0 < clearance.clear_steps(sim.data, 1000, middle, still) < 1000


def test_a_scene_outside_its_assumptions_is_never_clear():
    spec = mujoco.MjSpec()
    robot = spec.worldbody.add_body(name="robot")
    for name, kind, axis in (("x", mujoco.mjtJoint.mjJNT_SLIDE, [1, 0, 0]), ("y", mujoco.mjtJoint.mjJNT_SLIDE,
                                                                           [0, 1, 0]),
                             ("yaw", mujoco.mjtJoint.mjJNT_HINGE, [0, 0, 1])):
        robot.add_joint(name=name, type=kind, axis=axis)
    robot.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.2, 0, 0], pos=[0, 0, 0.2])
    ball = spec.worldbody.add_body(name="ball", pos=[5, 0, 1])  # a body that physics moves
    ball.add_freejoint()
    ball.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.1, 0, 0])
    model = spec.compile()
    data = mujoco.MjData(model)
    clearance = ContactClearance(model, model.body("robot").id, 1.0)
    assert not clearance.usable
    assert clearance.clear_steps(data, 1, np.zeros(3), np.zeros(3)) == 0


def test_the_compiled_motor_ramp_and_its_shadow_change_nothing(monkeypatch):
    """The motor ramp's stretches run in one compiled call, most of them in a robot-only shadow model
    (simnav.sim.native); without the shadow, or stepped from Python, the poses after every stretch, the contacts,
    the scans and the final state are the same to the bit (a robot without wheel encoders: with them, the ramp
    is stepped from Python)."""
    world, robot = load_world("office"), load_robot("giraff")
    robot = robot.model_copy(update={"sensors": [s for s in robot.sensors if s.type == "lidar2d"]})
    config = SimConfig(pedestrians=6, wanderers=1)
    compiled_stretches = []
    ramp_steps = simulator.ramp_steps

    def counted(*args):
        out = ramp_steps(*args)
        compiled_stretches.append(out[3])
        return out

    monkeypatch.setattr(simulator, "ramp_steps", counted)
    runs = []
    for variant in ("shadow", "compiled", "python"):
        with Simulator(world, robot, config, seed=3) as sim:
            assert sim._native_scene is not None and sim._shadow is not None, "both are available here"
            if variant != "shadow":
                sim._native_shadow = _NO_SHADOW
            if variant == "python":
                sim._native_scene = None
            history, events, scans = _drive(sim, 400)
            if variant == "shadow":
                assert sum(compiled_stretches) > 1000 and events, "the compiled ramp ran, and contacts were made"
            state = np.empty(mujoco.mj_stateSize(sim.model, STATE))
            mujoco.mj_getState(sim.model, sim.data, state, STATE)
            runs.append((history, events, scans, state, sim.data.qacc.copy(), sim.data.xpos.copy()))
    for other in runs[1:]:
        assert other[0] == runs[0][0] and other[1] == runs[0][1]
        for a, b in zip(other[2], runs[0][2], strict=True):
            np.testing.assert_array_equal(a, b)
        for a, b in zip(other[3:], runs[0][3:], strict=True):
            np.testing.assert_array_equal(a, b)
