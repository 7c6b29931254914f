"""Simulator behaviour: drive model, clocks, determinism, contacts, agents that stay out of walls."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from shapely.geometry import Point

from simnav.errors import SimnavError
from simnav.robot import RobotInterface, load_robot
from simnav.sensors.readings import LaserScan, RGBDFrame, WheelTicks
from simnav.sim import SimConfig, SimRobot, Simulator
from simnav.world import load_world
from simnav.world.footprint import obstacle_polygons
from tests.conftest import box_room_spec

LIDAR_ONLY = ["sensors.camera.rate_hz=0.001"]


def test_unicycle_motion_follows_the_command(box_room):
    stiff = ["drive.command_latency_s=0", "drive.max_acc_m_s2=100", "drive.max_ang_acc_deg_s2=10000"]
    robot = load_robot("giraff", LIDAR_ONLY + stiff)
    with Simulator(box_room_spec(spawns=[{"x_m": 1.5, "y_m": 1.0}]), robot) as sim:
        for _ in range(40):  # 2 s at v = 0.3 m/s, w = 0.2 rad/s
            sim.step(0.3, 0.2)
        x, y, yaw = sim.pose_xy_yaw
    # ideal arc from (1.5, 1.0); the velocity servos lag by their 20 ms time constant
    ideal = np.array([1.5 + 1.5 * math.sin(0.4), 1.0 + 1.5 * (1 - math.cos(0.4)), 0.4])
    assert np.allclose([x, y, yaw], ideal, atol=0.01)
    v, w = sim.base_velocity()
    assert v == pytest.approx(0.3, abs=1e-3) and w == pytest.approx(0.2, abs=1e-3)


def test_latency_and_acceleration_limits(box_room):
    robot = load_robot("giraff", LIDAR_ONLY + ["drive.command_latency_s=0.1", "drive.max_acc_m_s2=0.5"])
    with Simulator(box_room, robot) as sim:
        sim.step(0.5, 0.0)  # 50 ms: the command has not arrived yet
        assert abs(sim.base_velocity()[0]) < 1e-3
        for _ in range(3):  # 150 ms later: 50 ms of ramping at 0.5 m/s^2 -> about 0.025 m/s
            sim.step(0.5, 0.0)
        assert 0.01 < sim.base_velocity()[0] < 0.05
        for _ in range(30):
            sim.step(0.5, 0.0)
        assert sim.base_velocity()[0] == pytest.approx(0.5, abs=0.01)


def test_a_measured_velocity_skips_the_motor_model(box_room):
    # hardware in the loop: real motors measured (v, w); the simulated motor must not add its latency and ramp
    robot = load_robot("giraff", LIDAR_ONLY + ["drive.command_latency_s=0.1", "drive.max_acc_m_s2=0.5"])
    with Simulator(box_room, robot) as sim:
        sim.step(0.5, 0.3, measured=True)  # 50 ms: only the base's 20 ms velocity servo lags
        v, w = sim.base_velocity()
        assert 0.4 < v <= 0.5 and 0.24 < w <= 0.3
        sim.step(0.0, 0.0, measured=True)
        assert abs(sim.base_velocity()[0]) < 0.06
        sim.step(0.5, 0.0)  # back to commands: the latency holds this one back
        assert abs(sim.base_velocity()[0]) < 0.01


def test_commands_are_clamped_and_nan_is_refused(box_room):
    with Simulator(box_room, load_robot("giraff", LIDAR_ONLY)) as sim:
        for _ in range(40):
            sim.step(10.0, 0.0)
        assert sim.base_velocity()[0] == pytest.approx(0.7, abs=0.01)
        with pytest.raises(SimnavError, match="finite"):
            sim.step(float("nan"), 0.0)


def test_sensor_rates_and_stamps(box_room):
    with Simulator(box_room, load_robot("giraff", ["sensors.camera.rate_hz=15"])) as sim:
        readings = []
        for _ in range(20):  # 1 s
            readings += sim.step(0.0, 0.0)
    by_type = {t: [r.stamp_s for r in readings if isinstance(r, t)] for t in (LaserScan, RGBDFrame, WheelTicks)}
    assert len(by_type[LaserScan]) == 11  # 10 Hz, t = 0 ... 1.0
    assert len(by_type[RGBDFrame]) == 16  # 15 Hz, t = 0 ... 1.0
    assert len(by_type[WheelTicks]) == 51  # 50 Hz
    assert np.allclose(np.diff(by_type[LaserScan]), 0.1)
    assert all(a <= b for a, b in zip([r.stamp_s for r in readings], [r.stamp_s for r in readings][1:]))


def test_reading_latency(box_room):
    robot = load_robot("giraff", LIDAR_ONLY + ["sensors.laser_front.latency_s=0.12"])
    with Simulator(box_room, robot) as sim:
        sim.step(0.0, 0.0)
        assert sim.latest("laser_front") is None
        for _ in range(3):
            sim.step(0.0, 0.0)
        assert sim.latest("laser_front").stamp_s == 0.0


def test_wheel_ticks_follow_the_motion(box_room):
    robot = load_robot("giraff", LIDAR_ONLY + ["drive.slip_std=0"])
    with Simulator(box_room_spec(spawns=[{"x_m": 1.0, "y_m": 2.0}]), robot) as sim:
        x0 = sim.pose_xy_yaw[0]
        for _ in range(40):
            sim.step(0.4, 0.0)
        ticks = sim.latest("wheels")
        travelled = sim.pose_xy_yaw[0] - x0
    per_tick = 2 * math.pi * robot.drive.wheel_radius_m / robot.drive.ticks_per_rev
    assert ticks.left_ticks * per_tick == pytest.approx(travelled, abs=0.01)
    assert ticks.right_ticks == pytest.approx(ticks.left_ticks, abs=2)


def same_run(seed: int):
    world = load_world("office")
    robot = load_robot("giraff", ["sensors.camera.preset=kinect_qqvga", "sensors.camera.rate_hz=5"])
    out = []
    with Simulator(world, robot, SimConfig(pedestrians=6, wanderers=1), seed=seed) as sim:
        for k in range(30):
            out += sim.step(0.3, 0.3 * math.sin(k / 5))
        gt = sim.T_world_base.copy()
        crowd = sim.crowd.positions_xy.copy()
    return out, gt, crowd


def test_same_seed_same_readings_and_ground_truth():
    a, gt_a, crowd_a = same_run(3)
    b, gt_b, crowd_b = same_run(3)
    c, _, crowd_c = same_run(4)
    assert len(a) == len(b)
    for ra, rb in zip(a, b, strict=True):
        assert type(ra) is type(rb) and ra.stamp_s == rb.stamp_s
        for name in ("ranges_m", "depth_m", "rgb", "body_id", "velocity_optical"):
            if hasattr(ra, name):
                np.testing.assert_array_equal(getattr(ra, name), getattr(rb, name))
    np.testing.assert_array_equal(gt_a, gt_b)
    np.testing.assert_array_equal(crowd_a, crowd_b)
    assert not np.array_equal(crowd_a, crowd_c)


def test_driving_into_a_wall_is_a_contact_event(box_room):
    with Simulator(box_room, load_robot("giraff", LIDAR_ONLY)) as sim:
        for _ in range(200):  # 10 s towards the wall 2.95 m ahead
            sim.step(0.5, 0.0)
        events = sim.contact_events
        x = sim.pose_xy_yaw[0]
    assert events and events[0].kind == "static" and events[0].other == "world"
    assert events[0].position_world[0] == pytest.approx(5.95, abs=0.05)
    assert 4.0 < events[0].stamp_s < 7.0
    assert x < 5.95 - 0.26 + 0.05  # the wall stops the robot (front of the base is 0.26 m ahead)


def test_robot_interface(box_room):
    sim = Simulator(box_room, load_robot("giraff", LIDAR_ONLY))
    robot = SimRobot(sim)
    assert isinstance(robot, RobotInterface)
    robot.send_velocity(0.2, 0.0)
    for _ in range(10):
        robot.wait_next_period()
    readings = robot.poll_readings()
    assert {r.sensor for r in readings} == {"laser_front", "wheels", "camera"}
    assert sum(r.sensor == "laser_front" for r in readings) == 6  # 10 Hz, t = 0, 0.1, ... 0.5
    assert robot.poll_readings() == []
    assert robot.now_s() == pytest.approx(0.5)
    sim.close()


@pytest.mark.slow
def test_people_never_end_inside_walls_or_each_other():
    world = load_world("office")
    robot = load_robot("giraff", ["sensors=[]"])
    config = SimConfig(pedestrians=12, wanderers=1, control_dt_s=0.2)
    walls = obstacle_polygons(world, 0.0, 2.0)
    with Simulator(world, robot, config, seed=7) as sim:
        radius = sim.crowd.radius_m
        for _ in range(10_000 // 5):  # 10,000 agent steps of 40 ms
            sim.step(0.0, 0.0)
            xy = sim.crowd.positions_xy
            gaps = np.linalg.norm(xy[:, None] - xy[None], axis=-1) + np.eye(len(xy)) * 1e9
            assert gaps.min() >= 2 * radius - 1e-3
            for p in xy:
                assert min(poly.distance(Point(p)) for poly in walls) >= radius - 1e-3
        assert np.isfinite(sim.crowd.positions_xy).all()


def test_doors_and_other_robots_move_as_mocap_bodies():
    world = load_world("office")
    with Simulator(world, load_robot("giraff", ["sensors=[]"]), SimConfig(pedestrians=2, wanderers=1)) as sim:
        door_quats, wanderer_xy = [], []
        for _ in range(40):
            for _ in range(20):  # 1 s
                sim.step(0.0, 0.0)
            door_quats.append(sim.data.mocap_quat[sim.index.door_mocap].copy())
            wanderer_xy.append(sim.data.mocap_pos[sim.index.wanderer_mocap, :2].copy())
        yaw = [2 * np.arctan2(q[:, 3], q[:, 0]) for q in door_quats]
        expected = np.array([door.yaw_rad for door in sim.doors])
    np.testing.assert_allclose(np.angle(np.exp(1j * (yaw[-1] - expected))), 0, atol=0.05)
    assert np.ptp(np.array(yaw), axis=0).max() > 1.0  # some door swung during the 40 s
    assert np.linalg.norm(wanderer_xy[-1] - wanderer_xy[0]) > 1.0


def test_driving_into_a_closed_door_is_a_moving_body_contact():
    door = dict(hinge=[4.5, 1.5], width_m=0.9, closed_yaw_deg=90, open_s=5, closed_s=100, move_s=1.0,
                phase_s=6.0, auto_open_radius_m=0)  # closed from t = 0 for 100 s, never opened for the robot
    world = box_room_spec(doors=[door])
    with Simulator(world, load_robot("giraff", LIDAR_ONLY)) as sim:
        sim.step(0.0, 0.0)
        scan = sim.latest("laser_front")
        centre = np.argmin(np.abs(scan.angles_rad))
        assert scan.ranges_m[centre] == pytest.approx(4.5 - 0.02 - 3.22, abs=0.03)  # the leaf, not the wall
        for _ in range(100):
            sim.step(0.4, 0.0)
    kinds = {(e.kind, e.other) for e in sim.contact_events}
    assert ("door", "door0") in kinds
    assert sim.pose_xy_yaw[0] < 4.5 - 0.26 + 0.03


def test_teleport_then_capture(box_room):
    with Simulator(box_room, load_robot("giraff", LIDAR_ONLY + ["sensors.laser_front.noise_std_m=0"])) as sim:
        sim.teleport(1.0, 2.0, math.pi)
        scan = sim.capture_now("laser_front")
        assert sim.pose_xy_yaw == pytest.approx((1.0, 2.0, math.pi))
    centre = np.argmin(np.abs(scan.angles_rad))
    assert scan.ranges_m[centre] == pytest.approx(1.0 - 0.22 - 0.05, abs=1e-3)  # facing -x: wall face at 0.05


def test_a_robot_at_rest_still_follows_commands(box_room):
    # the scene skips the static geoms' kinematics through MuJoCo's sleep feature: the actuated robot never sleeps
    with Simulator(box_room, load_robot("giraff", LIDAR_ONLY)) as sim:
        assert sim.model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_SLEEP
        for _ in range(40):  # 2 s at rest
            sim.step(0.0, 0.0)
        for _ in range(20):
            sim.step(0.3, 0.0)
        assert sim.base_velocity()[0] == pytest.approx(0.3, abs=0.01)
        assert sim.data.ntree_awake == sim.model.ntree
