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
RECT, CIRCLE = 0.0, 1.0  # kinds of section rows
SECTION_FIELDS = 10
VERTICAL_TOL = 1e-9  # |z| of a unit vector still treated as horizontal (or 1 - |z| as vertical)
ANGLE_SPARE_RAD = 1e-9  # added to computed angular extents (far below a bin, far above their rounding)
CULL_SPARE_M = 1e-9  # taken off a section's distance before rays with closer hits skip it (far above its rounding)
_TWO_PI = 2.0 * math.pi


@njit(cache=True, error_model="numpy")
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
    if not _horizontal(dirs, dist_out, geom_out):
        return False
    # 1. The 2D section of every geom that crosses the scan plane, in geom order (ties go to the first).
    sections = np.empty((3 * len(geom_ids), SECTION_FIELDS))
    count = _collect_sections(origin[0], origin[1], origin[2], geom_ids, geom_type, geom_size, geom_rbound,
                              geom_xpos, geom_xmat, sections, 0)
    if count < 0:
        return False
    # 2. Every section against the rays of its azimuth bins.
    _cast_sections(origin[0], origin[1], sections, count, dirs, *_bin_rays(azimuth_rad), max_dist_m, dist_out,
                   geom_out)
    return True


@njit(cache=True, error_model="numpy")
def fixed_sections(oz: float, geom_ids: np.ndarray, geom_type: np.ndarray, geom_size: np.ndarray,
                   geom_rbound: np.ndarray, geom_xpos: np.ndarray, geom_xmat: np.ndarray) -> np.ndarray:
    """The sections, at height ``oz`` (m), of geoms that never move (no lying capsules among them: their sections
    depend on the origin), in geom order: (S, SECTION_FIELDS) rows for :func:`cast_planar_scan`, or None when a
    geom leaves the planar model."""
    sections = np.empty((3 * len(geom_ids), SECTION_FIELDS))
    count = _collect_sections(0.0, 0.0, oz, geom_ids, geom_type, geom_size, geom_rbound, geom_xpos, geom_xmat,
                              sections, 0)
    return sections[:count].copy() if count >= 0 else None


@njit(cache=True, error_model="numpy")
def cast_planar_scan(origin: np.ndarray, mat: np.ndarray, dirs_sensor: np.ndarray, sensor_azimuth_rad: np.ndarray,
                     fixed: np.ndarray, geom_ids: np.ndarray, geom_type: np.ndarray, geom_size: np.ndarray,
                     geom_rbound: np.ndarray, geom_xpos: np.ndarray, geom_xmat: np.ndarray, max_dist_m: float,
                     dirs: np.ndarray, dist_out: np.ndarray, geom_out: np.ndarray, ranges_out: np.ndarray) -> bool:
    """:func:`cast_planar` for a sensor whose xy plane is horizontal, with the rays turned into the world here,
    the sections of the geoms that never move made beforehand, and the ranges within reach written out.

    Args:
        origin: (3,) sensor position, world frame, m. mat: (9,) its orientation, row-major (world from sensor).
        dirs_sensor: (N, 3) unit ray directions, sensor frame. sensor_azimuth_rad: (N,) their azimuths, rad.
        fixed: (S, SECTION_FIELDS) sections of the geoms that never move (:func:`fixed_sections` at the
            origin's height), all with lower geom ids than ``geom_ids``.
        geom_ids: (K,) the other geoms to test. geom_type ... geom_xmat, max_dist_m, dist_out, geom_out: as
            :func:`cast_planar`.
        dirs: (N, 3) written: the ray directions, world frame.
        ranges_out: (N,) written: the hit distances within [0, max_dist_m], else 0, m.

    Returns:
        False when the rays or a geom leave the planar model (outputs then undefined), else True.
    """
    n = dirs_sensor.shape[0]
    for i in range(n):
        for r in range(3):
            dirs[i, r] = dirs_sensor[i, 0] * mat[3 * r] + dirs_sensor[i, 1] * mat[3 * r + 1] + \
                dirs_sensor[i, 2] * mat[3 * r + 2]
    if not _horizontal(dirs, dist_out, geom_out):
        return False
    # 1. The fixed sections, then those of the other geoms, in geom order.
    sections = np.empty((fixed.shape[0] + 3 * len(geom_ids), SECTION_FIELDS))
    sections[:fixed.shape[0]] = fixed
    count = _collect_sections(origin[0], origin[1], origin[2], geom_ids, geom_type, geom_size, geom_rbound,
                              geom_xpos, geom_xmat, sections, fixed.shape[0])
    if count < 0:
        return False
    # 2. Every section against the rays of its azimuth bins (world azimuths).
    azimuth = np.empty(n)
    world_azimuths(sensor_azimuth_rad, mat, azimuth)
    _cast_sections(origin[0], origin[1], sections, count, dirs, *_bin_rays(azimuth), max_dist_m, dist_out,
                   geom_out)
    # 3. The hits within reach.
    for i in range(n):
        d = dist_out[i]
        ranges_out[i] = d if geom_out[i] >= 0 and d >= 0.0 and d <= max_dist_m else 0.0
    return True


