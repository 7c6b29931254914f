"""Tests of the pinhole camera model and the camera frame constants."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from simnav.geometry import PinholeCamera, se3
from simnav.geometry.camera import R_BODY_OPTICAL, R_MUJOCOCAM_OPTICAL


def _camera() -> PinholeCamera:
    return PinholeCamera.from_fovy(320, 240, 58.0)


def _points_in_view(rng: np.random.Generator, cam: PinholeCamera, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2) pixel coordinates inside the image and (n,) depths in m."""
    uv = np.c_[rng.uniform(-0.5, cam.width - 0.5, n), rng.uniform(-0.5, cam.height - 0.5, n)]
    return uv, rng.uniform(0.1, 20.0, n)


def test_from_fovy_numbers() -> None:
    cam = _camera()
    assert cam.fx == pytest.approx(216.49, abs=5e-3)
    assert cam.fy == cam.fx
    assert (cam.cx, cam.cy) == (159.5, 119.5)
    np.testing.assert_allclose(cam.K, [[cam.fx, 0, 159.5], [0, cam.fy, 119.5], [0, 0, 1]])
    assert cam.vfov_rad == pytest.approx(math.radians(58.0), abs=1e-12)
    assert cam.hfov_rad == pytest.approx(2 * math.atan(160.0 / cam.fx), abs=1e-12)
    assert cam.hfov_rad > cam.vfov_rad


