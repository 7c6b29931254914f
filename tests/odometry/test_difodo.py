"""DIFODO (thesis §3.E): motion recovery on ray-cast depth images, robustness, degeneracy, mount, pyramid.

Depth images come from a pure-numpy ray caster of a 6 x 5 x 2.8 m box room with a few axis-aligned boxes inside
(:func:`render`): each pixel's ray is intersected with the room (from inside) and with every box (slab method).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from simnav.errors import ConfigError
from simnav.geometry import se3
from simnav.geometry.camera import R_BODY_OPTICAL, box_room_depth
from simnav.odometry import difodo as difodo_module
from simnav.odometry.depth_pyramid import (
    LevelCamera,
    gated_downsample,
    plan_pyramid,
    warp_depth,
)
from simnav.odometry.difodo import (
    DIFODO,
    DifodoConfig,
    edge_aware_gradient,
    hold_weak_translations,
    level_system,
)
from simnav.sensors.readings import RGBDFrame

ROOM = np.array([[-3.0, -2.5, 0.0], [3.0, 2.5, 2.8]])
"""Lower and upper corners of the room (world frame, z up), m."""
BOXES = np.array([
    [[1.5, -1.8, 0.0], [2.3, -0.9, 0.9]],
    [[2.0, 0.5, 0.0], [2.9, 1.6, 1.6]],
    [[0.8, -0.2, 0.0], [1.1, 0.3, 1.2]],
    [[1.2, 0.9, 1.0], [1.6, 1.3, 1.4]],
    [[-0.5, 1.6, 0.0], [0.1, 2.5, 0.5]],
])
"""(n, 2, 3) lower and upper corners of the boxes in the room, m."""
T_BASE_CAMERA = se3.from_rotation_translation(R_BODY_OPTICAL, [0.1, 0.0, 1.0])
"""Forward-looking camera 1 m above the base (optical frame: z forward, x right, y down)."""
T_WORLD_BASE0 = se3.from_rpy(0.0, 0.0, math.radians(8.0), [-1.6, 0.2, 0.23])
DT_S = 1.0 / 30.0


def intrinsics(height: int, width: int) -> np.ndarray:
    """(3, 3) Kinect-like K (525 px focal length at VGA) for a QVGA- or QQVGA-sized image."""
    f = 525.0 * width / 640.0
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


def render(T_world_camera: np.ndarray, K: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) float32 z-depth of the room seen from optical frame pose ``T_world_camera``, m."""
    return box_room_depth(T_world_camera, K, shape, ROOM, BOXES)[0].astype(np.float32)