@njit(cache=True, error_model="numpy")
def _horizontal(dirs: np.ndarray, dist_out: np.ndarray, geom_out: np.ndarray) -> bool:
    """Whether every ray of ``dirs`` (N, 3) is horizontal; the outputs (N,) start with no hit (-1)."""
    for i in range(dirs.shape[0]):
        if abs(dirs[i, 2]) > VERTICAL_TOL:
            return False
        dist_out[i] = -1.0
        geom_out[i] = -1
    return True


@njit(cache=True, error_model="numpy")
def _collect_sections(ox: float, oy: float, oz: float, geom_ids: np.ndarray, geom_type: np.ndarray,
                      geom_size: np.ndarray, geom_rbound: np.ndarray, geom_xpos: np.ndarray, geom_xmat: np.ndarray,
                      sections: np.ndarray, count: int) -> int:
    """Write the 2D sections at height ``oz`` (m) of the geoms ``geom_ids``, in order, after the first ``count``
    rows of ``sections``; (ox, oy) is the ray origin (m). Returns the new count, or -1 when a geom leaves the
    planar model."""
    for g in geom_ids:
        # Scalars only: views or array arguments would cost reference counting per geom.
        t, dz, m8 = geom_type[g], abs(oz - geom_xpos[g, 2]), geom_xmat[g, 8]
        if t == PLANE:
            if abs(m8) < 1.0 - VERTICAL_TOL:
                return -1
        elif dz > geom_rbound[g]:
            continue  # entirely above or below the scan plane
        elif t == BOX:
            up = _vertical_axis(geom_xmat[g, 6], geom_xmat[g, 7], m8)
            if up < 0:
                return -1
            if dz <= geom_size[g, up]:
                a, b = (up + 1) % 3, (up + 2) % 3
                count = _put(sections, count, (RECT, float(g), geom_xpos[g, 0], geom_xpos[g, 1], geom_xmat[g, a],
                                               geom_xmat[g, 3 + a], geom_xmat[g, b], geom_xmat[g, 3 + b],
                                               geom_size[g, a], geom_size[g, b]))
        elif t == SPHERE or abs(m8) >= 1.0 - VERTICAL_TOL:
            r = _section_radius(t, geom_size[g, 0], geom_size[g, 1], dz)
            if r < 0.0:
                return -1
            if r > 0.0:
                row = (CIRCLE, float(g), geom_xpos[g, 0], geom_xpos[g, 1], r, 0.0, 0.0, 0.0, 0.0, 0.0)
                count = _put(sections, count, row)
        elif abs(m8) <= VERTICAL_TOL:
            count = _lying_sections(ox, oy, t, geom_xpos[g], geom_xmat[g], geom_size[g], dz, g, sections, count)
            if count < 0:
                return -1
        else:
            return -1
    return count


