"""Rays in a horizontal plane against MuJoCo primitives, cast on the primitives' cross-sections (Numba).

A planar lidar on a ground robot scans a horizontal plane. There, an upright box is a rectangle, an upright
cylinder or capsule and any sphere are circles, a lying cylinder is a rectangle, a lying capsule a stadium, and a
horizontal plane is never hit; a ray meets the solid exactly where it meets that 2D section. Casting against the
sections gives what ``mj_multiRay`` returns (the first non-negative hit distance along each ray, the exit point
for a ray that starts inside a geom) at a fraction of the cost: each section is tested only against the rays
inside its angular extent, found through a table of azimuth bins. The kernel reports when a case falls outside
this model (a ray leaves the plane, a slanted geom or plane reaches the scan plane, the origin lies inside a lying
capsule, a geom type other than plane, sphere, capsule, cylinder or box); the caller then casts with MuJoCo.

Conventions: world frame, metres; geom poses as MuJoCo stores them (``geom_xpos`` (G, 3), ``geom_xmat`` (G, 9)
row-major, ``geom_size`` (G, 3), bounding radius ``geom_rbound`` (G,)); geom type codes are MuJoCo's ``mjtGeom``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

PLANE, SPHERE, CAPSULE, CYLINDER, BOX = 0, 2, 3, 5, 6  # mjtGeom codes this module models
SUPPORTED_TYPES = frozenset({PLANE, SPHERE, CAPSULE, CYLINDER, BOX})
AZIMUTH_BINS = 1024
VERTICAL_TOL = 1e-9  # |z| of a unit vector still treated as horizontal (or 1 - |z| as vertical)
_TWO_PI = 2.0 * math.pi


@njit(cache=True)
def cast_planar(origin: np.ndarray, dirs: np.ndarray, azimuth_rad: np.ndarray, geom_ids: np.ndarray,
                geom_type: np.ndarray, geom_size: np.ndarray, geom_rbound: np.ndarray, geom_xpos: np.ndarray,
                geom_xmat: np.ndarray, max_dist_m: float, dist_out: np.ndarray, geom_out: np.ndarray) -> bool:
    """Cast horizontal rays from ``origin`` against the cross-sections of the geoms ``geom_ids``.

    Args:
        origin: (3,) ray origin, world frame, m.
        dirs: (N, 3) unit ray directions, world frame (all with z = 0 within ``VERTICAL_TOL``).
        azimuth_rad: (N,) their azimuths, world frame, rad, to within a few ulp (only to find candidates).
        geom_ids: (K,) geoms to test (indices into the per-geom arrays).
        geom_type, geom_size, geom_rbound, geom_xpos, geom_xmat: per-geom MuJoCo arrays (G,), (G, 3), (G,),
            (G, 3), (G, 9).
        max_dist_m: geoms whose section lies entirely farther than this are skipped, m.
        dist_out: (N,) written: first hit distance along each ray, m, or -1 where nothing is hit.
        geom_out: (N,) written: id of the geom hit, or -1.

    Returns:
        False when the rays or a geom leave the planar model (outputs then undefined), else True.
    """
    n = dirs.shape[0]
    for i in range(n):
        if abs(dirs[i, 2]) > VERTICAL_TOL:
            return False
        dist_out[i] = -1.0
        geom_out[i] = -1
    start, order = _bin_rays(azimuth_rad)
    ox, oy, oz = origin[0], origin[1], origin[2]
    for g in geom_ids:
        t, pos, mat, size = geom_type[g], geom_xpos[g], geom_xmat[g], geom_size[g]
        dz = abs(oz - pos[2])
        if t == PLANE:
            if abs(mat[8]) < 1.0 - VERTICAL_TOL:
                return False
        elif dz > geom_rbound[g]:
            continue  # entirely above or below the scan plane
        elif t == BOX:
            up = _vertical_axis(mat)
            if up < 0:
                return False
            if dz <= size[up]:
                a, b = (up + 1) % 3, (up + 2) % 3
                _cast_rect(ox, oy, pos[0], pos[1], mat[a], mat[3 + a], mat[b], mat[3 + b], size[a], size[b], g,
                           dirs, start, order, max_dist_m, dist_out, geom_out)
        elif t == SPHERE or abs(mat[8]) >= 1.0 - VERTICAL_TOL:
            r = _section_radius(t, size, dz)
            if r < 0.0:
                return False
            if r > 0.0:
                _cast_circle(ox, oy, pos[0], pos[1], r, g, dirs, start, order, max_dist_m, dist_out, geom_out)
        elif abs(mat[8]) <= VERTICAL_TOL:
            if not _cast_lying(ox, oy, t, pos, mat, size, dz, g, dirs, start, order, max_dist_m, dist_out, geom_out):
                return False
        else:
            return False
    return True


@njit(cache=True)
def _cast_lying(ox: float, oy: float, geom_type: int, pos: np.ndarray, mat: np.ndarray, size: np.ndarray, dz: float,
                g: int, dirs: np.ndarray, start: np.ndarray, order: np.ndarray, max_dist_m: float,
                dist_out: np.ndarray, geom_out: np.ndarray) -> bool:
    """A cylinder or capsule whose axis is horizontal: a rectangle, plus end circles for the capsule's stadium.

    Returns False for another type, or for an origin inside the stadium (a union's exit is not its pieces').
    """
    r, half = size[0], size[1]
    if dz >= r:
        return True
    w = math.sqrt(r * r - dz * dz)  # half-width of the section
    ux, uy = mat[2], mat[5]  # the axis, horizontal
    norm = math.sqrt(ux * ux + uy * uy)
    ux, uy = ux / norm, uy / norm
    if geom_type == CYLINDER:
        _cast_rect(ox, oy, pos[0], pos[1], ux, uy, -uy, ux, half, w, g, dirs, start, order, max_dist_m, dist_out,
                   geom_out)
        return True
    if geom_type != CAPSULE:
        return False
    pu, pv = (ox - pos[0]) * ux + (oy - pos[1]) * uy, -(ox - pos[0]) * uy + (oy - pos[1]) * ux
    gap_u = max(abs(pu) - half, 0.0)
    if gap_u * gap_u + pv * pv <= w * w:
        return False
    _cast_rect(ox, oy, pos[0], pos[1], ux, uy, -uy, ux, half, w, g, dirs, start, order, max_dist_m, dist_out,
               geom_out)
    for end in (-half, half):
        _cast_circle(ox, oy, pos[0] + end * ux, pos[1] + end * uy, w, g, dirs, start, order, max_dist_m, dist_out,
                     geom_out)
    return True


@njit(cache=True)
def _vertical_axis(mat: np.ndarray) -> int:
    """Index of the geom axis (column of the row-major ``mat``) along world z, or -1 if none is."""
    for k in range(3):
        if abs(mat[6 + k]) >= 1.0 - VERTICAL_TOL:
            return k
    return -1


@njit(cache=True)
def _section_radius(geom_type: int, size: np.ndarray, dz: float) -> float:
    """Radius of an upright round geom's section ``dz`` from its centre (0: the plane misses it; -1: unknown type)."""
    if geom_type == SPHERE:
        r = size[0]
        return math.sqrt(r * r - dz * dz) if dz < r else 0.0
    if geom_type == CYLINDER:
        return size[0] if dz <= size[1] else 0.0
    if geom_type == CAPSULE:
        r, cap = size[0], dz - size[1]
        if cap <= 0.0:
            return r
        return math.sqrt(r * r - cap * cap) if cap < r else 0.0
    return -1.0


