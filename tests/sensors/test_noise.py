"""Depth noise and the grazing-angle mask: the compiled passes compute, bit for bit, the float32 formulas their
docstrings state (written here with numpy), on images with holes, edges and far pixels."""

from __future__ import annotations

import numpy as np
import pytest

from simnav.geometry.camera import PinholeCamera
from simnav.sensors.noise import depth_noise, grazing_mask


def depth_image(seed: int, h: int = 120, w: int = 160) -> np.ndarray:
    """A wall with a box in front of it, a floor, and holes (0) - z-depth in metres, float32."""
    rng = np.random.default_rng(seed)
    z = np.full((h, w), 3.0, dtype=np.float32) + rng.normal(0, 0.01, (h, w)).astype(np.float32)
    z[h // 3: h // 2, w // 4: w // 2] = 1.2
    rows = np.arange(h // 2, h, dtype=np.float32)[:, None]
    z[h // 2:] = np.minimum(z[h // 2:], 40.0 / (rows - h / 2 + 1))
    z[rng.random((h, w)) < 0.05] = 0
    return z


def numpy_noise(z, rng, k, quantum, dropout):
    z = z.astype(np.float32)
    valid = z > 0
    z2 = z * z
    if k > 0:
        z += rng.standard_normal(z.shape, dtype=np.float32) * np.float32(k) * z2
    if quantum > 0:
        step = np.maximum(np.float32(quantum) * z2, np.float32(1e-9))
        z = np.round(z / step) * step
    if dropout > 0:
        valid &= rng.random(z.shape, dtype=np.float32) >= dropout
    valid &= np.isfinite(z) & (z > 0)
    z[~valid] = 0
    return z


def numpy_grazing(z, K, max_angle_rad):
    f, cx, cy = float(K[0, 0]), float(K[0, 2]), float(K[1, 2])
    h, w = z.shape
    z_u, z_v = np.zeros_like(z), np.zeros_like(z)
    z_u[:, 1:-1] = (z[:, 2:] - z[:, :-2]) * 0.5
    z_v[1:-1, :] = (z[2:, :] - z[:-2, :]) * 0.5
    x = ((np.arange(w, dtype=np.float32) - cx) / f)[None, :]
    y = ((np.arange(h, dtype=np.float32) - cy) / f)[:, None]
    n_z = x * z_u + y * z_v + z / f
    n2 = z_u * z_u + z_v * z_v + n_z * n_z
    grazing = (z / f) ** 2 < np.float32(np.cos(max_angle_rad) ** 2) * (1 + x * x + y * y) * n2
    grazing[:, [0, -1]] = False
    grazing[[0, -1], :] = False
    return grazing


@pytest.mark.parametrize(("k", "quantum", "dropout"), [(0.001425, 0.001, 0.0), (0.003, 0.0, 0.05), (0.0, 0.002, 0.0),
                                                       (0.0, 0.0, 0.0)])
def test_depth_noise_is_the_float32_formula(k, quantum, dropout):
    for seed in range(3):
        z = depth_image(seed)
        out = depth_noise(z, np.random.default_rng(seed), k, quantum, dropout)
        expected = numpy_noise(z, np.random.default_rng(seed), k, quantum, dropout)
        assert out.dtype == np.float32 and out.shape == z.shape
        np.testing.assert_array_equal(out, expected)
        assert (out[z == 0] == 0).all()


def test_depth_noise_keeps_non_finite_input_out():
    z = depth_image(0)
    z[5, 5], z[6, 6] = np.nan, np.inf
    out = depth_noise(z, np.random.default_rng(0), 0.001425, 0.001, 0.0)
    assert np.isfinite(out).all() and out[5, 5] == 0 and out[6, 6] == 0


@pytest.mark.parametrize("angle_deg", [60.0, 75.0, 80.0])
def test_grazing_mask_is_the_float32_formula(angle_deg):
    K = PinholeCamera.from_fovy(160, 120, 45.6).K
    for seed in range(3):
        z = depth_image(seed)
        mask = grazing_mask(z, K, np.radians(angle_deg))
        np.testing.assert_array_equal(mask, numpy_grazing(z, K, np.radians(angle_deg)))
    assert mask[1:-1, 1:-1].any() and not mask[1:-1, 1:-1].all()