def frame(T_world_base: np.ndarray, stamp_s: float, shape: tuple[int, int] = (240, 320), noise_k: float = 0.0,
          rng: np.random.Generator | None = None, T_base_camera: np.ndarray = T_BASE_CAMERA) -> RGBDFrame:
    """An RGB-D frame (no colour) from base pose ``T_world_base``; ``noise_k`` adds N(0, (k z^2)^2) noise."""
    K = intrinsics(*shape)
    depth = render(T_world_base @ T_base_camera, K, shape)
    if noise_k > 0:
        depth = depth + (noise_k * depth**2 * rng.standard_normal(depth.shape)).astype(np.float32)
    return RGBDFrame("depth", stamp_s, depth, None, K, T_base_camera.copy())


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation angle (deg) of ``inv(T_true) @ T_est``."""
    xi = se3.log(se3.inverse(T_true) @ T_est)
    return float(np.linalg.norm(xi[:3])), math.degrees(float(np.linalg.norm(xi[3:])))


def camera_motion(T_base_motion: np.ndarray, T_base_camera: np.ndarray = T_BASE_CAMERA) -> np.ndarray:
    """(4, 4) motion of the camera frame for a base motion (both expressed in their own frames)."""
    return se3.inverse(T_base_camera) @ T_base_motion @ T_base_camera


def plane_depth(T_plane_camera: np.ndarray, K: np.ndarray, shape: tuple[int, int], normal: tuple[float, float, float],
                offset_m: float) -> np.ndarray:
    """(H, W) float32 depth of the plane ``n . p = offset`` (plane frame) seen from ``T_plane_camera``, m."""
    h, w = shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    n = np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
    d = rays @ T_plane_camera[:3, :3].T
    return ((offset_m - n @ T_plane_camera[:3, 3]) / (d @ n)).astype(np.float32)


def two_frames(motion: np.ndarray, shape: tuple[int, int], noise_k: float = 0.0, seed: int = 0,
               T_base_camera: np.ndarray = T_BASE_CAMERA) -> tuple[RGBDFrame, RGBDFrame, np.ndarray]:
    """Frames before and after the camera moves by ``exp(motion)`` (in its optical frame), and that motion."""
    rng = np.random.default_rng(seed)
    T_motion = se3.exp(motion)
    T_world_base1 = T_WORLD_BASE0 @ T_base_camera @ T_motion @ se3.inverse(T_base_camera)
    return (frame(T_WORLD_BASE0, 0.0, shape, noise_k, rng, T_base_camera),
            frame(T_world_base1, DT_S, shape, noise_k, rng, T_base_camera), T_motion)


SMALL_MOTION = np.array([0.012, -0.006, 0.015, math.radians(0.4), math.radians(-0.6), math.radians(0.5)])
"""A 2 cm, 0.9 deg camera motion between two frames at 30 Hz (0.6 m/s, 27 deg/s)."""


# ---------------------------------------------------------------------------------------------------- motion


@pytest.mark.parametrize("shape", [(240, 320), (120, 160)])
def test_two_frames_recover_a_small_6dof_motion(shape):
    f0, f1, T_motion = two_frames(SMALL_MOTION, shape)
    odo = DIFODO()
    first = odo.process(f0)
    est = odo.process(f1)
    assert np.array_equal(first.T_odom_camera, np.eye(4)) and not first.extra["measured"]
    dist, angle = pose_error(est.T_odom_camera, T_motion)
    assert dist < 5e-3 and angle < 0.3  # measured: 1.1 / 0.6 mm, 0.02 / 0.02 deg (QVGA / QQVGA)
    assert est.extra["measured"] and not est.degenerate
    assert est.valid_points > 0.8 * shape[0] * shape[1]
    np.testing.assert_allclose(est.twist_camera, se3.log(T_motion) / DT_S, atol=0.1)  # m/s, rad/s; measured 0.03
    assert np.all(np.linalg.eigvalsh(est.covariance) > 0) and np.all(np.isfinite(est.covariance))


@pytest.mark.parametrize("shape", [(240, 320), (120, 160)])
def test_depth_noise_growing_with_z_squared_still_converges(shape):
    # Kinect-like noise: sigma = 1.5e-3 z^2, i.e. 6 mm at 2 m and 24 mm at 4 m.
    f0, f1, T_motion = two_frames(SMALL_MOTION, shape, noise_k=1.5e-3, seed=4)
    odo = DIFODO()
    odo.process(f0)
    dist, angle = pose_error(odo.process(f1).T_odom_camera, T_motion)
    assert dist < 5e-3 and angle < 0.3  # measured: 0.8 / 1.7 mm, 0.02 / 0.05 deg (QVGA / QQVGA)


def base_trajectory(n: int) -> list[np.ndarray]:
    """n base poses at 30 Hz: 0.4 m/s forward, swaying and bobbing, yaw rate up to 23 deg/s."""
    poses, T = [], T_WORLD_BASE0
    for i in range(n):
        poses.append(T)
        t = (i + 0.5) * DT_S
        xi = np.array([0.4, 0.05 * math.sin(2 * t), 0.1 * math.cos(3 * t), 0.1 * math.sin(2 * t),
                       0.05 * math.cos(t), 0.4 * math.cos(1.5 * t)])
        T = T @ se3.exp(xi * DT_S)
    return poses


def test_sequence_drift_stays_small():
    poses = base_trajectory(20)
    rng = np.random.default_rng(3)
    odo = DIFODO()
    out = [odo.process(frame(T, i * DT_S, noise_k=1.5e-3, rng=rng)) for i, T in enumerate(poses)]
    length = sum(np.linalg.norm((se3.inverse(a) @ b)[:3, 3]) for a, b in zip(poses, poses[1:]))
    dist, angle = pose_error(out[-1].T_odom_base, se3.inverse(poses[0]) @ poses[-1])
    assert 0.25 < length < 0.27
    assert dist < 0.015 and angle < 0.3  # measured: 7.3 mm (2.8 % of 0.26 m), 0.15 deg
    assert all(est.extra["measured"] and not est.degenerate for est in out[1:])


def test_static_camera_gives_identity():
    f0 = frame(T_WORLD_BASE0, 0.0, (120, 160))
    odo = DIFODO()
    out = [odo.process(RGBDFrame(f0.sensor, i * DT_S, f0.depth_m, None, f0.K, f0.T_base_sensor)) for i in range(3)]
    for est in out:
        np.testing.assert_allclose(est.T_odom_camera, np.eye(4), atol=1e-9)
        np.testing.assert_allclose(est.twist_camera, 0.0, atol=1e-9)
    # With noise the estimate stays within it.
    rng = np.random.default_rng(1)
    odo = DIFODO()
    noisy = [odo.process(frame(T_WORLD_BASE0, i * DT_S, (120, 160), 1.5e-3, rng)) for i in range(5)]
    dist, angle = pose_error(noisy[-1].T_odom_camera, np.eye(4))
    assert dist < 3e-3 and angle < 0.1  # measured: 1.0 mm, 0.02 deg


def test_rotated_mount_gives_the_base_motion():
    # Camera looking left and 20 deg down, rolled 10 deg, off the base centre.
    mount = se3.from_rpy(math.radians(10.0), math.radians(20.0), math.radians(80.0), [0.2, -0.1, 0.9])
    T_base_camera = mount @ se3.from_rotation_translation(R_BODY_OPTICAL)
    T_base_motion = se3.exp(np.array([0.015, 0.004, 0.0, 0.0, 0.0, math.radians(0.8)]))  # planar base motion
    f0, f1, T_camera_motion = two_frames(se3.log(camera_motion(T_base_motion, T_base_camera)), (120, 160),
                                         T_base_camera=T_base_camera)
    odo = DIFODO()
    odo.process(f0)
    est = odo.process(f1)
    np.testing.assert_allclose(T_camera_motion, camera_motion(T_base_motion, T_base_camera), atol=1e-12)
    dist, angle = pose_error(est.T_odom_base, T_base_motion)
    assert dist < 5e-3 and angle < 0.3  # measured: 0.5 mm, 0.02 deg
    np.testing.assert_allclose(est.T_odom_base,
                               T_base_camera @ est.T_odom_camera @ se3.inverse(T_base_camera), atol=1e-12)


# ---------------------------------------------------------------------------------------------- robustness


def test_invalid_frames_keep_the_constant_velocity_prior():
    f0, f1, T_motion = two_frames(SMALL_MOTION, (120, 160))
    f2 = frame(se3.exp(np.array([0.01, 0, 0, 0, 0, 0.01])) @ T_WORLD_BASE0, 2 * DT_S, (120, 160))
    bad = np.full(f2.depth_m.shape, np.nan, dtype=np.float32)
    bad[::2] = np.inf
    bad[1::4] = -1.0
    odo = DIFODO()
    odo.process(f0)
    measured = odo.process(f1)
    for i, depth in enumerate([np.zeros_like(bad), bad]):
        est = odo.process(RGBDFrame("depth", (2 + i) * DT_S, depth, None, f2.K, f2.T_base_sensor))
        assert not est.extra["measured"] and est.degenerate and est.valid_points == 0
        np.testing.assert_allclose(est.twist_camera, measured.twist_camera, atol=1e-9)
        np.testing.assert_allclose(est.covariance, DifodoConfig().lost_variance * np.eye(6))
        assert np.all(np.isfinite(est.T_odom_camera))
    # Two increments predicted with the measured velocity.
    T_expected = measured.T_odom_camera @ se3.exp(measured.twist_camera * 2 * DT_S)
    np.testing.assert_allclose(est.T_odom_camera, T_expected, atol=1e-9)


def test_sparse_frames_with_nan_and_inf_are_aligned_on_their_valid_pixels():
    f0, f1, T_motion = two_frames(SMALL_MOTION, (120, 160))
    rng = np.random.default_rng(0)
    depth = f1.depth_m.copy()
    holes = rng.random(depth.shape) < 0.2
    depth[holes] = rng.choice(np.array([np.nan, np.inf, -np.inf, 0.0], dtype=np.float32), size=holes.sum())
    odo = DIFODO()
    odo.process(f0)
    est = odo.process(RGBDFrame("depth", DT_S, depth, None, f1.K, f1.T_base_sensor))
    dist, angle = pose_error(est.T_odom_camera, T_motion)
    assert est.extra["measured"] and dist < 5e-3 and angle < 0.3  # measured: 0.6 mm, 0.02 deg


def test_a_single_plane_filling_the_view_is_degenerate():
    K = intrinsics(120, 160)
    normal, offset = (0.3, -0.2, -1.0), -2.0  # tilted wall about 2 m ahead
    T_motion = se3.exp(np.array([0.01, 0.0, 0.005, 0.0, 0.01, 0.0]))
    odo = DIFODO()
    for i, T in enumerate([np.eye(4), T_motion]):
        est = odo.process(RGBDFrame("depth", i * DT_S, plane_depth(T, K, (120, 160), normal, offset), None, K,
                                    T_BASE_CAMERA))
    assert est.extra["measured"] and est.degenerate
    assert est.extra["degeneracy_ratio"] < 1e-3  # measured: 1e-5 (the room view of the other tests: 0.02)
    assert np.linalg.eigvalsh(est.covariance)[-1] >= DifodoConfig().lost_variance


def test_unusable_sizes_and_options_raise():
    odo = DIFODO()
    with pytest.raises(ValueError, match=r"\(100, 130\)"):
        odo.process(RGBDFrame("depth", 0.0, np.ones((100, 130), np.float32), None, intrinsics(100, 130), np.eye(4)))
    with pytest.raises(ConfigError, match="allowed"):
        DIFODO(max_levels=3)
    cfg = DifodoConfig(max_rows=120)
    assert DIFODO(cfg, levels=3).config == DifodoConfig(max_rows=120, levels=3)
    # values of the wrong type name the option (as from `--set noise_kz=abc`); ints stand for floats
    with pytest.raises(ConfigError, match="DIFODO option noise_kz: expected float, got 'abc'"):
        DIFODO(noise_kz="abc")
    with pytest.raises(ConfigError, match="DIFODO option hold_degenerate: expected bool, got 1"):
        DIFODO(hold_degenerate=1)
    assert DIFODO(filter_k1=1).config.filter_k1 == 1.0


# ------------------------------------------------------------------------------------------- pyramid, warp


def test_pyramid_plan_follows_the_thesis_levels():
    assert plan_pyramid((240, 320), 240, 15, None).levels == 5  # QVGA down to 15 x 20
    assert plan_pyramid((120, 160), 240, 15, None).levels == 4  # QQVGA
    vga = plan_pyramid((480, 640), 240, 15, None)
    assert (vga.skip, vga.levels) == (1, 5)  # VGA input is processed from QVGA on
    assert plan_pyramid((480, 640), 120, 15, None).skip == 2
    with pytest.raises(ValueError, match=r"\(241, 320\)"):
        plan_pyramid((241, 320), 240, 15, None)
    cams = vga.cameras(intrinsics(480, 640))
    assert (cams[0].height, cams[0].width, cams[-1].height) == (240, 320, 15)
    assert cams[1].fx == pytest.approx(525.0 / 4) and cams[1].cx == pytest.approx(319.5 / 4)


def test_gated_downsample_does_not_mix_across_discontinuities():
    z = np.full((8, 8), 3.0, dtype=np.float32)
    z[:, :3] = 1.0
    z[5, 6] = 0.0  # an invalid neighbour does not count
    z[4, 4] = 0.0
    out = gated_downsample(z, 0.1)
    assert set(np.unique(out)) == {0.0, 1.0, 3.0}
    np.testing.assert_array_equal(out[:, 0], 1.0)
    assert out[2, 2] == 0.0  # centre (4, 4) invalid: stays invalid, its window's depths are not copied into it
    assert out[2, 3] == 3.0  # centre (4, 6) valid, next to the invalid (5, 6)


def test_a_degenerate_estimate_keeps_the_prediction_along_its_weakest_translation():
    # floor (normal y, optical frame) and a wall (normal x): the motion along z changes no depth
    rng = np.random.default_rng(1)
    rows = []
    for normal in ((0.0, -1.0, 0.0), (1.0, 0.0, 0.0)):
        for _ in range(200):
            p = rng.uniform(-2, 2, 3) + np.array([0.0, 0.0, 3.0])
            rows.append(np.r_[normal, np.cross(p, normal)])
    information = sum(np.outer(r, r) for r in rows)
    xi = np.array([0.01, -0.02, 0.05, 0.1, -0.2, 0.3])
    prediction = np.array([0.5, 0.4, 0.6, -1.0, 1.0, 2.0])
    held = hold_weak_translations(xi, prediction, information, 3.0, 0.003)
    np.testing.assert_allclose(held[2], 0.6, atol=1e-9)  # along the corridor: the prediction
    np.testing.assert_allclose(held[[0, 1, 3, 4, 5]], xi[[0, 1, 3, 4, 5]], atol=1e-9)  # the rest as estimated


def test_a_degenerate_estimate_facing_one_wall_keeps_both_translations_along_it():
    # a wall (normal x, optical frame): the slides along y and z and the turn about x change no depth
    rng = np.random.default_rng(2)
    normal = np.array([1.0, 0.0, 0.0])
    rows = [np.r_[normal, np.cross(rng.uniform(-2, 2, 3) + [3.0, 0.0, 0.0], normal)] for _ in range(400)]
    information = sum(np.outer(r, r) for r in rows)
    xi = np.array([0.01, -0.02, 0.05, 0.1, -0.2, 0.3])
    prediction = np.array([0.5, 0.4, 0.6, -1.0, 1.0, 2.0])
    held = hold_weak_translations(xi, prediction, information, 3.0, 0.003)
    np.testing.assert_allclose(held[[1, 2]], prediction[[1, 2]], atol=1e-9)  # along the wall: the prediction
    np.testing.assert_allclose(held[[0, 3, 4, 5]], xi[[0, 3, 4, 5]], atol=1e-9)  # the rest (rotations) as estimated


CORRIDOR = np.array([[-3.0, -1.1, 0.0], [80.0, 1.1, 2.8]])
"""A 2.2 m wide corridor whose far end lies beyond the camera's range (world frame), m."""


