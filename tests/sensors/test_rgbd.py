"""RGB-D camera: analytic depth of a wall and the floor, projection of known points, both backends agree,
segmentation and per-pixel motion of a walking person, noise never produces NaN."""

from __future__ import annotations

import numpy as np
import pytest

from simnav.geometry.camera import PinholeCamera
from simnav.robot import load_robot
from simnav.sim import SimConfig, Simulator
from tests.conftest import box_room_spec

IDEAL = ["sensors.depth.noise_k_per_m=0", "sensors.depth.depth_quantum_m=0", "sensors.depth.grazing_angle_deg=89.9",
         "sensors.depth.min_range_m=0.05", "sensors.depth.max_range_m=10"]
CAMERA_X, CAMERA_Z = 3.07, 0.12  # minibot depth camera in the box room (robot at x=3, y=2, facing +x)


def frame_in(world, overrides, backend="auto", seed=0, steps=1, pedestrians=0):
    robot = load_robot("minibot", overrides)
    with Simulator(world, robot, SimConfig(depth_backend=backend, pedestrians=pedestrians), seed=seed) as sim:
        for _ in range(steps):
            sim.step(0.0, 0.0)
        return sim.capture_now("depth"), sim


def analytic_depth(camera: PinholeCamera, wall_z: float) -> np.ndarray:
    """z-depth of a level camera at height CAMERA_Z facing a wall ``wall_z`` ahead, above a floor at z = 0."""
    rays = camera.rays_optical()
    y = rays[..., 1]  # optical y points down
    with np.errstate(divide="ignore"):
        floor_z = np.where(y > 0, CAMERA_Z / y, np.inf)
    return np.minimum(floor_z, wall_z)


@pytest.mark.parametrize("backend", ["gl", "raycast"])
def test_depth_of_wall_and_floor_is_analytic(box_room, backend):
    frame, _ = frame_in(box_room, IDEAL, backend)
    camera = PinholeCamera(160, 120, frame.K[0, 0], frame.K[1, 1], frame.K[0, 2], frame.K[1, 2])
    expected = analytic_depth(camera, 5.95 - CAMERA_X)
    valid = frame.depth_m > 0
    assert valid.mean() > 0.95
    np.testing.assert_allclose(frame.depth_m[valid], expected[valid], rtol=2e-3, atol=2e-3)


def test_known_point_projects_to_the_right_pixel():
    world = box_room_spec(cylinders=[dict(center=[4.5, 2.4], radius_m=0.1, height_m=1.0)])
    frame, sim = frame_in(world, IDEAL)
    K = frame.K
    # the cylinder's front at the camera height, in the optical frame: x right = -y_world, y down = -z_world
    p_optical = np.array([-(2.4 - 2.0), 0.0, 4.4 - CAMERA_X])
    u = K[0, 0] * p_optical[0] / p_optical[2] + K[0, 2]
    v = K[1, 1] * p_optical[1] / p_optical[2] + K[1, 2]
    assert u < K[0, 2]  # left of the image centre, as the cylinder is to the robot's left
    depth = frame.depth_m[int(round(v)), int(round(u))]
    assert depth == pytest.approx(p_optical[2], abs=0.01)
    beside = frame.depth_m[int(round(v)), int(round(u)) + 20]  # right of the cylinder: the wall
    assert beside == pytest.approx(5.95 - CAMERA_X, abs=0.01)


def test_backends_agree(box_room):
    gl, _ = frame_in(box_room_spec(cylinders=[dict(center=[4.5, 2.4], radius_m=0.1, height_m=1.0)]), IDEAL, "gl")
    rc, _ = frame_in(box_room_spec(cylinders=[dict(center=[4.5, 2.4], radius_m=0.1, height_m=1.0)]), IDEAL,
                     "raycast")
    both = (gl.depth_m > 0) & (rc.depth_m > 0)
    assert both.mean() > 0.95
    assert np.median(np.abs(gl.depth_m[both] - rc.depth_m[both])) < 1e-3
    assert (gl.body_id == rc.body_id).mean() > 0.98