@njit(cache=True, inline="always", error_model="numpy")
def _put(sections: np.ndarray, count: int, row: tuple) -> int:
    """Writes ``row`` (SECTION_FIELDS numbers) as section ``count``; returns the new count."""
    for k in range(SECTION_FIELDS):
        sections[count, k] = row[k]
    return count + 1


@njit(cache=True, error_model="numpy")
def _lying_sections(ox: float, oy: float, geom_type: int, pos: np.ndarray, mat: np.ndarray, size: np.ndarray,
                    dz: float, g: int, sections: np.ndarray, count: int) -> int:
    """Sections of a cylinder or capsule whose axis is horizontal: a rectangle, plus end circles for the
    capsule's stadium. Returns the new count, or -1 for another type or an origin inside the stadium (a union's
    exit is not its pieces')."""
    r, half = size[0], size[1]
    if dz >= r:
        return count
    w = math.sqrt(r * r - dz * dz)  # half-width of the section
    ux, uy = mat[2], mat[5]  # the axis, horizontal
    norm = math.sqrt(ux * ux + uy * uy)
    ux, uy = ux / norm, uy / norm
    if geom_type != CYLINDER and geom_type != CAPSULE:
        return -1
    if geom_type == CAPSULE:
        pu, pv = (ox - pos[0]) * ux + (oy - pos[1]) * uy, -(ox - pos[0]) * uy + (oy - pos[1]) * ux
        gap_u = max(abs(pu) - half, 0.0)
        if gap_u * gap_u + pv * pv <= w * w:
            return -1
    count = _put(sections, count, (RECT, float(g), pos[0], pos[1], ux, uy, -uy, ux, half, w))
    if geom_type == CAPSULE:
        for end in (-half, half):
            row = (CIRCLE, float(g), pos[0] + end * ux, pos[1] + end * uy, w, 0.0, 0.0, 0.0, 0.0, 0.0)
            count = _put(sections, count, row)
    return count


@njit(cache=True, error_model="numpy")
def _vertical_axis(m6: float, m7: float, m8: float) -> int:
    """Index of the geom axis along world z, from the last row ``m6, m7, m8`` of its row-major rotation, or -1 if
    none is."""
    for k, m in enumerate((m6, m7, m8)):
        if abs(m) >= 1.0 - VERTICAL_TOL:
            return k
    return -1


@njit(cache=True, error_model="numpy")
def _section_radius(geom_type: int, size0: float, size1: float, dz: float) -> float:
    """Radius of an upright round geom's section ``dz`` from its centre, from its first two sizes (0: the plane
    misses it; -1: unknown type)."""
    if geom_type == SPHERE:
        return math.sqrt(size0 * size0 - dz * dz) if dz < size0 else 0.0
    if geom_type == CYLINDER:
        return size0 if dz <= size1 else 0.0
    if geom_type == CAPSULE:
        cap = dz - size1
        if cap <= 0.0:
            return size0
        return math.sqrt(size0 * size0 - cap * cap) if cap < size0 else 0.0
    return -1.0


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def _azimuth_bin(azimuth_rad: float) -> int:
    """Bin of an azimuth, any real angle (wrapped)."""
    b = int(math.floor((azimuth_rad + math.pi) * (AZIMUTH_BINS / _TWO_PI))) % AZIMUTH_BINS
    return b + AZIMUTH_BINS if b < 0 else b


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def _bin_span(center_rad: float, half_width_rad: float) -> tuple[int, int]:
    """First and last bin (the last may exceed the bin count: wrap it) covering an azimuth interval, padded."""
    if half_width_rad >= math.pi:
        return 0, AZIMUTH_BINS - 1
    lo = int(math.floor((center_rad - half_width_rad + math.pi) * (AZIMUTH_BINS / _TWO_PI))) - 1
    hi = int(math.floor((center_rad + half_width_rad + math.pi) * (AZIMUTH_BINS / _TWO_PI))) + 1
    if hi - lo >= AZIMUTH_BINS:
        return 0, AZIMUTH_BINS - 1
    return lo, hi