def corridor_frame(T_world_base: np.ndarray, stamp_s: float, rng: np.random.Generator) -> RGBDFrame:
    """A QVGA frame of the corridor, Kinect-like noise, depths beyond 4.5 m invalid."""
    K = intrinsics(240, 320)
    depth = box_room_depth(T_world_base @ T_BASE_CAMERA, K, (240, 320), CORRIDOR, np.zeros((0, 2, 3)))[0]
    depth = (depth + 1.4e-3 * depth**2 * rng.standard_normal(depth.shape)).astype(np.float32)
    depth[depth > 4.5] = 0.0
    return RGBDFrame("depth", stamp_s, depth, None, K, T_BASE_CAMERA.copy())


@pytest.mark.parametrize("levels", [True, False])
def test_a_corridor_keeps_the_predicted_translation_along_it_at_the_coarse_levels_too(monkeypatch, levels):
    # the camera sees the floor and one wall 25 deg off the corridor's axis: one unobservable translation
    holds = []
    hold = difodo_module.hold_weak_translations
    monkeypatch.setattr(difodo_module, "hold_weak_translations", lambda *a: holds.append(1) or hold(*a))
    rng = np.random.default_rng(0)
    odo = DIFODO(hold_degenerate_levels=levels)
    counts, twists = [], []
    for k in range(5):
        holds.clear()
        T = se3.from_rpy(0.0, 0.0, math.radians(25.0), [0.0, -0.3, 0.0]) @ se3.from_rpy(0, 0, 0, [0.02 * k, 0, 0])
        estimate = odo.process(corridor_frame(T, k * DT_S, rng))
        counts.append(len(holds))
        twists.append(estimate.twist_camera)
        assert k == 0 or estimate.degenerate
    # the first pair has no prediction (the final hold only); from the second on, with the option, a coarse level
    # (15 x 20 or 30 x 40, as coarse as the 2-degree level of the degeneracy test) holds it too, then the final hold
    assert counts[:2] == [0, 1] and counts[2:] == ([2, 2, 2] if levels else [1, 1, 1])
    np.testing.assert_allclose(twists[2:], twists[1:-1], atol=0.01)  # the prediction kept (0.01 m/s, rad/s)
    # in the furnished room (no weak direction) no level holds anything
    holds.clear()
    odo = DIFODO(hold_degenerate_levels=levels)
    for k in range(3):
        odo.process(frame(T_WORLD_BASE0 @ se3.from_rpy(0, 0, 0, [0.02 * k, 0, 0]), k * DT_S))
    assert not holds