def test_body_ids_follow_a_geom_hidden_while_running():
    """The GL backend keeps its segmentation table while the scene's geoms stay the same. Hiding a geom (alpha 0)
    while the simulator runs shifts the segmentation ids of the geoms after it: the ids must come out as from a
    camera that had the geom hidden from the start."""
    world = box_room_spec(roadmap=dict(nodes=[[4.6, 2.0], [5.5, 1.0], [5.5, 3.0]], edges=[[0, 1], [0, 2]]),
                          agents=dict(pedestrians=1))
    robot = load_robot("minibot", IDEAL)
    frames = []
    for hide_from_start in (False, True):
        with Simulator(world, robot, SimConfig(depth_backend="gl", pedestrians=1), seed=0) as sim:
            model, person = sim.model, sim.index.pedestrian_body[0]
            # a visible geom of the scenery that comes before the person's geoms in the scene
            scenery = max(g for g in range(model.ngeom) if model.geom_bodyid[g] == 0 and model.geom_rgba[g, 3] > 0
                          and model.geom_group[g] < 3 and g < np.flatnonzero(model.geom_bodyid == person)[0])
            if hide_from_start:
                model.geom_rgba[scenery, 3] = 0.0
            for _ in range(20):
                sim.step(0.0, 0.0)
            before = sim.capture_now("depth")
            model.geom_rgba[scenery, 3] = 0.0
            frames.append((before, sim.capture_now("depth")))
    (shown, hidden_now), (_, hidden_throughout) = frames
    assert (shown.body_id == person).sum() > 50 and (hidden_now.body_id == person).sum() > 50
    np.testing.assert_array_equal(hidden_now.body_id, hidden_throughout.body_id)
    np.testing.assert_array_equal(hidden_now.depth_m, hidden_throughout.depth_m)


def test_noise_grows_with_depth_and_never_nan(box_room):
    frame, _ = frame_in(box_room, ["sensors.depth.dropout_prob=0.05", "sensors.depth.grazing_angle_deg=89.9"])
    ideal, _ = frame_in(box_room, IDEAL)
    assert np.isfinite(frame.depth_m).all()
    assert np.isfinite(frame.velocity_optical).all()
    both = (frame.depth_m > 0) & (ideal.depth_m > 0)
    err = frame.depth_m[both] - ideal.depth_m[both]
    far = ideal.depth_m[both] > 2.5
    near = ideal.depth_m[both] < 1.0
    assert np.std(err[far]) > 3 * np.std(err[near])
    assert 0.02 < np.mean(frame.depth_m == 0) - np.mean(ideal.depth_m == 0) < 0.1


def test_grazing_floor_pixels_are_null(box_room):
    frame, _ = frame_in(box_room, IDEAL[:2] + ["sensors.depth.grazing_angle_deg=80"])
    # the floor is visible from row 66 on (closer than the wall); up to row ~84 it is seen at > 80 degrees
    assert (frame.depth_m[67:82, 1:-1] == 0).all()  # border columns have no neighbours to judge
    assert (frame.depth_m[90:] > 0).mean() > 0.99
    assert (frame.depth_m[:55] > 0).all()


def test_walking_person_segmentation_and_motion():
    world = box_room_spec(roadmap=dict(nodes=[[4.6, 2.0], [5.5, 1.0], [5.5, 3.0]], edges=[[0, 1], [0, 2]]),
                          agents=dict(pedestrians=1))
    frame, sim = frame_in(world, IDEAL, steps=20, pedestrians=1)
    person = sim.index.pedestrian_body[0]
    mask = frame.body_id == person
    assert mask.sum() > 50
    v_world = np.array([*sim.crowd.velocities_xy[0], 0.0])
    assert np.linalg.norm(v_world) > 0.2
    R_world_optical = (sim.T_world_base_at(frame.stamp_s) @ frame.T_base_sensor)[:3, :3]
    expected = R_world_optical.T @ v_world
    measured = np.median(frame.velocity_optical[:, mask], axis=1)
    cosine = measured @ expected / (np.linalg.norm(measured) * np.linalg.norm(expected))
    assert cosine > 0.95  # same direction in the optical frame (x right, y down, z forward)
    assert np.linalg.norm(measured) == pytest.approx(np.linalg.norm(expected), rel=0.3)
    assert np.all(frame.velocity_optical[:, frame.body_id == 0] == 0)  # static scenery does not move


