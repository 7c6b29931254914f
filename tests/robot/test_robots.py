"""Shipped robots load and build; bad robot files give one clear error naming the file and the field."""

from __future__ import annotations

import pytest

from simnav.errors import ConfigError, UnknownNameError
from simnav.robot import list_robots, load_robot
from simnav.robot.mjcf import convex_parts
from simnav.sim.scene import build_scene
from tests.conftest import box_room_spec

ROBOT_YAML = """
name: tiny
prisms:
  - {name: base, z_min_m: 0.0, z_max_m: 0.3, polygon: [[0.2, -0.2], [0.2, 0.2], [-0.2, 0.2], [-0.2, -0.2]]}
sensors:
  - {name: laser, type: lidar2d, preset: hokuyo_urg04lx, mount: {xyz_m: [0.1, 0.0, 0.2]}}
"""


def test_all_shipped_robots_load_and_build():
    assert {"giraff", "rhodon", "minibot"} <= set(list_robots())
    for name in list_robots():
        robot = load_robot(name)
        model, index = build_scene(box_room_spec(), robot, pedestrians=2, wanderers=1, physics_dt_s=0.005)
        assert index.robot_body > 0 and model.nu == 3


def test_shipped_robots_match_the_thesis():
    giraff, rhodon, minibot = load_robot("giraff"), load_robot("rhodon"), load_robot("minibot")
    assert len(giraff.prisms) == 4 and 1.5 <= giraff.height_m <= 1.7
    assert len(rhodon.prisms) == 5 and rhodon.height_m == pytest.approx(1.8)
    arm = next(p for p in rhodon.prisms if p.name == "arm")
    base = next(p for p in rhodon.prisms if p.name == "base")
    reach = max(x for x, _ in arm.polygon) - max(x for x, _ in base.polygon)
    assert reach == pytest.approx(0.4, abs=0.05)
    kinect = rhodon.sensor("kinect")
    assert kinect.mount.rpy_deg[1] == 50
    assert minibot.drive.wheel_radius_m == 0.033 and minibot.drive.wheel_separation_m == 0.160
    assert minibot.hardware is not None


def test_non_convex_prisms_are_split_into_convex_parts():
    arm = next(p for p in load_robot("rhodon").prisms if p.name == "arm")
    parts = convex_parts(arm.polygon)
    assert len(parts) > 1
    from shapely.geometry import Polygon
    from shapely.ops import unary_union

    assert unary_union([Polygon(p) for p in parts]).area == pytest.approx(Polygon(arm.polygon).area)


def write(tmp_path, text):
    path = tmp_path / "robot.yaml"
    path.write_text(text)
    return path


def test_unknown_robot_lists_the_available_ones():
    with pytest.raises(UnknownNameError) as err:
        load_robot("wall-e")
    assert "wall-e" in str(err.value) and "giraff" in str(err.value) and "rhodon" in str(err.value)


def test_malformed_yaml_names_the_file_and_line(tmp_path):
    path = write(tmp_path, "name: x\nprisms: [\n  - oops: [1, 2\n")
    with pytest.raises(ConfigError) as err:
        load_robot(path)
    assert str(path) in str(err.value) and "line" in str(err.value)


def test_sensor_mounted_outside_the_robot(tmp_path):
    path = write(tmp_path, ROBOT_YAML.replace("[0.1, 0.0, 0.2]", "[1.5, 0.0, 0.2]"))
    with pytest.raises(ConfigError) as err:
        load_robot(path)
    message = str(err.value)
    assert str(path) in message and "'laser'" in message and "outside the robot" in message


def test_negative_rate_names_the_field(tmp_path):
    path = write(tmp_path, ROBOT_YAML.replace("mount:", "rate_hz: -5, mount:"))
    with pytest.raises(ConfigError) as err:
        load_robot(path)
    message = str(err.value)
    assert str(path) in message and "sensors.0.lidar2d.rate_hz" in message and "greater than 0" in message


def test_unknown_field_and_bad_values(tmp_path):
    with pytest.raises(ConfigError, match="drive.max_speed"):
        load_robot(write(tmp_path, ROBOT_YAML + "drive: {max_speed: 3}\n"))
    with pytest.raises(ConfigError, match="z_max_m"):
        load_robot(write(tmp_path, ROBOT_YAML.replace("z_max_m: 0.3", "z_max_m: -0.3")))
    with pytest.raises(UnknownNameError, match="hokuyo_urg04lx"):
        from simnav.sensors.presets import resolve_lidar2d

        robot = load_robot(write(tmp_path, ROBOT_YAML.replace("preset: hokuyo_urg04lx", "preset: x")))
        resolve_lidar2d(robot.sensors[0])


def test_overrides_by_index_and_name():
    robot = load_robot("giraff", ["sensors.camera.rate_hz=15", "sensors.0.noise_std_m=0.02", "drive.max_v_m_s=0.3"])
    assert robot.sensor("camera").rate_hz == 15
    assert robot.sensor("laser_front").noise_std_m == 0.02
    assert robot.drive.max_v_m_s == 0.3
    with pytest.raises(ConfigError, match="no list item 'lidar'"):
        load_robot("giraff", ["sensors.lidar.rate_hz=1"])
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        load_robot("giraff", ["drive.max_v_m_s"])
