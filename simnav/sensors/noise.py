"""Noise models turning ideal readings into realistic ones (numpy draws; Numba for the lidar's per-beam pass);
invalid values become 0, never NaN."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_NONE = np.zeros(0)  # no draws (no noise, no dropouts)
_NONE_F32 = np.zeros((0, 0), dtype=np.float32)  # the same for an image


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
    flat = type(ranges_m) is np.ndarray and ranges_m.ndim == 1 and ranges_m.dtype == np.float64 and \
        ranges_m.flags.c_contiguous
    ranges = ranges_m if flat else np.ascontiguousarray(ranges_m, dtype=np.float64).reshape(-1)
    # rng.normal(0, std) is 0 + std·z of these draws of z: the same stream, scaled in the pass below
    n = ranges.shape[0]
    normals = rng.standard_normal(n) if noise_std_m > 0 else _NONE
    uniforms = rng.random(n) if dropout_prob > 0 else _NONE
    out = _noisy_ranges(ranges, normals, noise_std_m, uniforms, dropout_prob, min_range_m, max_range_m)
    return out if flat else out.reshape(np.shape(ranges_m))


@njit(cache=True, error_model="numpy")
def _noisy_ranges(ranges_m: np.ndarray, normals: np.ndarray, noise_std_m: float, uniforms: np.ndarray,
                  dropout_prob: float, min_range_m: float, max_range_m: float) -> np.ndarray:
    """(N,) float32 ``ranges_m + noise_std_m · normals`` where the ideal range is valid (> 0), the beam not dropped
    (its uniform draw >= ``dropout_prob``) and the noisy range finite within [min, max]; 0 elsewhere. Empty
    ``normals`` or ``uniforms``: no noise, no dropouts."""
    out = np.empty(ranges_m.shape[0], dtype=np.float32)
    for i in range(ranges_m.shape[0]):
        noisy = ranges_m[i] + noise_std_m * normals[i] if normals.shape[0] else ranges_m[i]
        valid = ranges_m[i] > 0 and (uniforms.shape[0] == 0 or uniforms[i] >= dropout_prob)
        valid = valid and noisy >= min_range_m and noisy <= max_range_m and math.isfinite(noisy)
        out[i] = noisy if valid else 0.0
    return out


def depth_noise(
    depth_m: np.ndarray, rng: np.random.Generator, k_per_m: float, quantum_m: float, dropout_prob: float,
) -> np.ndarray:
    """Kinect-like depth noise on a (H, W) z-depth image (0 = invalid stays 0).

    Axial noise grows with the square of depth, sigma_z = k z^2 (Khoshelham & Elberink 2012); the depth is then
    quantised in disparity, i.e. with a step ``quantum_m * z^2`` (1 mm at 1 m for the default); random pixels drop
    out. Returns a new (H, W) float32 image.
    """
    z = np.ascontiguousarray(depth_m, dtype=np.float32)
    # the draws: a standard normal per pixel for the noise, then a uniform per pixel for the dropouts
    normals = rng.standard_normal(z.shape, dtype=np.float32) if k_per_m > 0 else _NONE_F32
    uniforms = rng.random(z.shape, dtype=np.float32) if dropout_prob > 0 else _NONE_F32
    return _noisy_depth(z, normals, np.float32(k_per_m), np.float32(quantum_m), uniforms, np.float32(dropout_prob))


@njit(cache=True, error_model="numpy")
def _noisy_depth(z: np.ndarray, normals: np.ndarray, k: np.float32, quantum: np.float32, uniforms: np.ndarray,
                 dropout: np.float32) -> np.ndarray:
    """(H, W) float32 ``z + k z^2 normals``, rounded to the nearest multiple of ``quantum z^2``, 0 where ``z`` is 0,
    the pixel dropped (its uniform draw < ``dropout``) or the result not finite and positive; every operation in
    float32. Empty ``normals`` or ``uniforms``: no noise, no dropouts; ``quantum`` 0: no rounding."""
    h, w = z.shape
    out = np.empty((h, w), dtype=np.float32)
    tiny = np.float32(1e-9)
    for i in range(h):
        for j in range(w):
            v = z[i, j]
            valid = v > 0
            v2 = v * v
            if normals.shape[0]:
                v = v + normals[i, j] * k * v2
            if quantum > 0:
                step = max(quantum * v2, tiny)
                v = np.float32(np.rint(v / step)) * step
            if uniforms.shape[0]:
                valid = valid and uniforms[i, j] >= dropout
            valid = valid and np.isfinite(v) and v > 0
            out[i, j] = v if valid else np.float32(0)
    return out


def grazing_mask(depth_m: np.ndarray, K: np.ndarray, max_angle_rad: float) -> np.ndarray:
    """(H, W) bool: pixels whose surface is seen at more than ``max_angle_rad`` from its normal.

    With P = z (x, y, 1), x = (u - cx)/f, y = (v - cy)/f, the surface normal is proportional to
    (-z_u, -z_v, x z_u + y z_v + z/f) and n.P = z^2/f, so the angle follows from the depth gradient alone:
    cos^2 = (z/f)^2 / ((1 + x^2 + y^2) |n|^2). Pixels on depth discontinuities get a huge gradient and are
    dropped too, as real structured-light and ToF cameras do at object edges. Border pixels are kept.

    Args:
        depth_m: (H, W) z-depth, m (0 = invalid).
        K: (3, 3) intrinsics with fx = fy = f.
    """
    z = np.ascontiguousarray(depth_m, dtype=np.float32)
    f, cx, cy = (np.float32(v) for v in (K[0, 0], K[0, 2], K[1, 2]))
    return _grazing(z, f, cx, cy, np.float32(np.cos(max_angle_rad) ** 2))


@njit(cache=True, error_model="numpy")
def _grazing(z: np.ndarray, f: np.float32, cx: np.float32, cy: np.float32, cos2: np.float32) -> np.ndarray:
    """:func:`grazing_mask` of a contiguous float32 image, in float32 with central differences."""
    h, w = z.shape
    out = np.zeros((h, w), dtype=np.bool_)
    half, one = np.float32(0.5), np.float32(1)
    for i in range(1, h - 1):
        y = (np.float32(i) - cy) / f
        for j in range(1, w - 1):
            x = (np.float32(j) - cx) / f
            z_u = (z[i, j + 1] - z[i, j - 1]) * half
            z_v = (z[i + 1, j] - z[i - 1, j]) * half
            zf = z[i, j] / f
            n_z = x * z_u + y * z_v + zf
            n2 = z_u * z_u + z_v * z_v + n_z * n_z
            out[i, j] = zf * zf < cos2 * (one + x * x + y * y) * n2
    return out