def test_without_opengl_cameras_fall_back_to_ray_casting_and_say_so_once():
    import os
    import subprocess
    import sys

    code = (
        "import logging; logging.basicConfig(level=logging.WARNING)\n"
        "from simnav.robot import load_robot\n"
        "from simnav.sim import Simulator\n"
        "from tests.conftest import box_room_spec\n"
        "for _ in range(2):\n"
        "    sim = Simulator(box_room_spec(), load_robot('minibot'))\n"
        "    sim.step(0.0, 0.0)\n"
        "    frame = sim.latest('depth')\n"
        "    print(sim.sensors[1].backend, round(float((frame.depth_m > 0).mean()), 2))\n"
    )
    env = {**os.environ, "MUJOCO_GL": "disable"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300,
                         check=True)
    lines = out.stdout.split()
    assert lines[0] == "raycast" and float(lines[1]) > 0.5
    assert out.stderr.count("fall back to ray casting") == 1


def test_software_rendering_stays_in_the_rendering_thread():
    """simnav keeps Mesa's llvmpipe from starting rasteriser threads (LP_NUM_THREADS=0 unless the user sets it):
    after GL frames of both cameras the process has no llvmpipe threads, and a user's setting is kept."""
    import os
    import subprocess
    import sys

    code = (
        "import glob, os, simnav\n"
        "from simnav.robot import load_robot\n"
        "from simnav.sim import SimConfig, Simulator\n"
        "from tests.conftest import box_room_spec\n"
        "with Simulator(box_room_spec(), load_robot('minibot'), SimConfig(depth_backend='gl')) as sim:\n"
        "    sim.step(0.0, 0.0)\n"
        "    assert sim.capture_now('depth').depth_m.any()\n"
        "    names = [open(f).read().strip() for f in glob.glob('/proc/self/task/*/comm')]\n"
        "print(os.environ['LP_NUM_THREADS'], sum(n.startswith('llvmpipe') for n in names))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "LP_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300,
                         check=True)
    assert out.stdout.split() == ["0", "0"]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**env, "LP_NUM_THREADS": "2"}, timeout=300, check=True)
    assert out.stdout.split()[0] == "2"


@pytest.mark.parametrize("backend", ["gl", "raycast"])
def test_the_camera_does_not_see_its_own_robot(backend):
    # Rhodon's Kinect looks down over its outstretched arm: its own body must not become an obstacle
    import simnav  # noqa: F401
    from simnav.robot import load_robot
    from simnav.sim import SimConfig, Simulator
    from simnav.world import load_world

    with Simulator(load_world("desks"), load_robot("rhodon"),
                   SimConfig(pedestrians=0, wanderers=0, depth_backend=backend)) as sim:
        camera = next(s.name for s in sim.robot.sensors if s.type == "rgbd")
        frame = sim.capture_now(camera)
        robot_ids = np.nonzero(sim.index.body_kind == "robot")[0]
        assert not np.isin(frame.body_id, robot_ids).any()
        assert (frame.depth_m > 0).mean() > 0.5


def test_the_floor_shows_texture_to_the_colour_camera(box_room):
    # mottled tiles: neighbouring floor pixels differ (a flat-shaded floor gives a mean step below 0.1 grey levels)
    with Simulator(box_room, load_robot("giraff"), SimConfig(pedestrians=0, wanderers=0), seed=0) as sim:
        frame = sim.capture_now("camera")
    floor = frame.rgb.astype(float).mean(axis=2)[-60:, :]
    assert np.abs(np.diff(floor, axis=1)).mean() > 1.0


def test_floor_texture_is_deterministic_with_dark_joints():
    from simnav.world.mjcf import FLOOR_TEXTURE_M, FLOOR_TILE_M, floor_texture

    a, b = floor_texture(256, seed=3), floor_texture.__wrapped__(256, seed=3)
    np.testing.assert_array_equal(a, b)
    tile_px = round(256 * FLOOR_TILE_M / FLOOR_TEXTURE_M)
    assert a[:, ::tile_px].mean() < 0.75 * a.mean()  # joints every tile
    assert not a.flags.writeable