def test_warping_renders_a_plane_exactly():
    K = intrinsics(120, 160)
    cam = LevelCamera.from_K(K, 120, 160)
    normal, offset = (0.2, -0.5, -1.0), -2.5
    T_prev_new = se3.exp(np.array([0.03, -0.02, 0.05, 0.02, -0.03, 0.04]))
    warped = warp_depth(plane_depth(T_prev_new, K, (120, 160), normal, offset), cam, T_prev_new, 6.0)
    truth = plane_depth(np.eye(4), K, (120, 160), normal, offset)
    covered = warped > 0
    assert covered.mean() > 0.9
    np.testing.assert_allclose(warped[covered], truth[covered], rtol=1e-6)  # float32 rounding


def test_warping_keeps_the_closest_surface():
    # 25 cm to the right: the boxes slide over the walls behind them.
    K = intrinsics(120, 160)
    T_prev_new = se3.exp(np.array([0.25, 0.0, 0.0, 0.0, 0.0, 0.0]))
    T_world_camera = T_WORLD_BASE0 @ T_BASE_CAMERA
    warped = warp_depth(render(T_world_camera @ T_prev_new, K, (120, 160)), LevelCamera.from_K(K, 120, 160),
                        T_prev_new, 6.0)
    truth = render(T_world_camera, K, (120, 160))
    covered = warped > 0
    err = warped[covered] - truth[covered]
    assert covered.mean() > 0.85 and np.mean(np.abs(err) < 0.01) > 0.98  # measured: 0.90, 0.99
    # Background where the previous view sees a foreground: only where that surface is hidden in the new view.
    assert np.mean(err > 0.05) < 0.01  # measured: 0.4 % (farthest-wins: 2.1 %)


