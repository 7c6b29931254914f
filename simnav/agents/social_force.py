"""Helbing & Molnár (1995) social force model with hard non-overlap constraints.

All arrays are in the world frame (x/y on the floor), SI units. Pedestrian α accelerates as

    dv_α/dt = (v_α⁰·e_α − v_α)/τ + Σ_β w·f_αβ + Σ_c w·f_αc + Σ_B f_αB

* ``f_αβ = −∇V(b)``, ``V(b) = V⁰·exp(−b/σ)``, where b is the semi-minor axis of the ellipse about β that
  accounts for β's next step ``y_β = v_β·Δt``: ``2b = sqrt((|r| + |r − y_β|)² − |y_β|²)``, ``r = r_α − r_β``.
  The gradient is analytic: ``∇b = (|r| + |r − y|)/(4b) · (r/|r| + (r − y)/|r − y|)``.
* Round obstacles c (e.g. the robot) repel like pedestrians, with r measured from the rim of the circle.
* Walls: ``f_αB = −∇U(d)``, ``U(d) = U⁰·exp(−d/R)``, d the distance to the closest point of each segment.
  Two additions keep the model usable with segment outlines and doorways (see :class:`SocialForceParams`):
  closest points seen within ``wall_merge_angle_deg`` of a closer one belong to the same obstacle and push
  once (a corner is not counted twice); and while the ``wall_look_ahead_m`` ahead of a pedestrian are clear
  of walls, walls only steer it (with U⁰ = 10, R = 0.2 the jambs of a 1 m doorway otherwise brake harder,
  2.8 m/s², than anybody slower than 1.4 m/s can push, v⁰/τ).
* Field of view: ``w = 1`` when the interaction partner lies within ±fov/2 of e_α, else
  ``out_of_view_weight``.

Forces are per unit mass (m/s²). :func:`resolve_overlaps` then projects positions out of walls, circles and
each other, so bodies never interpenetrate even where the forces are too weak.

The per-step entry points (:func:`social_force_pairs`, :func:`integrate`, :func:`resolve_overlaps_pairs`) run as
Numba kernels (:mod:`simnav.agents.kernels`); the array formulation here (:func:`social_force_pairs_reference`,
:func:`resolve_overlaps_pairs_reference` and the functions they call) defines the model, and the kernels give the
same results to the bit.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from simnav.agents.kernels import CONTACT_MARGIN_M as KERNEL_CONTACT_MARGIN_M
from simnav.agents.kernels import (
    exponents,
    integrate_kernel,
    resolve_overlaps_kernel,
    social_force_kernel,
    wall_far_m,
    wall_offsets,
)

_EPS = 1e-9
_NEGLIGIBLE_M_S2 = 1e-3  # wall forces weaker than this are skipped
CONTACT_MARGIN_M = KERNEL_CONTACT_MARGIN_M
"""Clearance added by :func:`resolve_overlaps` beyond touching (bodies end up at least half of it apart)."""
NEAR_SLACK_M = 1.0
"""A projection ignores walls further than the radius + this + the move from ``previous_xy``, metres."""


@dataclass(frozen=True)
class SocialForceParams:
    """Parameters of the social force model (defaults: Helbing & Molnár 1995 as in common implementations).

    Attributes:
        v0_m2_s2: V⁰, strength of the pedestrian repulsion potential.
        sigma_m: σ, range of the pedestrian repulsion potential.
        u0_m2_s2: U⁰, strength of the wall repulsion potential.
        r_m: R, range of the wall repulsion potential.
        tau_s: τ, relaxation time of the driving term.
        fov_deg: full opening angle 2φ of the field of view.
        out_of_view_weight: weight c of forces from partners outside the field of view.
        max_speed_factor: speed cap as a multiple of the desired speed.
        step_time_s: Δt of the step ``y_β = v_β·Δt`` in the elliptical potential.
        radius_m: body radius of a pedestrian.
        wall_cutoff_m: walls further than this are ignored.
        wall_merge_angle_deg: wall points seen within this angle of a closer one count as the same obstacle
            (0: every segment pushes on its own).
        wall_look_ahead_m: when no wall comes within ``radius_m`` of this stretch along the desired
            direction, wall forces only steer: their component against the desired direction is dropped,
            so door jambs do not hold people back (with the H&M values a 1 m doorway otherwise stops
            anyone slower than about 1.4 m/s). 0 gives plain H&M walls.
        circle_steering: fraction of a round obstacle's (a robot's) push against the desired direction that is
            turned into a sideways push, away from the line through the obstacle along that direction (to the
            right when dead centre): people walk around a robot standing in their way instead of stopping in
            front of it, where the plain model balances drive and repulsion. 0 gives plain H&M.
        circle_clearance_m: personal space people keep from a round obstacle (a robot), beyond touching it: the
            crowd sees every circle this much larger (repulsion, non-overlap, face-offs), so people pass a robot
            at arm's length instead of brushing it or standing pressed against it. 0: they may touch.
    """

    v0_m2_s2: float = 2.1
    sigma_m: float = 0.3
    u0_m2_s2: float = 10.0
    r_m: float = 0.2
    tau_s: float = 0.5
    fov_deg: float = 200.0
    out_of_view_weight: float = 0.5
    max_speed_factor: float = 1.3
    step_time_s: float = 0.4
    radius_m: float = 0.25
    wall_cutoff_m: float = 1.5  # U0/R exp(-1.5/R) = 0.03 m/s^2 there: negligible beside the ~2.7 m/s^2 drive
    wall_merge_angle_deg: float = 45.0
    wall_look_ahead_m: float = 1.0
    circle_steering: float = 1.0
    circle_clearance_m: float = 0.1

    @property
    def cos_half_fov(self) -> float:
        """cos(φ) with φ = fov/2."""
        return math.cos(math.radians(0.5 * self.fov_deg))


class Segments:
    """Wall segments prepared for repeated point queries.

    Args:
        segments: (M, 2, 2) segment endpoints ``[[x0, y0], [x1, y1]]``, world frame, metres.
    """

    def __init__(self, segments: np.ndarray) -> None:
        seg = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
        self.start = np.ascontiguousarray(seg[:, 0])
        self.delta = np.ascontiguousarray(seg[:, 1] - seg[:, 0])
        self.inv_len2 = 1.0 / np.maximum(np.sum(self.delta**2, axis=1), 1e-18)

    def __len__(self) -> int:
        return len(self.start)

    @property
    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(start (M, 2), delta (M, 2), 1/|delta|² (M,)), as the kernels of :mod:`simnav.agents.kernels` take them."""
        return self.start, self.delta, self.inv_len2

    def extended(self, segments: np.ndarray) -> Segments:
        """These segments followed by (D, 2, 2) ``segments``, metres (as :class:`Segments` of both together)."""
        extra = Segments(segments)
        out = Segments.__new__(Segments)
        out.start = np.concatenate([self.start, extra.start])
        out.delta = np.concatenate([self.delta, extra.delta])
        out.inv_len2 = np.concatenate([self.inv_len2, extra.inv_len2])
        return out

    def closest_points(self, points: np.ndarray, seg_idx: np.ndarray) -> np.ndarray:
        """(P, 2) closest point of segment ``seg_idx[k]`` to ``points[k]``, for (P, 2) points."""
        a = self.start[seg_idx]
        ab = self.delta[seg_idx]
        ap = points - a
        t = (ap[:, 0] * ab[:, 0] + ap[:, 1] * ab[:, 1]) * self.inv_len2[seg_idx]
        np.clip(t, 0.0, 1.0, out=t)
        return a + t[:, None] * ab

    def offsets(
        self, points: np.ndarray, ped_idx: np.ndarray, seg_idx: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Offsets of points from segments, metres.

        Returns:
            (P, 2) vectors from the closest point of segment ``seg_idx[k]`` to ``points[ped_idx[k]]``,
            and their (P,) lengths.
        """
        p = points[ped_idx]
        diff = p - self.closest_points(p, seg_idx)
        return diff, np.hypot(diff[:, 0], diff[:, 1])


def wall_reach_m(params: SocialForceParams) -> float:
    """Distance within which a wall can affect a pedestrian's forces, metres."""
    return max(params.wall_cutoff_m, params.wall_look_ahead_m + params.radius_m)


def all_pairs(n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Every (pedestrian, segment) index pair for n pedestrians and m segments: two (n·m,) int arrays."""
    return np.repeat(np.arange(n), m), np.tile(np.arange(m), n)


def box_pairs(points: np.ndarray, segments: Segments, reach_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(point, segment) index pairs whose segment bounding box, grown by ``reach_m``, holds the point.

    A superset of the pairs closer than ``reach_m``, found with a few comparisons per pair.
    """
    if len(points) == 0 or len(segments) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    end = segments.start + segments.delta
    low = np.minimum(segments.start, end) - reach_m
    high = np.maximum(segments.start, end) + reach_m
    x, y = points[:, 0:1], points[:, 1:2]
    inside = (x >= low[:, 0]) & (x <= high[:, 0]) & (y >= low[:, 1]) & (y <= high[:, 1])
    return np.nonzero(inside)


def driving_force(
    velocities: np.ndarray, desired_dirs: np.ndarray, desired_speeds: np.ndarray, params: SocialForceParams
) -> np.ndarray:
    """Relaxation toward the desired velocity, ``(v⁰·e − v)/τ``: (N, 2) m/s² from (N, 2), (N, 2), (N,)."""
    return (desired_speeds[:, None] * desired_dirs - velocities) / params.tau_s


def elliptical_repulsion(r: np.ndarray, step: np.ndarray, params: SocialForceParams) -> np.ndarray:
    """``−∇V(b)`` with respect to r for the elliptical potential of a partner taking ``step``.

    Args:
        r: (..., 2) vectors from the partner to the pedestrian, metres.
        step: (..., 2) the partner's step ``v·Δt``, metres (broadcast against r).
        params: model parameters (V⁰, σ).

    Returns:
        (..., 2) force per unit mass, m/s², pointing away from the partner.
    """
    u = r - step
    n1 = np.maximum(np.sqrt(np.sum(r * r, axis=-1)), _EPS)
    n2 = np.maximum(np.sqrt(np.sum(u * u, axis=-1)), _EPS)
    s2 = np.sum(step * step, axis=-1)
    total = n1 + n2
    b = np.maximum(0.5 * np.sqrt(np.maximum(total * total - s2, 0.0)), _EPS)
    scale = params.v0_m2_s2 / params.sigma_m * np.exp(-b / params.sigma_m) * total / (4.0 * b)
    return scale[..., None] * (r / n1[..., None] + u / n2[..., None])


def view_weights(desired_dirs: np.ndarray, forces: np.ndarray, params: SocialForceParams) -> np.ndarray:
    """Field-of-view weights (N, K) for forces (N, K, 2) acting on pedestrians with directions (N, 2).

    A repulsion points away from its source, so the source is in view when ``e·(−f) ≥ |f|·cos(φ)``.
    """
    toward = -np.sum(desired_dirs[:, None, :] * forces, axis=-1)
    norm = np.sqrt(np.sum(forces * forces, axis=-1))
    return np.where(toward >= norm * params.cos_half_fov, 1.0, params.out_of_view_weight)


def pedestrian_repulsion(
    positions: np.ndarray, velocities: np.ndarray, desired_dirs: np.ndarray, params: SocialForceParams
) -> np.ndarray:
    """Sum of the weighted elliptical repulsions between N pedestrians: (N, 2) m/s².

    Args:
        positions: (N, 2) metres. velocities: (N, 2) m/s. desired_dirs: (N, 2) unit vectors.
        params: model parameters.
    """
    n = len(positions)
    if n < 2:
        return np.zeros((n, 2))
    r = positions[:, None, :] - positions[None, :, :]
    step = (velocities * params.step_time_s)[None, :, :]
    f = elliptical_repulsion(r, step, params)
    f *= view_weights(desired_dirs, f, params)[..., None]
    f[np.arange(n), np.arange(n)] = 0.0
    return np.sum(f, axis=1)


def circle_repulsion(
    positions: np.ndarray,
    desired_dirs: np.ndarray,
    circles: np.ndarray,
    circle_velocities: np.ndarray | None,
    params: SocialForceParams,
) -> np.ndarray:
    """Weighted elliptical repulsion from C moving circles ``[x, y, radius]``, distances from their rims.

    Args:
        positions: (N, 2) metres. desired_dirs: (N, 2) unit vectors.
        circles: (C, 3) centre x, y and radius, metres.
        circle_velocities: (C, 2) m/s, or None for still circles.
        params: model parameters.

    Returns:
        (N, 2) m/s².
    """
    circles = np.asarray(circles, dtype=float).reshape(-1, 3)
    if len(circles) == 0 or len(positions) == 0:
        return np.zeros((len(positions), 2))
    vel = np.zeros((len(circles), 2)) if circle_velocities is None else np.asarray(circle_velocities, float)
    r = positions[:, None, :] - circles[None, :, :2]
    dist = np.maximum(np.sqrt(np.sum(r * r, axis=-1)), _EPS)
    rim_dist = np.maximum(dist - circles[None, :, 2], 1e-3)
    r_rim = r * (rim_dist / dist)[..., None]
    f = elliptical_repulsion(r_rim, (vel * params.step_time_s)[None, :, :], params)
    f *= view_weights(desired_dirs, f, params)[..., None]
    if params.circle_steering > 0:
        f = _steer_around(f, r, desired_dirs, params.circle_steering)
    return np.sum(f, axis=1)


def _steer_around(f: np.ndarray, r: np.ndarray, desired_dirs: np.ndarray, fraction: float) -> np.ndarray:
    """(N, C, 2) forces ``f`` with ``fraction`` of their part against the desired direction turned sideways.

    ``r`` (N, C, 2) runs from each obstacle to each pedestrian; the sideways direction is the part of ``r``
    across the desired direction (the pedestrian's side of the obstacle), or the right-hand side when that
    part is shorter than 1 cm.
    """
    e = desired_dirs[:, None, :]
    against = np.minimum(np.sum(f * e, axis=-1), 0.0) * fraction  # (N, C), <= 0
    across = r - np.sum(r * e, axis=-1)[..., None] * e
    norm = np.sqrt(np.sum(across * across, axis=-1))
    right = np.broadcast_to(np.stack([e[..., 1], -e[..., 0]], axis=-1), across.shape)
    side = np.where((norm > 0.01)[..., None], across / np.maximum(norm, 1e-12)[..., None], right)
    return f - against[..., None] * e - against[..., None] * side


def wall_repulsion_pairs(
    positions: np.ndarray,
    segments: Segments,
    ped_idx: np.ndarray,
    seg_idx: np.ndarray,
    params: SocialForceParams,
    desired_dirs: np.ndarray | None = None,
) -> np.ndarray:
    """Wall repulsion ``U⁰/R·exp(−d/R)`` along the outward normal, summed over the walls a pedestrian faces.

    Each segment offers its closest point. A point seen within ``wall_merge_angle_deg`` of a closer one is
    part of the same obstacle (the other segment at a corner, the far face of a thin wall, the next piece of
    a straight wall) and adds nothing, so every obstacle pushes once, from its nearest point, as in the
    model, however its outline is cut into segments. With ``desired_dirs`` and ``wall_look_ahead_m`` > 0, a
    pedestrian whose way ahead is clear keeps only the part of the force that does not oppose its desired
    direction.

    Args:
        positions: (N, 2) metres.
        segments: the walls.
        ped_idx, seg_idx: (P,) candidate (pedestrian, segment) pairs; pairs beyond ``wall_cutoff_m`` add
            nothing.
        params: model parameters.
        desired_dirs: (N, 2) unit desired directions, or None.

    Returns:
        (N, 2) m/s².
    """
    n = len(positions)
    if len(ped_idx) == 0:
        return np.zeros((n, 2))
    diff, d = segments.offsets(positions, ped_idx, seg_idx)
    strength = params.u0_m2_s2 / params.r_m
    reach = params.r_m * math.log(max(strength / _NEGLIGIBLE_M_S2, 1.0))
    near = d < min(params.wall_cutoff_m, reach)
    in_look = d <= params.wall_look_ahead_m + params.radius_m  # only these can come near the stretch
    look_ped, look_seg = ped_idx[in_look], seg_idx[in_look]
    ped, diff, d = ped_idx[near], diff[near], np.maximum(d[near], _EPS)
    normal = diff / d[:, None]
    kept = _nearest_per_direction(ped, d, normal, n, math.cos(math.radians(params.wall_merge_angle_deg)))
    mag = strength * np.exp(-d[kept] / params.r_m)
    force = _sum_by_index(ped[kept], normal[kept] * mag[:, None], n)
    if desired_dirs is None or params.wall_look_ahead_m <= 0.0:
        return force
    return _steer_only_when_clear(force, positions, desired_dirs, segments, look_ped, look_seg, params)


def _steer_only_when_clear(
    force: np.ndarray,
    positions: np.ndarray,
    desired_dirs: np.ndarray,
    segments: Segments,
    ped_idx: np.ndarray,
    seg_idx: np.ndarray,
    params: SocialForceParams,
) -> np.ndarray:
    """Drop the component of ``force`` against the desired direction where the way ahead is clear.

    The way is clear when no segment comes within a body radius of the look-ahead stretch.
    """
    start = positions[ped_idx]
    ahead = start + params.wall_look_ahead_m * desired_dirs[ped_idx]
    hits = _segment_gaps(start, ahead, segments, seg_idx) < params.radius_m
    clear = np.bincount(ped_idx[hits], minlength=len(positions)) == 0
    along = np.sum(force * desired_dirs, axis=1)
    against = clear & (along < 0.0)
    force[against] -= along[against, None] * desired_dirs[against]
    return force


def _nearest_per_direction(
    ped: np.ndarray, dist: np.ndarray, normal: np.ndarray, n: int, cos_merge: float
) -> np.ndarray:
    """(P,) True for the points no closer point of the same pedestrian sees within the merge angle."""
    if len(ped) == 0:
        return np.zeros(0, dtype=bool)
    order = np.lexsort((dist, ped))
    ped_s, normal_s = ped[order], normal[order]
    counts = np.bincount(ped_s, minlength=n)
    rank = np.arange(len(ped_s)) - np.repeat(np.cumsum(counts) - counts, counts)
    width = int(counts.max())
    padded = np.zeros((n, width, 2))
    padded[ped_s, rank] = normal_s
    nx, ny = padded[..., 0], padded[..., 1]
    cos = nx[:, :, None] * nx[:, None, :] + ny[:, :, None] * ny[:, None, :]
    closer = np.tri(width, width, -1, dtype=bool)  # [k, j]: j comes before (is closer than) k
    merged = np.any((cos > cos_merge) & closer, axis=2)  # padding comes after a row's points: never closer
    kept = np.empty(len(ped), dtype=bool)
    kept[order] = ~merged[ped_s, rank]
    return kept


def social_force(
    positions: np.ndarray,
    velocities: np.ndarray,
    desired_dirs: np.ndarray,
    desired_speeds: np.ndarray,
    segments: np.ndarray,
    circles: np.ndarray | None = None,
    circle_velocities: np.ndarray | None = None,
    params: SocialForceParams = SocialForceParams(),
) -> np.ndarray:
    """Total social-force acceleration of N pedestrians.

    Args:
        positions: (N, 2) pedestrian centres, world frame, metres.
        velocities: (N, 2) m/s.
        desired_dirs: (N, 2) unit vectors toward the next waypoint.
        desired_speeds: (N,) m/s (0 for a pedestrian that wants to stand still).
        segments: (M, 2, 2) wall segments, metres.
        circles: (C, 3) round obstacles ``[x, y, radius]`` (e.g. the robot), metres, or None.
        circle_velocities: (C, 2) m/s of the circles, or None (still).
        params: model parameters.

    Returns:
        (N, 2) acceleration, m/s².
    """
    positions = np.asarray(positions, dtype=float).reshape(-1, 2)
    segs = Segments(segments)
    ped_idx, seg_idx = box_pairs(positions, segs, wall_reach_m(params))
    return social_force_pairs(
        positions, velocities, desired_dirs, desired_speeds, segs, ped_idx, seg_idx,
        circles, circle_velocities, params,
    )


def social_force_pairs(
    positions: np.ndarray,
    velocities: np.ndarray,
    desired_dirs: np.ndarray,
    desired_speeds: np.ndarray,
    segments: Segments,
    ped_idx: np.ndarray,
    seg_idx: np.ndarray,
    circles: np.ndarray | None,
    circle_velocities: np.ndarray | None,
    params: SocialForceParams,
) -> np.ndarray:
    """:func:`social_force` with prepared walls and candidate (pedestrian, segment) pairs (a Numba kernel)."""
    pos = np.ascontiguousarray(positions, dtype=float).reshape(-1, 2)
    circ, circ_vel = circle_arrays(circles, circle_velocities)
    n = len(pos)
    vel, dirs, speeds = (_broadcast(a, shape) for a, shape in
                         ((velocities, (n, 2)), (desired_dirs, (n, 2)), (desired_speeds, (n,))))
    ped, seg, p = _as_index(ped_idx), _as_index(seg_idx), kernel_params(params)
    offsets = wall_offsets(pos, segments.start, segments.delta, segments.inv_len2, ped, seg, wall_far_m(p))
    args, ell = exponents(pos, vel, offsets, circ, circ_vel, p)
    return social_force_kernel(
        pos, vel, dirs, speeds, segments.start, segments.delta, ped, seg, offsets, circ, circ_vel,
        circles is not None, p, params.wall_look_ahead_m > 0.0, np.exp(args), ell,
    )


def circle_arrays(
    circles: np.ndarray | None, circle_velocities: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """Round obstacles as the kernels take them: contiguous (C, 3) ``[x, y, radius]`` (metres; (0, 3) for None)
    and (C, 2) velocities (m/s; zeros for None)."""
    circ = np.zeros((0, 3)) if circles is None else np.ascontiguousarray(circles, dtype=float).reshape(-1, 3)
    if circle_velocities is None:
        return circ, np.zeros((len(circ), 2))
    return circ, _broadcast(circle_velocities, (len(circ), 2))


@functools.lru_cache(maxsize=16)
def kernel_params(params: SocialForceParams) -> np.ndarray:
    """The parameters as the float64 vector the kernels of :mod:`simnav.agents.kernels` read (read-only)."""
    strength = params.u0_m2_s2 / params.r_m
    reach = params.r_m * math.log(max(strength / _NEGLIGIBLE_M_S2, 1.0))
    values = np.array([
        params.v0_m2_s2, params.sigma_m, params.u0_m2_s2, params.r_m, params.tau_s, params.cos_half_fov,
        params.out_of_view_weight, params.step_time_s, params.radius_m, params.wall_cutoff_m,
        math.cos(math.radians(params.wall_merge_angle_deg)), params.wall_look_ahead_m, params.circle_steering,
        strength, min(params.wall_cutoff_m, reach),
    ], dtype=np.float64)
    values.flags.writeable = False
    return values


def _as_index(idx: np.ndarray) -> np.ndarray:
    """(P,) contiguous int64 indices."""
    return np.ascontiguousarray(idx, dtype=np.int64).reshape(-1)


def social_force_pairs_reference(
    positions: np.ndarray,
    velocities: np.ndarray,
    desired_dirs: np.ndarray,
    desired_speeds: np.ndarray,
    segments: Segments,
    ped_idx: np.ndarray,
    seg_idx: np.ndarray,
    circles: np.ndarray | None,
    circle_velocities: np.ndarray | None,
    params: SocialForceParams,
) -> np.ndarray:
    """:func:`social_force_pairs` written with numpy array operations (the reference of the kernel)."""
    velocities = np.asarray(velocities, dtype=float).reshape(-1, 2)
    desired_dirs = np.asarray(desired_dirs, dtype=float).reshape(-1, 2)
    acc = driving_force(velocities, desired_dirs, np.asarray(desired_speeds, dtype=float), params)
    acc += pedestrian_repulsion(positions, velocities, desired_dirs, params)
    if circles is not None:
        acc += circle_repulsion(positions, desired_dirs, circles, circle_velocities, params)
    acc += wall_repulsion_pairs(positions, segments, ped_idx, seg_idx, params, desired_dirs)
    return acc


def integrate(
    positions: np.ndarray,
    velocities: np.ndarray,
    acceleration: np.ndarray,
    desired_speeds: np.ndarray,
    dt_s: float,
    params: SocialForceParams = SocialForceParams(),
) -> tuple[np.ndarray, np.ndarray]:
    """Semi-implicit Euler step with the speed cap ``|v| ≤ max_speed_factor·v⁰``.

    Args:
        positions: (N, 2) metres. velocities: (N, 2) m/s. acceleration: (N, 2) m/s².
        desired_speeds: (N,) m/s, the v⁰ of the cap.
        dt_s: time step, seconds.
        params: model parameters.

    Returns:
        New positions (N, 2) and velocities (N, 2), with ``x' = x + v'·dt``.
    """
    pos = np.ascontiguousarray(positions, dtype=float).reshape(-1, 2)
    n = len(pos)
    vel, acc, speeds = (_broadcast(a, shape) for a, shape in
                        ((velocities, (n, 2)), (acceleration, (n, 2)), (desired_speeds, (n,))))
    return integrate_kernel(pos, vel, acc, speeds, float(dt_s), float(params.max_speed_factor))


def _broadcast(values: np.ndarray | float, shape: tuple[int, ...]) -> np.ndarray:
    """``values`` as a contiguous float64 array of ``shape`` (broadcast as numpy would)."""
    array = np.asarray(values, dtype=float)
    return np.ascontiguousarray(array if array.shape == shape else np.broadcast_to(array, shape))


def resolve_overlaps(
    positions: np.ndarray,
    radius_m: float,
    segments: np.ndarray,
    circles: np.ndarray | None = None,
    iterations: int = 4,
    previous_xy: np.ndarray | None = None,
) -> np.ndarray:
    """Project discs of ``radius_m`` out of walls, round obstacles and each other.

    Each sweep separates overlapping pedestrian pairs (a pedestrian touching a wall does not yield), pushes
    pedestrians out of circles, then pushes them out of every segment closer than the radius along the
    direction from the closest segment point to the centre, so a wall never pushes anybody through itself.
    Sweeps stop early once nothing moves; walls have the last word. With ``previous_xy``, a pedestrian whose
    move from there crosses a segment is first put back where it was.

    Args:
        positions: (N, 2) centres, world frame, metres.
        radius_m: body radius, metres.
        segments: (M, 2, 2) wall segments, metres.
        circles: (C, 3) immovable round obstacles ``[x, y, radius]``, metres, or None.
        iterations: maximum number of sweeps.
        previous_xy: (N, 2) positions before the move, or None.

    Returns:
        (N, 2) corrected positions (a new array).
    """
    positions = np.asarray(positions, dtype=float).reshape(-1, 2)
    segs = Segments(segments)
    move = 0.0
    if previous_xy is not None and len(positions):
        move = float(np.max(np.linalg.norm(positions - np.asarray(previous_xy, dtype=float), axis=1)))
    ped_idx, seg_idx = box_pairs(positions, segs, radius_m + NEAR_SLACK_M + move)
    crossing = None if previous_xy is None else np.ones(len(ped_idx), dtype=bool)
    return resolve_overlaps_pairs(
        positions, radius_m, segs, ped_idx, seg_idx, circles, iterations, previous_xy, crossing
    )


def resolve_overlaps_pairs(
    positions: np.ndarray,
    radius_m: float,
    segments: Segments,
    ped_idx: np.ndarray,
    seg_idx: np.ndarray,
    circles: np.ndarray | None,
    iterations: int,
    previous_xy: np.ndarray | None = None,
    check_crossing: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`resolve_overlaps` on candidate (pedestrian, segment) pairs (a Numba kernel).

    ``check_crossing`` (P,) marks the pairs whose segment may not be crossed on the way from ``previous_xy``
    (static walls); moving segments (door leaves) are left to the push-out.
    """
    pos = np.ascontiguousarray(positions, dtype=float).reshape(-1, 2)
    circ = circle_arrays(circles, None)[0]
    has_prev = previous_xy is not None
    prev = np.ascontiguousarray(previous_xy, dtype=float).reshape(-1, 2) if has_prev else pos
    guard = has_prev and check_crossing is not None
    check = np.ascontiguousarray(check_crossing, dtype=bool).reshape(-1) if guard else np.zeros(len(ped_idx), bool)
    return resolve_overlaps_kernel(
        pos, float(radius_m), segments.start, segments.delta, segments.inv_len2, _as_index(ped_idx),
        _as_index(seg_idx), circ, int(iterations), prev, has_prev, check, guard, NEAR_SLACK_M,
    )


def resolve_overlaps_pairs_reference(
    positions: np.ndarray,
    radius_m: float,
    segments: Segments,
    ped_idx: np.ndarray,
    seg_idx: np.ndarray,
    circles: np.ndarray | None,
    iterations: int,
    previous_xy: np.ndarray | None = None,
    check_crossing: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`resolve_overlaps_pairs` written with numpy array operations (the reference of the kernel).

    ``check_crossing`` (P,) marks the pairs whose segment may not be crossed on the way from ``previous_xy``
    (static walls); moving segments (door leaves) are left to the push-out.
    """
    pos = np.array(positions, dtype=float)
    prev = None if previous_xy is None else np.asarray(previous_xy, dtype=float)
    moved = pos.copy()
    step = np.zeros(len(pos)) if prev is None else np.linalg.norm(pos - prev, axis=1)
    reach = radius_m + NEAR_SLACK_M + (float(step.max()) if len(step) else 0.0)
    dist = _distances(pos, segments, ped_idx, seg_idx)
    near = dist < reach
    near_ped, near_seg, near_dist = ped_idx[near], seg_idx[near], dist[near]
    guarded = None
    if prev is not None and check_crossing is not None:
        guarded = np.asarray(check_crossing, dtype=bool)[near]
        # a segment crossed on the way from prev lies within the length of that way of its end
        first = guarded & (near_dist <= step[near_ped] + _EPS)
        pos = _undo_crossings(pos, prev, segments, near_ped[first], near_seg[first])
    pos = _project(pos, radius_m, segments, near_ped, near_seg, circles, iterations)
    if prev is not None and guarded is not None:
        way = np.linalg.norm(pos - prev, axis=1) + np.linalg.norm(pos - moved, axis=1)
        last = guarded & (near_dist <= way[near_ped] + _EPS)
        undone = _undo_crossings(pos, prev, segments, near_ped[last], near_seg[last])
        if undone is not pos:  # pushes combined across a wall (e.g. squeezed by a door leaf): walls win
            pos, _ = _push_out_of_walls(undone, radius_m, segments, near_ped, near_seg)
    return pos


def _project(
    pos: np.ndarray,
    radius_m: float,
    segments: Segments,
    ped_idx: np.ndarray,
    seg_idx: np.ndarray,
    circles: np.ndarray | None,
    iterations: int,
) -> np.ndarray:
    """Sweeps of pedestrian separation, circle and wall push-outs until nothing moves; walls go last."""
    circles = None if circles is None else np.asarray(circles, dtype=float).reshape(-1, 3)
    pos, contact = _push_out_of_walls(pos, radius_m, segments, ped_idx, seg_idx)
    for _ in range(max(int(iterations), 1)):
        pos, moved_peds = _separate_pedestrians(pos, radius_m, contact)
        pos, moved_circles = _push_out_of_circles(pos, radius_m, circles)
        if not (moved_peds or moved_circles):
            break
        pos, contact = _push_out_of_walls(pos, radius_m, segments, ped_idx, seg_idx)
    return pos


def _distances(pos: np.ndarray, segments: Segments, ped_idx: np.ndarray, seg_idx: np.ndarray) -> np.ndarray:
    """(P,) distance from pedestrian ``ped_idx[k]`` to segment ``seg_idx[k]``, metres."""
    if len(ped_idx) == 0:
        return np.zeros(0)
    return segments.offsets(pos, ped_idx, seg_idx)[1]


def _push_out_of_walls(
    pos: np.ndarray,
    radius_m: float,
    segments: Segments,
    ped_idx: np.ndarray,
    seg_idx: np.ndarray,
    sweeps: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """Push centres to ``radius + margin`` from every segment closer than ``radius + margin/2``.

    Returns the new positions and the (N,) mask of pedestrians in contact with a wall.
    """
    n = len(pos)
    contact = np.zeros(n, dtype=bool)
    target = radius_m + CONTACT_MARGIN_M
    for _ in range(sweeps):
        if len(ped_idx) == 0:
            break
        diff, d = segments.offsets(pos, ped_idx, seg_idx)
        contact[ped_idx[d < target + 0.5 * CONTACT_MARGIN_M]] = True
        hit = d < radius_m + 0.5 * CONTACT_MARGIN_M
        if not np.any(hit):
            break
        normal = _unit_or_segment_normal(diff[hit], d[hit], segments, seg_idx[hit])
        push = normal * (target - d[hit])[:, None]
        pos = pos + _sum_by_index(ped_idx[hit], push, n)
    return pos, contact


def _unit_or_segment_normal(
    diff: np.ndarray, d: np.ndarray, segments: Segments, seg_idx: np.ndarray
) -> np.ndarray:
    """Unit vectors ``diff/d``; a centre lying on a segment gets the segment's left normal."""
    out = diff / np.maximum(d, _EPS)[:, None]
    on_line = d < 1e-12
    if np.any(on_line):
        t = segments.delta[seg_idx[on_line]]
        length = np.maximum(np.linalg.norm(t, axis=1), _EPS)
        out[on_line] = np.stack([-t[:, 1], t[:, 0]], axis=1) / length[:, None]
    return out


def _separate_pedestrians(pos: np.ndarray, radius_m: float, pinned: np.ndarray) -> tuple[np.ndarray, bool]:
    """Move overlapping pairs apart to ``2·radius + margin``; a pinned (wall-contact) one does not move."""
    n = len(pos)
    if n < 2:
        return pos, False
    i, j = _pair_indices(n)
    diff = pos[i] - pos[j]
    d = np.hypot(diff[:, 0], diff[:, 1])
    hit = d < 2.0 * radius_m + 0.5 * CONTACT_MARGIN_M
    if not np.any(hit):
        return pos, False
    i, j, diff, d = i[hit], j[hit], diff[hit], d[hit]
    normal = diff / np.maximum(d, _EPS)[:, None]
    same = d < 1e-12
    if np.any(same):  # coincident centres: a fixed, index-dependent direction
        angle = 2.399963 * i[same]
        normal[same] = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    w_i = np.where(pinned[i], 0.0, 1.0)
    w_j = np.where(pinned[j], 0.0, 1.0)
    total = w_i + w_j
    share_i = np.where(total > 0, w_i / np.maximum(total, _EPS), 0.5)
    push = normal * (2.0 * radius_m + CONTACT_MARGIN_M - d)[:, None]
    delta_i = _sum_by_index(i, push * share_i[:, None], n)
    delta_j = _sum_by_index(j, push * (1.0 - share_i)[:, None], n)
    return pos + delta_i - delta_j, True


@functools.lru_cache(maxsize=8)
def _pair_indices(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Index arrays (i, j) of all pairs i < j among n."""
    i, j = np.triu_indices(n, 1)
    i.flags.writeable = False
    j.flags.writeable = False
    return i, j


def _push_out_of_circles(
    pos: np.ndarray, radius_m: float, circles: np.ndarray | None
) -> tuple[np.ndarray, bool]:
    if circles is None or len(circles) == 0 or len(pos) == 0:
        return pos, False
    diff = pos[:, None, :] - circles[None, :, :2]
    d = np.sqrt(np.sum(diff * diff, axis=-1))
    reach = circles[None, :, 2] + radius_m
    hit = d < reach + 0.5 * CONTACT_MARGIN_M
    if not np.any(hit):
        return pos, False
    normal = diff / np.maximum(d, _EPS)[..., None]
    normal[d < 1e-12] = (1.0, 0.0)
    push = np.where(hit, reach + CONTACT_MARGIN_M - d, 0.0)[..., None] * normal
    return pos + np.sum(push, axis=1), True


def _undo_crossings(
    pos: np.ndarray, prev: np.ndarray, segments: Segments, ped_idx: np.ndarray, seg_idx: np.ndarray
) -> np.ndarray:
    """Put back pedestrians whose straight move from ``prev`` to ``pos`` touches or crosses a segment."""
    if len(ped_idx) == 0:
        return pos
    crossed = _crossings(prev[ped_idx], pos[ped_idx], segments, seg_idx)
    if np.any(crossed):
        pos = pos.copy()
        back = np.unique(ped_idx[crossed])
        pos[back] = prev[back]
    return pos


def _crossings(p0: np.ndarray, p1: np.ndarray, segments: Segments, seg_idx: np.ndarray) -> np.ndarray:
    """(P,) True where the straight move p0[k] → p1[k] touches or crosses segment ``seg_idx[k]``."""
    a, ab = segments.start[seg_idx], segments.delta[seg_idx]
    move = p1 - p0
    d1 = _cross(ab, p0 - a)
    d2 = _cross(ab, p1 - a)
    d3 = _cross(move, a - p0)
    d4 = _cross(move, a + ab - p0)
    collinear = (d1 == 0.0) & (d2 == 0.0)
    return (d1 * d2 <= 0.0) & (d3 * d4 <= 0.0) & ~collinear


def _segment_gaps(p0: np.ndarray, p1: np.ndarray, segments: Segments, seg_idx: np.ndarray) -> np.ndarray:
    """(P,) distance between the stretch p0[k]–p1[k] and segment ``seg_idx[k]``, metres (0 if they cross)."""
    a, ab = segments.start[seg_idx], segments.delta[seg_idx]
    gaps = np.minimum(
        np.minimum(_point_to_segment(p0, a, ab), _point_to_segment(p1, a, ab)),
        np.minimum(_point_to_segment(a, p0, p1 - p0), _point_to_segment(a + ab, p0, p1 - p0)),
    )
    gaps[_crossings(p0, p1, segments, seg_idx)] = 0.0
    return gaps


def _point_to_segment(p: np.ndarray, a: np.ndarray, ab: np.ndarray) -> np.ndarray:
    """(P,) distance from points p to segments a → a + ab, all (P, 2)."""
    ap = p - a
    len2 = np.maximum(ab[:, 0] ** 2 + ab[:, 1] ** 2, 1e-18)
    t = np.clip((ap[:, 0] * ab[:, 0] + ap[:, 1] * ab[:, 1]) / len2, 0.0, 1.0)
    return np.hypot(ap[:, 0] - t * ab[:, 0], ap[:, 1] - t * ab[:, 1])


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]


def _sum_by_index(idx: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Sum (P, 2) ``values`` into n rows by ``idx``."""
    sum_x = np.bincount(idx, weights=values[:, 0], minlength=n)
    sum_y = np.bincount(idx, weights=values[:, 1], minlength=n)
    return np.stack([sum_x, sum_y], axis=1).astype(np.float64)  # bincount of nothing is int64