@njit(cache=True)
def _bin_rays(azimuth_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays sorted by azimuth bin: ``order[start[b]:start[b + 1]]`` are the rays of bin ``b``."""
    n = azimuth_rad.shape[0]
    bins = np.empty(n, dtype=np.int64)
    start = np.zeros(AZIMUTH_BINS + 1, dtype=np.int64)
    for i in range(n):
        b = _azimuth_bin(azimuth_rad[i])
        bins[i] = b
        start[b + 1] += 1
    for b in range(AZIMUTH_BINS):
        start[b + 1] += start[b]
    fill = start[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        order[fill[bins[i]]] = i
        fill[bins[i]] += 1
    return start, order


@njit(cache=True)
def _azimuth_bin(azimuth_rad: float) -> int:
    """Bin of an azimuth, any real angle (wrapped)."""
    b = int(math.floor((azimuth_rad + math.pi) * (AZIMUTH_BINS / _TWO_PI))) % AZIMUTH_BINS
    return b + AZIMUTH_BINS if b < 0 else b


@njit(cache=True)
def world_azimuths(sensor_azimuth_rad: np.ndarray, mat: np.ndarray, out: np.ndarray) -> None:
    """Azimuths in the world of rays in a sensor's xy plane, for a sensor whose xy plane is horizontal.

    Args:
        sensor_azimuth_rad: (N,) ray azimuths in the sensor frame, rad.
        mat: (9,) sensor orientation, row-major (world from sensor).
        out: (N,) written: world azimuths, rad (not wrapped).
    """
    heading = math.atan2(mat[3], mat[0])  # where the sensor's x axis points
    mirror = -1.0 if mat[0] * mat[4] - mat[1] * mat[3] < 0.0 else 1.0  # upside down: angles turn the other way
    for i in range(sensor_azimuth_rad.shape[0]):
        out[i] = heading + mirror * sensor_azimuth_rad[i]


@njit(cache=True)
def _bin_span(center_rad: float, half_width_rad: float) -> tuple[int, int]:
    """First and last bin (the last may exceed the bin count: wrap it) covering an azimuth interval, padded."""
    if half_width_rad >= math.pi:
        return 0, AZIMUTH_BINS - 1
    lo = int(math.floor((center_rad - half_width_rad + math.pi) * (AZIMUTH_BINS / _TWO_PI))) - 1
    hi = int(math.floor((center_rad + half_width_rad + math.pi) * (AZIMUTH_BINS / _TWO_PI))) + 1
    if hi - lo >= AZIMUTH_BINS:
        return 0, AZIMUTH_BINS - 1
    return lo, hi


@njit(cache=True)
def _cast_circle(ox: float, oy: float, cx: float, cy: float, r: float, g: int, dirs: np.ndarray, start: np.ndarray,
                 order: np.ndarray, max_dist_m: float, dist_out: np.ndarray, geom_out: np.ndarray) -> None:
    """Rays against a circle: the smallest non-negative root of |o + t d - c|^2 = r^2."""
    px, py = ox - cx, oy - cy
    d = math.sqrt(px * px + py * py)
    if d - r > max_dist_m:
        return
    half = math.pi if d <= r else math.asin(r / d)
    lo, hi = _bin_span(math.atan2(-py, -px), half)
    c = px * px + py * py - r * r
    for b in range(lo, hi + 1):
        bb = b % AZIMUTH_BINS
        for j in range(start[bb], start[bb + 1]):
            i = order[j]
            half_b = px * dirs[i, 0] + py * dirs[i, 1]
            disc = half_b * half_b - c
            if disc < 0.0:
                continue
            root = math.sqrt(disc)
            t = -half_b - root
            if t < 0.0:
                t = -half_b + root
            if t >= 0.0 and (geom_out[i] < 0 or t < dist_out[i]):
                dist_out[i], geom_out[i] = t, g


@njit(cache=True)
def _cast_rect(ox: float, oy: float, cx: float, cy: float, ux: float, uy: float, vx: float, vy: float, hu: float,
               hv: float, g: int, dirs: np.ndarray, start: np.ndarray, order: np.ndarray, max_dist_m: float,
               dist_out: np.ndarray, geom_out: np.ndarray) -> None:
    """Rays against a rectangle centred at c with unit axes u, v and half-sizes hu, hv (slab test)."""
    px, py = ox - cx, oy - cy
    pu, pv = px * ux + py * uy, px * vx + py * vy  # origin in the rectangle's frame
    gap_u, gap_v = max(abs(pu) - hu, 0.0), max(abs(pv) - hv, 0.0)
    if math.sqrt(gap_u * gap_u + gap_v * gap_v) > max_dist_m:
        return
    inside = abs(pu) <= hu and abs(pv) <= hv
    center = math.atan2(-py, -px)
    half = math.pi if inside else _rect_half_width(px, py, ux, uy, vx, vy, hu, hv, center)
    lo, hi = _bin_span(center, half)
    for b in range(lo, hi + 1):
        bb = b % AZIMUTH_BINS
        for j in range(start[bb], start[bb + 1]):
            i = order[j]
            du = dirs[i, 0] * ux + dirs[i, 1] * uy
            dv = dirs[i, 0] * vx + dirs[i, 1] * vy
            t = _slab_hit(pu, pv, du, dv, hu, hv)
            if t >= 0.0 and (geom_out[i] < 0 or t < dist_out[i]):
                dist_out[i], geom_out[i] = t, g


@njit(cache=True)
def _rect_half_width(px: float, py: float, ux: float, uy: float, vx: float, vy: float, hu: float, hv: float,
                     center_rad: float) -> float:
    """Largest angle between the direction to the centre and the direction to a corner, seen from outside."""
    half = 0.0
    for su in (-1.0, 1.0):
        for sv in (-1.0, 1.0):
            kx = -px + su * hu * ux + sv * hv * vx
            ky = -py + su * hu * uy + sv * hv * vy
            off = math.atan2(ky, kx) - center_rad
            off = abs(math.atan2(math.sin(off), math.cos(off)))
            half = max(half, off)
    return half


@njit(cache=True)
def _slab_hit(pu: float, pv: float, du: float, dv: float, hu: float, hv: float) -> float:
    """First non-negative t where p + t d meets the boundary of [-hu, hu] x [-hv, hv], or -1."""
    t_near, t_far = -np.inf, np.inf
    for p, d, h in ((pu, du, hu), (pv, dv, hv)):
        if d == 0.0:
            if abs(p) > h:
                return -1.0
            continue
        t0, t1 = (-h - p) / d, (h - p) / d
        if t0 > t1:
            t0, t1 = t1, t0
        t_near, t_far = max(t_near, t0), min(t_far, t1)
    if t_near > t_far or t_far < 0.0:
        return -1.0
    return t_near if t_near >= 0.0 else t_far
