"""Depth-image pyramid and rigid warping for DIFODO (thesis §3.C, §3.E.6; MRPT ``CDifodo``).

Conventions:

* Depth images are (H, W) float32 z-depth along the optical axis, metres, 0 = invalid (never NaN or inf).
* The optical frame is z forward, x right, y down; pixel ``(u, v)`` (column u, row v) has its centre at integer
  coordinates, so ``u = fx x / z + cx``.
* Pyramids are lists indexed finest first. Each coarser level keeps every second row and column of the finer one:
  coarse pixel ``(u, v)`` sits on fine pixel ``(2u, 2v)``, so its intrinsics are ``fx / 2, fy / 2, cx / 2,
  cy / 2`` exactly.

The pyramid is a bilateral 5 x 5 binomial filter that does not mix depths across discontinuities: a neighbour
contributes ``g (gate - |z - z_centre|)`` when its depth is within ``gate`` of the centre's (CDifodo); an invalid
centre stays invalid. (CDifodo gives it the smallest valid depth of its window: a depth on a ray that saw nothing.
Along the camera's range limit those pixels form a contour that stays put while the camera moves along a floor or a
wall, and pull the estimate towards standing still.) Warping renders a depth image from another viewpoint with a
z-buffer (3.14, the closest surface wins) by rasterising the triangles between neighbouring pixels, which is exact
for planes; CDifodo splats points bilinearly instead, which on steep surfaces (a floor seen at a grazing angle)
shifts the warped depth by a fraction of a pixel times a large gradient and biases the motion by millimetres.

The per-pixel loops (downsampling, rasterisation) are Numba kernels (``@njit(cache=True)``): numpy and OpenCV
cannot rasterise, and the vectorised gated filter took 2.3 ms per QVGA frame against 1.2 ms compiled. Kernels write
into caller-owned arrays (:class:`Workspace`): a fresh large array costs a page fault per 4 KiB on every call (about
2 us each in a virtual machine), which was more than the arithmetic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit

GAUSS5 = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0
"""Binomial 5-tap kernel of the pyramid (its outer product is the 5 x 5 mask)."""
MIN_WARP_DEPTH_M = 1e-3
"""Moved points closer than this to the camera plane (or behind it) are not projected, m."""
SQRT2 = math.sqrt(2.0)


@dataclass(frozen=True)
class LevelCamera:
    """Pinhole intrinsics and size of one pyramid level.

    Attributes:
        height, width: image size, pixels.
        fx, fy: focal lengths, pixels.
        cx, cy: principal point, pixels (0 = centre of the first column / row).
    """

    height: int
    width: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_K(cls, K: np.ndarray, height: int, width: int) -> LevelCamera:
        """The camera of a (height, width) image with intrinsic matrix ``K`` (3, 3)."""
        return cls(height, width, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))

    def half(self) -> LevelCamera:
        """The next coarser level (every second row and column, starting with the first)."""
        return LevelCamera(self.height // 2, self.width // 2, self.fx / 2, self.fy / 2, self.cx / 2, self.cy / 2)

    @cached_property
    def x_over_z(self) -> np.ndarray:
        """(W,) float64 ``(u - cx) / fx`` of every column."""
        return (np.arange(self.width) - self.cx) / self.fx

    @cached_property
    def y_over_z(self) -> np.ndarray:
        """(H,) float64 ``(v - cy) / fy`` of every row."""
        return (np.arange(self.height) - self.cy) / self.fy


class Workspace:
    """Scratch arrays of one image size, reused by the kernels from call to call.

    Attributes:
        real: (4, H, W) float64 scratch images.
        flags: (3, H, W) bool scratch masks.
        depth: (H, W) float32, the output of :func:`warp_depth`.
    """

    def __init__(self, height: int, width: int) -> None:
        self.real = np.empty((4, height, width))
        self.flags = np.empty((3, height, width), dtype=np.bool_)
        self.depth = np.empty((height, width), dtype=np.float32)


@dataclass(frozen=True)
class PyramidPlan:
    """How a frame size is turned into a pyramid.

    Attributes:
        shape: (H, W) of the input frames.
        skip: halvings applied before the finest level used (e.g. 1 for VGA input processed at QVGA).
        levels: levels used by the coarse-to-fine loop, finest first after ``skip``.
    """

    shape: tuple[int, int]
    skip: int
    levels: int

    def cameras(self, K: np.ndarray) -> tuple[LevelCamera, ...]:
        """Intrinsics of the used levels, finest first, for input intrinsics ``K``."""
        cam = LevelCamera.from_K(K, *self.shape)
        for _ in range(self.skip):
            cam = cam.half()
        cams = [cam]
        for _ in range(self.levels - 1):
            cams.append(cams[-1].half())
        return tuple(cams)


def plan_pyramid(shape: tuple[int, int], max_rows: int, coarsest_rows: int, levels: int | None) -> PyramidPlan:
    """Chooses the halvings of a frame size.

    The frame is halved until it has at most ``max_rows`` rows (the finest level used); from there ``levels``
    levels are built or, when ``levels`` is None, the frame keeps being halved while the result has at least
    ``coarsest_rows`` rows (QVGA with 15: 240 -> 15 rows, 5 levels; QQVGA: 4 levels). Every halving needs an even
    height and width.

    Args:
        shape: (H, W) of the frames.
        max_rows: the finest level used has at most this many rows.
        coarsest_rows: the automatic level count stops before going under this many rows.
        levels: explicit number of levels, or None.

    Returns:
        The plan.

    Raises:
        ValueError: the shape cannot be halved as often as needed (the message gives the shape and the divisor).
    """
    h, w = (int(n) for n in shape)
    if h < 4 or w < 4:
        raise ValueError(f"DIFODO needs depth images of at least 4 x 4 pixels, got shape {tuple(shape)}")
    skip = 0
    while h >> skip > max_rows:
        skip += 1
    if levels is None:
        levels = 1
        while (h >> (skip + levels - 1)) // 2 >= coarsest_rows:
            levels += 1
    divisor = 1 << (skip + levels - 1)
    if h % divisor or w % divisor:
        raise ValueError(f"DIFODO cannot use depth images of shape {tuple(shape)}: {skip} halving(s) down to at "
                         f"most {max_rows} rows and {levels} pyramid level(s) need height and width divisible by "
                         f"{divisor} (change max_rows, levels or coarsest_rows, or crop the images)")
    return PyramidPlan((h, w), skip, levels)


def sanitize_depth(depth_m: np.ndarray) -> np.ndarray:
    """(H, W) float32 copy of a depth image with NaN, inf, negative and zero depths set to 0 (invalid)."""
    z = np.asarray(depth_m, dtype=np.float32)
    return np.where(np.isfinite(z) & (z > 0), z, np.float32(0.0))


def gated_downsample(depth_m: np.ndarray, gate_m: float) -> np.ndarray:
    """Halves a depth image with the gated (bilateral) 5 x 5 binomial filter of CDifodo.

    Output pixel ``(u, v)`` is centred on input pixel ``(2u, 2v)``. Each valid neighbour in the 5 x 5 window
    (pixels outside the image do not count) is weighted by ``g_k (gate - |z_k - z_centre|)`` when positive, so
    depths across a discontinuity are never mixed. An invalid centre stays invalid.

    Args:
        depth_m: (H, W) float32 depth, 0 = invalid; H and W even.
        gate_m: depth-similarity gate, m.

    Returns:
        (H/2, W/2) float32 depth, 0 = invalid.
    """
    z = np.ascontiguousarray(depth_m, dtype=np.float32)
    out = np.empty((z.shape[0] // 2, z.shape[1] // 2), dtype=np.float32)
    _downsample_kernel(z, float(gate_m), out)
    return out


@njit(cache=True, error_model="numpy")
def _downsample_kernel(z: np.ndarray, gate: float, out: np.ndarray) -> None:
    """Compiled :func:`gated_downsample`: writes the halved image into ``out``. Inside the image the window has
    fixed bounds and invalid or gated-out neighbours weigh 0 by a select (no branches: 0.6x the time); windows
    over the border skip what lies outside."""
    h, w = z.shape
    for v in range(out.shape[0]):
        inner_v = 2 <= 2 * v < h - 2
        for u in range(out.shape[1]):
            centre = z[2 * v, 2 * u]
            num = den = 0.0
            if centre <= 0:
                pass  # stays invalid
            elif inner_v and 2 <= 2 * u < w - 2:
                for i in range(5):
                    for j in range(5):
                        d = z[2 * v + i - 2, 2 * u + j - 2]
                        weight = GAUSS5[i] * GAUSS5[j] * (gate - abs(d - centre))
                        weight = weight if (weight > 0) & (d > 0) else 0.0
                        num, den = num + weight * d, den + weight
            else:
                for y in range(max(2 * v - 2, 0), min(2 * v + 3, h)):
                    for x in range(max(2 * u - 2, 0), min(2 * u + 3, w)):
                        d = z[y, x]
                        weight = GAUSS5[y - 2 * v + 2] * GAUSS5[x - 2 * u + 2] * (gate - abs(d - centre))
                        if weight > 0 and d > 0:
                            num, den = num + weight * d, den + weight
            out[v, u] = num / den if den > 0 else 0.0  # (the centre itself weighs > 0 when valid)


def build_pyramid(depth_m: np.ndarray, plan: PyramidPlan, gate_m: float) -> list[np.ndarray]:
    """Depth pyramid of one frame, finest used level first (the input itself is not smoothed).

    Args:
        depth_m: (H, W) float32 sanitized depth (:func:`sanitize_depth`) of shape ``plan.shape``.
        plan: from :func:`plan_pyramid`.
        gate_m: depth-similarity gate of :func:`gated_downsample`, m.

    Returns:
        ``plan.levels`` float32 depth images, finest first.
    """
    z = depth_m
    for _ in range(plan.skip):
        z = gated_downsample(z, gate_m)
    levels = [z]
    for _ in range(plan.levels - 1):
        levels.append(gated_downsample(levels[-1], gate_m))
    return levels


def warp_depth(depth_m: np.ndarray, cam: LevelCamera, T_dst_src: np.ndarray, max_step_px: float,
               work: Workspace | None = None) -> np.ndarray:
    """Renders a depth image from another viewpoint with a z-buffer (3.14, the closest surface wins).

    The valid pixels of the source image are moved into the target camera frame and projected; every 2 x 2 block
    of them is split into two triangles (along the diagonal with the smaller depth difference), and each triangle
    whose corners lie on one surface is rasterised onto the target pixels it covers, interpolating the inverse
    depth linearly in the image (exact for planes). Two pixels ``k`` apart lie on one surface when their depths
    differ by at most ``max_step_px * k`` pixel footprints ``z / f`` (a surface seen at more than
    ``atan(max_step_px)`` from its normal counts as a discontinuity). Points in no triangle fall into the nearest
    pixel. Each target pixel keeps the closest depth it receives.

    Args:
        depth_m: (H, W) float32 source depth, 0 = invalid.
        cam: intrinsics of both images (same level).
        T_dst_src: (4, 4) pose of the source camera in the target camera frame.
        max_step_px: depth continuity limit between neighbouring pixels, in pixel footprints.
        work: scratch arrays of this size; the result is written into ``work.depth`` (None = fresh arrays).

    Returns:
        (H, W) float32 depth seen from the target camera, 0 where nothing projects.
    """
    work = Workspace(*depth_m.shape) if work is None else work
    step = max_step_px / math.sqrt(cam.fx * cam.fy)
    _warp_kernel(np.ascontiguousarray(depth_m, dtype=np.float32), cam.x_over_z, cam.y_over_z,
                 np.ascontiguousarray(T_dst_src, dtype=np.float64), cam.fx, cam.fy, cam.cx, cam.cy, step, work.real,
                 work.flags[0], work.depth)
    return work.depth


@njit(cache=True, error_model="numpy", fastmath={"contract", "arcp", "reassoc", "nsz"})
def _warp_kernel(z: np.ndarray, xn: np.ndarray, yn: np.ndarray, T: np.ndarray, fx: float, fy: float, cx: float,
                 cy: float, step: float, real: np.ndarray, drawn: np.ndarray, out: np.ndarray) -> None:
    """Compiled :func:`warp_depth`; ``step`` is the continuity limit as a fraction of depth per pixel, ``real``
    and ``drawn`` are scratch, the result goes into ``out``."""
    h, w = z.shape
    pu, pv, inv, best = real[0], real[1], real[2], real[3]
    # 1. Move and project every valid point: target pixel coordinates and inverse depth (0 = not projected).
    for v in range(h):
        for u in range(w):
            inv[v, u] = best[v, u] = 0.0
            drawn[v, u] = False
            d = z[v, u]
            if d <= 0:
                continue
            x, y = xn[u] * d, yn[v] * d
            zt = T[2, 0] * x + T[2, 1] * y + T[2, 2] * d + T[2, 3]
            if zt <= MIN_WARP_DEPTH_M:
                continue
            inv[v, u] = 1.0 / zt
            pu[v, u] = fx * (T[0, 0] * x + T[0, 1] * y + T[0, 2] * d + T[0, 3]) * inv[v, u] + cx
            pv[v, u] = fy * (T[1, 0] * x + T[1, 1] * y + T[1, 2] * d + T[1, 3]) * inv[v, u] + cy
    # 2. Rasterise the two triangles of every 2 x 2 block whose corners lie on one surface.
    for v in range(h - 1):
        for u in range(w - 1):
            # Block a b / c d, split along the diagonal with the smaller depth difference into the triangles
            # p q r and r s p (p-r the diagonal; a b d and d c a, or b a c and c d b).
            if abs(z[v, u] - z[v + 1, u + 1]) <= abs(z[v, u + 1] - z[v + 1, u]):
                vp, up, vq, uq, vr, ur, vs, us = v, u, v, u + 1, v + 1, u + 1, v + 1, u
            else:
                vp, up, vq, uq, vr, ur, vs, us = v, u + 1, v, u, v + 1, u, v + 1, u + 1
            ip, iq, ir, i_s = inv[vp, up], inv[vq, uq], inv[vr, ur], inv[vs, us]
            zp, zq, zr, zs = z[vp, up], z[vq, uq], z[vr, ur], z[vs, us]
            if not (ip > 0 and ir > 0 and _same_surface(zp, zr, SQRT2, step)):
                continue
            first = iq > 0 and _same_surface(zp, zq, 1.0, step) and _same_surface(zq, zr, 1.0, step)
            second = i_s > 0 and _same_surface(zr, zs, 1.0, step) and _same_surface(zs, zp, 1.0, step)
            if first:
                drawn[vp, up] = drawn[vq, uq] = drawn[vr, ur] = True
                _rasterise(pu[vp, up], pv[vp, up], ip, pu[vq, uq], pv[vq, uq], iq, pu[vr, ur], pv[vr, ur], ir, best)
            if second:
                drawn[vr, ur] = drawn[vs, us] = drawn[vp, up] = True
                _rasterise(pu[vr, ur], pv[vr, ur], ir, pu[vs, us], pv[vs, us], i_s, pu[vp, up], pv[vp, up], ip, best)
    # 3. Points in no triangle fall into their nearest pixel.
    for v in range(h):
        for u in range(w):
            if inv[v, u] > 0 and not drawn[v, u]:
                ku, kv = int(math.floor(pu[v, u] + 0.5)), int(math.floor(pv[v, u] + 0.5))
                if 0 <= ku < w and 0 <= kv < h and inv[v, u] > best[kv, ku]:
                    best[kv, ku] = inv[v, u]
    for v in range(h):
        for u in range(w):
            out[v, u] = 1.0 / best[v, u] if best[v, u] > 0 else 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _same_surface(z0: float, z1: float, pixels: float, step: float) -> bool:
    """Whether two depths ``pixels`` apart lie on one surface (see :func:`warp_depth`)."""
    return abs(z1 - z0) <= step * pixels * min(z0, z1)


@njit(cache=True, error_model="numpy", fastmath={"contract", "arcp", "reassoc", "nsz"}, inline="always")
def _rasterise(au: float, av: float, ai: float, bu: float, bv: float, bi: float, cu: float, cv: float, ci: float,
               best: np.ndarray) -> None:
    """Rasterises the triangle of projected corners ``(u, v, inverse depth)`` a, b, c into ``best`` (largest
    inverse depth per target pixel), interpolating the inverse depth linearly. Called once per triangle, not
    inlined: with one array argument its reference counting is cheap against the rasterisation."""
    area = (bu - au) * (cv - av) - (cu - au) * (bv - av)
    if abs(area) < 1e-12:
        return
    h, w = best.shape
    k0, k1 = max(math.ceil(min(au, bu, cu) - 1e-9), 0), min(math.floor(max(au, bu, cu) + 1e-9), w - 1)
    m0, m1 = max(math.ceil(min(av, bv, cv) - 1e-9), 0), min(math.floor(max(av, bv, cv) + 1e-9), h - 1)
    sign = 1.0 if area > 0 else -1.0
    tol = -1e-9 * abs(area)
    for m in range(m0, m1 + 1):
        for k in range(k0, k1 + 1):
            # Barycentric weights times the signed area; inside when all three have its sign.
            wa = sign * ((bu - k) * (cv - m) - (cu - k) * (bv - m))
            wb = sign * ((cu - k) * (av - m) - (au - k) * (cv - m))
            wc = abs(area) - wa - wb
            if wa >= tol and wb >= tol and wc >= tol:
                i = (wa * ai + wb * bi + wc * ci) / abs(area)
                if i > best[m, k]:
                    best[m, k] = i