def test_camera_is_frozen_and_validated() -> None:
    cam = _camera()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cam.fx = 1.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        PinholeCamera(0, 10, 1.0, 1.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        PinholeCamera(10, 10, -1.0, 1.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        PinholeCamera.from_fovy(10, 10, 180.0)


def test_project_back_project_round_trip() -> None:
    rng = np.random.default_rng(0)
    cam = PinholeCamera(640, 480, 500.0, 510.0, 320.2, 241.7)
    uv, depth = _points_in_view(rng, cam, 1000)
    P = cam.back_project(uv, depth)
    np.testing.assert_allclose(P[:, 2], depth)
    uv2, valid = cam.project(P)
    assert valid.all()
    np.testing.assert_allclose(uv2, uv, atol=1e-9)
    # and the other way: points -> pixels -> points
    np.testing.assert_allclose(cam.back_project(*cam.project(P)[:1], P[:, 2]), P, atol=1e-9)


def test_project_matches_intrinsic_matrix() -> None:
    rng = np.random.default_rng(0)
    cam = _camera()
    P = np.c_[rng.normal(size=(50, 2)), rng.uniform(0.5, 5.0, 50)]
    h = (cam.K @ P.T).T
    uv, _ = cam.project(P)
    np.testing.assert_allclose(uv, h[:, :2] / h[:, 2:], atol=1e-10)
    # the optical axis hits the principal point
    uv0, valid0 = cam.project([[0.0, 0.0, 3.0]])
    np.testing.assert_allclose(uv0, [[cam.cx, cam.cy]])
    assert valid0[0]


def test_points_behind_or_outside_are_invalid() -> None:
    cam = _camera()
    P = np.array([
        [0.0, 0.0, -1.0],  # behind
        [0.1, 0.1, 0.0],  # in the camera plane
        [0.0, 0.0, 1.0],  # centre: valid
        [10.0, 0.0, 1.0],  # far right
        [0.0, -10.0, 1.0],  # far up
    ])
    uv, valid = cam.project(P)
    np.testing.assert_array_equal(valid, [False, False, True, False, False])
    assert np.isnan(uv[:2]).all() and np.isfinite(uv[2:]).all()


def test_image_bounds_are_half_open() -> None:
    cam = _camera()
    W, H = cam.width, cam.height
    uv = np.array([[-0.5, -0.5], [W - 0.5 - 1e-9, H - 0.5 - 1e-9],
                   [W - 0.5, 0.0], [0.0, H - 0.5], [-0.51, 0.0]])
    P = cam.back_project(uv, np.full(len(uv), 2.0))
    _, valid = cam.project(P)
    np.testing.assert_array_equal(valid, [True, True, False, False, False])


def test_back_project_depth_and_rays() -> None:
    rng = np.random.default_rng(0)
    cam = PinholeCamera.from_fovy(64, 48, 60.0)
    depth = rng.uniform(0.2, 8.0, size=(48, 64))
    depth[rng.random(depth.shape) < 0.2] = 0.0
    P = cam.back_project_depth(depth)
    assert P.shape == (48, 64, 3)
    np.testing.assert_array_equal(P[depth == 0], 0.0)
    np.testing.assert_allclose(P[..., 2], depth)
    vv, uu = np.mgrid[0:48, 0:64]
    uv = np.stack([uu, vv], -1).reshape(-1, 2).astype(float)
    np.testing.assert_allclose(P.reshape(-1, 3), cam.back_project(uv, depth.reshape(-1)), atol=1e-12)
    ok = depth > 0
    uv2, valid = cam.project(P[ok])
    assert valid.all()
    np.testing.assert_allclose(uv2, uv.reshape(48, 64, 2)[ok], atol=1e-9)
    rays = cam.rays_optical()
    np.testing.assert_array_equal(rays[..., 2], 1.0)
    np.testing.assert_allclose(rays[24, 0], [(0 - cam.cx) / cam.fx, (24 - cam.cy) / cam.fy, 1.0])
    with pytest.raises(ValueError):
        cam.back_project_depth(depth.T)


@pytest.mark.parametrize("factor", [0.5, 0.25, 0.125, 2.0])
def test_scaled_camera_is_consistent(factor: float) -> None:
    rng = np.random.default_rng(0)
    cam = _camera()
    small = cam.scaled(factor)
    assert (small.width, small.height) == (cam.width * factor, cam.height * factor)
    assert small.fx == pytest.approx(cam.fx * factor)
    assert small.cx == pytest.approx((cam.cx + 0.5) * factor - 0.5)
    assert small.hfov_rad == pytest.approx(cam.hfov_rad)
    uv, depth = _points_in_view(rng, cam, 500)
    P = cam.back_project(uv, depth)
    uv_small, valid = small.project(P)
    np.testing.assert_allclose(uv_small, (uv + 0.5) * factor - 0.5, atol=1e-9)
    assert valid.all()


def test_scaled_round_trip_and_errors() -> None:
    cam = _camera()
    back = cam.scaled(0.5).scaled(2.0)
    for f in dataclasses.fields(cam):
        assert getattr(back, f.name) == pytest.approx(getattr(cam, f.name))
    with pytest.raises(ValueError):
        cam.scaled(0.0)
    with pytest.raises(ValueError):
        cam.scaled(1e-4)


def test_frame_constants() -> None:
    for R in (R_BODY_OPTICAL, R_MUJOCOCAM_OPTICAL):
        np.testing.assert_allclose(R @ R.T, np.eye(3))
        assert np.linalg.det(R) == pytest.approx(1.0)
    # optical axes expressed in the body frame: z = body x (forward), x = -body y (right), y = -body z (down)
    np.testing.assert_array_equal(R_BODY_OPTICAL[:, 2], [1, 0, 0])
    np.testing.assert_array_equal(R_BODY_OPTICAL[:, 0], [0, -1, 0])
    np.testing.assert_array_equal(R_BODY_OPTICAL[:, 1], [0, 0, -1])
    # a point 2 m ahead and 1 m to the left of the camera body projects left of the principal point
    cam = _camera()
    p_optical = R_BODY_OPTICAL.T @ np.array([2.0, 1.0, 0.0])
    uv, valid = cam.project(p_optical[None])
    assert valid[0] and uv[0, 0] < cam.cx and uv[0, 1] == pytest.approx(cam.cy)
    # a MuJoCo camera looks along its -z axis with y up
    p_optical = R_MUJOCOCAM_OPTICAL.T @ np.array([0.0, 0.5, -2.0])  # ahead and above
    uv, valid = cam.project(p_optical[None])
    assert valid[0] and uv[0, 1] < cam.cy
    T = se3.from_rotation_translation(R_BODY_OPTICAL, [0.1, 0.0, 0.5])
    np.testing.assert_allclose(se3.transform_points(T, [[0.0, 0.0, 1.0]]), [[1.1, 0.0, 0.5]])
    with pytest.raises(ValueError):
        R_BODY_OPTICAL[0, 0] = 1.0
