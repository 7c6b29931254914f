"""The planar ray caster against MuJoCo's own ``mj_multiRay`` on every primitive it models, and its fallbacks."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from simnav.robot import load_robot
from simnav.sensors.lidar import Lidar2D, RayCaster
from simnav.sensors.planar_rays import cast_planar, world_azimuths
from simnav.sim import SimConfig, Simulator
from simnav.world import load_world

# every modelled primitive, upright, lying and rotated, around a scanner; group 3 is seen by the lidar, group 0 not
SCENE = """
<mujoco>
  <worldbody>
    <geom type="plane" size="10 10 0.1" group="3"/>
    <geom type="box" size="0.3 0.2 0.5" pos="2 0 0.5" euler="0 0 30" group="3"/>
    <geom type="box" size="0.4 0.3 0.2" pos="-2 0.5 0.3" xyaxes="0.94 0.342 0 0 0 1" group="3"/>
    <geom type="box" size="0.2 0.2 0.2" pos="0 -2 0.2" xyaxes="0 0 1 -0.7071 0.7071 0" group="3"/>
    <geom type="cylinder" size="0.25 0.5" pos="1.5 1.5 0.5" group="3"/>
    <geom type="cylinder" size="0.3 0.6" pos="-1.5 -1.5 0.3" euler="90 0 35" group="3"/>
    <geom type="capsule" size="0.2 0.4" pos="0 2.5 0.6" group="3"/>
    <geom type="capsule" size="0.35 0.5" pos="-3 -0.5 0.42" euler="0 90 -20" group="3"/>
    <geom type="sphere" size="0.4" pos="2.5 -2 0.5" group="3"/>
    <geom type="box" size="0.2 0.2 0.2" pos="1 -1 0.3" group="3" rgba="1 1 1 0"/>
    <geom type="box" size="0.2 0.2 0.2" pos="-1 1 0.3" group="0"/>
    <geom name="wall" type="box" size="5 0.05 1" pos="0 4 1" group="3"/>
    <body name="scanner" pos="0 0 0.35">
      <joint type="free"/>
      <geom type="cylinder" size="0.1 0.1" group="3"/>
      <site name="scan"/>
    </body>
  </worldbody>
