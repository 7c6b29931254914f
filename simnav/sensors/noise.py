"""Noise models turning ideal readings into realistic ones. Pure numpy; invalid values become 0, never NaN."""

from __future__ import annotations

import numpy as np


def lidar_noise(
    ranges_m: np.ndarray, rng: np.random.Generator, noise_std_m: float, dropout_prob: float,
    min_range_m: float, max_range_m: float,
) -> np.ndarray:
    """Gaussian range noise, random dropouts, and out-of-range returns marked invalid (0).

    Args:
        ranges_m: (N,) ideal ranges, 0 where the beam hit nothing within range.
    Returns:
        (N,) float32 noisy ranges, 0 = invalid.
    """
    valid = ranges_m > 0
    noisy = ranges_m + rng.normal(0.0, noise_std_m, ranges_m.shape) if noise_std_m > 0 else ranges_m.copy()
    if dropout_prob > 0:
        valid &= rng.random(ranges_m.shape) >= dropout_prob
    valid &= (noisy >= min_range_m) & (noisy <= max_range_m) & np.isfinite(noisy)
    return np.where(valid, noisy, 0.0).astype(np.float32)


def depth_noise(
    depth_m: np.ndarray, rng: np.random.Generator, k_per_m: float, quantum_m: float, dropout_prob: float,
) -> np.ndarray:
    """Kinect-like depth noise on a (H, W) z-depth image (0 = invalid stays 0).

    Axial noise grows with the square of depth, sigma_z = k z^2 (Khoshelham & Elberink 2012); the depth is then
    quantised in disparity, i.e. with a step ``quantum_m * z^2`` (1 mm at 1 m for the default); random pixels drop
    out.
    """
    valid = depth_m > 0
    z = depth_m.astype(np.float64)
    if k_per_m > 0:
        z = z + rng.normal(0.0, 1.0, z.shape) * k_per_m * z * z
    if quantum_m > 0:
        step = quantum_m * np.maximum(z * z, 1e-6)
        z = np.round(z / step) * step
    if dropout_prob > 0:
        valid &= rng.random(z.shape) >= dropout_prob
    valid &= np.isfinite(z) & (z > 0)
    return np.where(valid, z, 0.0).astype(np.float32)


def grazing_mask(points_optical: np.ndarray, max_angle_rad: float) -> np.ndarray:
    """(H, W) bool: pixels whose surface is seen at more than ``max_angle_rad`` from its normal.

    Normals come from the cross product of horizontal and vertical neighbour differences of the back-projected
    (H, W, 3) points; pixels on depth discontinuities get arbitrary normals and are dropped too, as real
    structured-light and ToF cameras do at object edges.
    """
    p = points_optical.astype(np.float32, copy=False)
    du = np.zeros_like(p)
    dv = np.zeros_like(p)
    du[:, 1:-1] = p[:, 2:] - p[:, :-2]
    dv[1:-1, :] = p[2:, :] - p[:-2, :]
    normal = np.cross(du, dv)
    n2 = np.einsum("hwc,hwc->hw", normal, normal)
    p2 = np.einsum("hwc,hwc->hw", p, p)
    dot = np.einsum("hwc,hwc->hw", normal, p)
    # |cos| < cos(max) <=> dot^2 < cos(max)^2 |n|^2 |p|^2 (no square roots)
    grazing = dot * dot < np.float32(np.cos(max_angle_rad) ** 2) * n2 * p2
    grazing[n2 == 0] = False  # image border or flat neighbourhood: no normal to judge
    return grazing