# ------------------------------------------------------------------------------------------ normal equations


def _centred_squared_reference(f: np.ndarray, ok: np.ndarray, axis: int) -> np.ndarray:
    """``(f(+1) - f(-1))^2`` along ``axis`` with the one-sided rule next to a missing neighbour (numpy)."""
    fp, fn = np.roll(f, 1, axis), np.roll(f, -1, axis)
    has_p, has_n = np.roll(ok, 1, axis), np.roll(ok, -1, axis)
    first = [slice(None)] * 2
    first[axis] = 0
    has_p[tuple(first)] = False
    first[axis] = -1
    has_n[tuple(first)] = False
    diff = np.where(has_p & has_n, fn - fp, np.where(has_n, 2 * (fn - f), np.where(has_p, 2 * (f - fp), 0.0)))
    return diff**2


def test_normal_equations_match_the_weighted_constraints_written_out():
    # The compiled level system against eqs. 3.23, 3.30, 3.32 and 3.33 written with numpy, on a noisy pair.
    before, after, _ = two_frames(SMALL_MOTION, (120, 160), noise_k=1.5e-3)
    z_old, z_new = before.depth_m.copy(), after.depth_m.copy()
    z_new[40:50, 60:90] = 0.0  # a hole
    cfg, dt, xi = DifodoConfig(), DT_S, np.array([0.3, -0.1, 0.4, 0.2, -0.3, 0.25])
    cam = LevelCamera.from_K(before.K, 120, 160)
    system = level_system(z_old, z_new, cam, dt, xi, cfg)
    # Mean depth, temporal difference, edge-aware gradients.
    ok = (z_old > 0) & (z_new > 0)
    z = np.where(ok, 0.5 * (z_old.astype(np.float64) + z_new), 0.0)
    zt = np.where(ok, z_new.astype(np.float64) - z_old, 0.0)
    zu, zv, oku, okv = edge_aware_gradient(z, cam, cfg.discontinuity_px)
    # Linearisation error (3.32 plus the first-order term).
    lin = cfg.linearization_k1 * (zu**2 + zv**2 + zt**2) + cfg.linearization_kl * (
        _centred_squared_reference(zt, ok, 1) + _centred_squared_reference(zt, ok, 0)
        + _centred_squared_reference(zu, oku, 1) + _centred_squared_reference(zv, okv, 0)
        + _centred_squared_reference(zv, okv, 1))
    # Rows of the range-flow constraint and their measurement variance (3.30).
    use = oku & okv
    xn, yn = np.broadcast_to(cam.x_over_z, z.shape)[use], np.broadcast_to(cam.y_over_z[:, None], z.shape)[use]
    d = z[use]
    x, y = xn * d, yn * d
    a, b = cam.fx * zu[use] / d, cam.fy * zv[use] / d
    c = 1.0 + a * xn + b * yn
    A = np.stack([-a, -b, c, c * y + b * d, -(c * x + a * d), a * y - b * x], axis=1)
    p = xi[2] + y * xi[3] - x * xi[4]
    dzu = cam.fx * (xn * p - xi[0] - d * xi[4] + y * xi[5]) / d
    dzv = cam.fy * (yn * p - xi[1] + d * xi[3] - x * xi[5]) / d
    d_ray = p - c * xi[2] + a * xi[0] + b * xi[1]
    sz2 = (cfg.noise_kz * d * d) ** 2
    var = sz2 * (1 / (2 * dt * dt) + 0.125 * (dzu**2 + dzv**2)) + (cfg.noise_kz * d * d_ray) ** 2
    weight = 1.0 / (var + lin[use])
    B = -zt[use] / dt
    H = A.T @ (weight[:, None] * A)
    scale = 1.0 / np.abs(H).max()
    assert system.rows == use.sum() > 10000
    np.testing.assert_allclose(system.H, H * scale, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(system.g, A.T @ (weight * B) * scale, rtol=1e-9, atol=1e-12 * np.abs(system.g).max())
    assert system.bb == pytest.approx(np.sum(weight * B * B) * scale, rel=1e-9)
    assert system.mean_depth_m == pytest.approx(d.mean(), rel=1e-12)