@njit(cache=True, error_model="numpy")
def _cast_sections(ox: float, oy: float, sections: np.ndarray, count: int, dirs: np.ndarray, start: np.ndarray,
                   order: np.ndarray, max_dist_m: float, dist_out: np.ndarray, geom_out: np.ndarray) -> None:
    """The rays from ``(ox, oy)`` against the first ``count`` sections (rows ``kind, geom, cx, cy, ...``): a ray
    keeps its first non-negative hit, and skips a section lying entirely beyond a hit it has. Written out in one
    loop: per-section calls with array arguments would cost reference counting per geom."""
    for s in range(count):
        kind, g, cx, cy = sections[s, 0], int(sections[s, 1]), sections[s, 2], sections[s, 3]
        px, py = ox - cx, oy - cy
        if kind == CIRCLE:
            # Smallest non-negative root of |o + t d - c|^2 = r^2.
            r = sections[s, 4]
            d = math.sqrt(px * px + py * py)
            if d - r > max_dist_m:
                continue
            lo, hi = _bin_span(math.atan2(-py, -px), math.pi if d <= r else math.asin(r / d))
            c = px * px + py * py - r * r
            near = d - r - CULL_SPARE_M  # a ray that already hit closer than this cannot hit it closer
            for b in range(lo, hi + 1):
                bb = b % AZIMUTH_BINS
                for j in range(start[bb], start[bb + 1]):
                    i = order[j]
                    if geom_out[i] >= 0 and dist_out[i] < near:
                        continue
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
        else:
            # Rectangle centred at c with unit axes u, v and half-sizes hu, hv (slab test).
            ux, uy, vx, vy, hu, hv = sections[s, 4], sections[s, 5], sections[s, 6], sections[s, 7], \
                sections[s, 8], sections[s, 9]
            pu, pv = px * ux + py * uy, px * vx + py * vy  # origin in the rectangle's frame
            gap_u, gap_v = max(abs(pu) - hu, 0.0), max(abs(pv) - hv, 0.0)
            gap = math.sqrt(gap_u * gap_u + gap_v * gap_v)
            if gap > max_dist_m:
                continue
            inside = abs(pu) <= hu and abs(pv) <= hv
            center = math.atan2(-py, -px)
            half = math.pi if inside else _rect_half_width(px, py, ux, uy, vx, vy, hu, hv)
            lo, hi = _bin_span(center, half)
            near = gap - CULL_SPARE_M  # a ray that already hit closer than this cannot hit it closer
            for b in range(lo, hi + 1):
                bb = b % AZIMUTH_BINS
                for j in range(start[bb], start[bb + 1]):
                    i = order[j]
                    if geom_out[i] >= 0 and dist_out[i] < near:
                        continue
                    du = dirs[i, 0] * ux + dirs[i, 1] * uy
                    dv = dirs[i, 0] * vx + dirs[i, 1] * vy
                    t = _slab_hit(pu, pv, du, dv, hu, hv)
                    if t >= 0.0 and (geom_out[i] < 0 or t < dist_out[i]):
                        dist_out[i], geom_out[i] = t, g


@njit(cache=True, error_model="numpy")
def _rect_half_width(px: float, py: float, ux: float, uy: float, vx: float, vy: float, hu: float,
                     hv: float) -> float:
    """Largest angle between the direction to the centre and the direction to a corner, seen from outside (each
    the ``atan2`` of the cross and dot products), plus ANGLE_SPARE_RAD so as not to fall short of other roundings
    of it, rad."""
    half = 0.0
    for su in (-1.0, 1.0):
        for sv in (-1.0, 1.0):
            kx = -px + su * hu * ux + sv * hv * vx
            ky = -py + su * hu * uy + sv * hv * vy
            half = max(half, math.atan2(abs(px * ky - py * kx), -(px * kx + py * ky)))
    return half + ANGLE_SPARE_RAD


@njit(cache=True, error_model="numpy")
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