</mujoco>
"""


def make_caster(xml: str, dirs: np.ndarray, planar: bool | None = None):
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    caster = RayCaster(model, "scan", dirs, model.body("scanner").id, 8.0, planar=planar)
    return model, data, caster


def scan_dirs(n: int = 721) -> np.ndarray:
    a = np.linspace(-np.pi, np.pi, n, endpoint=False)
    return np.column_stack([np.cos(a), np.sin(a), np.zeros(n)])


def place(model, data, xyz, quat) -> None:
    data.qpos[:3], data.qpos[3:7] = xyz, quat
    mujoco.mj_kinematics(model, data)


def both(caster, data) -> tuple[np.ndarray, np.ndarray]:
    caster.planar = True
    fast = caster.cast(data)
    caster.planar = False
    reference = caster.cast(data)
    caster.planar = True
    return fast, reference


def inside_lying_capsule(model, data, xyz) -> bool:
    g = next(g for g in range(model.ngeom) if model.geom_type[g] == 3 and abs(data.geom_xmat[g][8]) < 0.5)
    (radius, half), axis = model.geom_size[g][:2], data.geom_xmat[g].reshape(3, 3)[:, 2]
    rel = np.asarray(xyz) - data.geom_xpos[g]
    along = np.clip(rel @ axis, -half, half)
    return bool(np.linalg.norm(rel - along * axis) < radius)


def planar_kernel_ok(model, data, caster) -> bool:
    site = caster._site
    dirs = caster._dirs @ data.site_xmat[site].reshape(3, 3).T
    az = np.empty(len(dirs))
    world_azimuths(np.arctan2(caster._dirs[:, 1], caster._dirs[:, 0]), data.site_xmat[site], az)
    dist, geom = np.empty(len(dirs)), np.empty(len(dirs), dtype=np.int32)
    return cast_planar(data.site_xpos[site].copy(), dirs, az, caster._seen, model.geom_type, model.geom_size,
                       model.geom_rbound, data.geom_xpos, data.geom_xmat, 8.0, dist, geom)


@pytest.mark.parametrize("height_m", [0.05, 0.35, 0.62, 0.85, 1.05])
@pytest.mark.parametrize("quat", [(1, 0, 0, 0), (np.cos(0.4), 0, 0, np.sin(0.4)), (0, 1, 0, 0)],
                         ids=["upright", "yawed", "upside-down"])
def test_planar_scan_equals_mj_multiray(height_m, quat):
    model, data, caster = make_caster(SCENE, scan_dirs())
    assert caster.planar
    rng = np.random.default_rng(int(height_m * 100))
    for xy in [(0.0, 0.0), *rng.uniform(-3.5, 3.5, (20, 2))]:
        place(model, data, (*xy, height_m), quat)
        # the one case the kernel hands back: the origin inside the lying capsule (a union of shapes)
        assert planar_kernel_ok(model, data, caster) != inside_lying_capsule(model, data, (*xy, height_m))
        fast, reference = both(caster, data)
        np.testing.assert_allclose(fast, reference, rtol=0, atol=1e-9)


def test_scan_sees_every_kind_of_section():
    model, data, caster = make_caster(SCENE, scan_dirs())
    place(model, data, (0.0, 0.0, 0.35), (1, 0, 0, 0))
    caster.cast(data)
    hit = set(caster._geomid[caster._geomid >= 0].tolist())
    kinds = {(int(model.geom_type[g]), bool(abs(data.geom_xmat[g][8]) < 0.5)) for g in hit}
    # upright and lying boxes, cylinders and capsules, and the sphere
    assert {(6, False), (6, True), (5, False), (5, True), (3, False), (3, True), (2, False)} <= kinds
    hidden = [i for i in range(model.ngeom) if model.geom_rgba[i, 3] == 0 or model.geom_group[i] == 0]
    assert hit.isdisjoint(hidden)


def test_ray_starting_inside_a_geom_gives_the_exit_like_mujoco():
    model, data, caster = make_caster(SCENE, scan_dirs())
    place(model, data, (2.0, 0.05, 0.35), (1, 0, 0, 0))  # inside the yawed box
    fast, reference = both(caster, data)
    np.testing.assert_allclose(fast, reference, rtol=0, atol=1e-9)
    assert np.all(fast[fast > 0] < 0.5)


def test_tilted_geom_in_the_plane_falls_back_to_mujoco():
    # a slanted box that reaches the scan plane
    xml = SCENE.replace('xyaxes="0 0 1 -0.7071 0.7071 0"', 'euler="0 30 45"')
    model, data, caster = make_caster(xml, scan_dirs())
    place(model, data, (0.0, 0.0, 0.3), (1, 0, 0, 0))
    assert not planar_kernel_ok(model, data, caster)
    fast, reference = both(caster, data)
    np.testing.assert_array_equal(fast, reference)
    assert np.sum((fast > 0) & (fast < 2.0)) > 0  # the slanted box is seen


def test_tilted_scan_plane_falls_back_to_mujoco():
    model, data, caster = make_caster(SCENE, scan_dirs())
    place(model, data, (0.0, 0.0, 0.35), (np.cos(0.05), np.sin(0.05), 0, 0))  # rolled 5.7 degrees
    assert not planar_kernel_ok(model, data, caster)
    fast, reference = both(caster, data)
    np.testing.assert_array_equal(fast, reference)


def test_non_planar_rays_or_meshes_always_use_mujoco():
    dirs = scan_dirs()
    dirs[:, 2] = 0.1
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    assert not make_caster(SCENE, dirs)[2].planar
    mesh = '<asset><mesh name="m" vertex="0 0 0 1 0 0 0 1 0 0 0 1"/></asset>'
    xml = SCENE.replace("<worldbody>", mesh + '<worldbody><geom type="mesh" mesh="m" pos="3 3 0" group="3"/>')
    assert not make_caster(xml, scan_dirs())[2].planar
    assert not make_caster(SCENE, scan_dirs(), planar=False)[2].planar


def test_office_scans_match_mujoco_with_people_walking():
    robot = load_robot("giraff", ["sensors.camera.rate_hz=0.001"])
    with Simulator(load_world("office"), robot, SimConfig(), seed=1) as sim:
        caster = next(s for s in sim.sensors if isinstance(s, Lidar2D))._caster
        assert caster.planar
        rng = np.random.default_rng(1)
        for _ in range(60):
            sim.step(*rng.uniform([-0.3, -1.0], [0.7, 1.0]))
            mujoco.mj_kinematics(sim.model, sim.data)
            assert planar_kernel_ok(sim.model, sim.data, caster)
            fast, reference = both(caster, sim.data)
            np.testing.assert_allclose(fast, reference, rtol=0, atol=1e-9)
