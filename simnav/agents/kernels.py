"""Numba kernels of the crowd update: social forces, integration and the non-overlap projection over flat arrays.

Written with numpy, one crowd step of 10 people made a few hundred small array operations (closest points, masks,
index sums), ~1 ms of per-call overhead for a few microseconds of arithmetic. These kernels loop over the same
data and do the same floating-point operations in the same order as the array formulation in
:mod:`simnav.agents.social_force` (kept there as the reference and tested against it), so forces and positions
are identical to the bit. The one operation done outside is ``exp``: numpy's vectorised ``exp`` and libm's (which
compiled code calls) differ in the last bit for a few per cent of arguments, and the crowd's dynamics carry such
differences up to metres within a minute, so :func:`exponents` lists the arguments and the caller takes
``np.exp`` of them.

* :func:`exponents`, then :func:`social_force_kernel`: driving term, pedestrian and round-obstacle repulsion, wall
  repulsion with the merging of nearby wall points and the look-ahead steering.
* :func:`integrate_kernel`: the semi-implicit Euler step with the speed cap.
* :func:`resolve_overlaps_kernel`: undo wall crossings, push out of walls, separate pedestrians, push out of
  circles, in the sweeps of :func:`simnav.agents.social_force.resolve_overlaps_pairs`.

All positions are world-frame metres, velocities m/s, forces m/s². ``@njit(cache=True)``: compiled on first use,
then loaded from ``__pycache__``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_EPS = 1e-9
CONTACT_MARGIN_M = 1e-3  # clearance beyond touching, metres (social_force.CONTACT_MARGIN_M)


@njit(cache=True)
def _ellipse(rx: float, ry: float, sx: float, sy: float) -> tuple[float, float, float, float]:
    """(b, |r|, |r − s|, |r| + |r − s|) of the elliptical potential, for the offset r and the partner's step s."""
    ux, uy = rx - sx, ry - sy
    n1 = max(math.sqrt(rx * rx + ry * ry), _EPS)
    n2 = max(math.sqrt(ux * ux + uy * uy), _EPS)
    s2 = sx * sx + sy * sy
    total = n1 + n2
    return max(0.5 * math.sqrt(max(total * total - s2, 0.0)), _EPS), n1, n2, total


@njit(cache=True)
def _elliptical(rx: float, ry: float, sx: float, sy: float, v0: float, sigma: float,
                exp_b: float) -> tuple[float, float]:
    """``−∇V(b)`` for the offset r from a partner taking the step s (metres): (fx, fy) m/s².

    ``exp_b`` is ``exp(−b/σ)``, computed outside (see :func:`exponents`).
    """
    b, n1, n2, total = _ellipse(rx, ry, sx, sy)
    scale = v0 / sigma * exp_b * total / (4.0 * b)
    return scale * (rx / n1 + (rx - sx) / n2), scale * (ry / n1 + (ry - sy) / n2)


@njit(cache=True)
def _view_weight(ex: float, ey: float, fx: float, fy: float, cos_half_fov: float, out_w: float) -> float:
    """1 when the source of the repulsion f lies within the field of view about e, else ``out_w``."""
    toward = -(ex * fx + ey * fy)
    norm = math.sqrt(fx * fx + fy * fy)
    return 1.0 if toward >= norm * cos_half_fov else out_w


@njit(cache=True)
def _offset(px: float, py: float, start: np.ndarray, delta: np.ndarray, inv_len2: np.ndarray, s: int,
            far_m: float = np.inf) -> tuple[float, float, float]:
    """Vector from the closest point of segment s to p, and its length (metres).

    The length is ``hypot`` (as numpy's), or, beyond ``1.01·far_m``, the cheaper ``sqrt(dx² + dy²)``, which
    differs by an ulp at most: on the same side of any threshold up to ``far_m``.
    """
    ax, ay, abx, aby = start[s, 0], start[s, 1], delta[s, 0], delta[s, 1]
    t = ((px - ax) * abx + (py - ay) * aby) * inv_len2[s]
    t = min(max(t, 0.0), 1.0)
    dx, dy = px - (ax + t * abx), py - (ay + t * aby)
    q = dx * dx + dy * dy
    if q > (1.01 * far_m) ** 2:
        return dx, dy, math.sqrt(q)
    return dx, dy, math.hypot(dx, dy)


@njit(cache=True)
def _point_to_segment(px: float, py: float, ax: float, ay: float, abx: float, aby: float) -> float:
    """Distance from p to the segment a → a + ab, metres."""
    apx, apy = px - ax, py - ay
    len2 = max(abx * abx + aby * aby, 1e-18)
    t = min(max((apx * abx + apy * aby) / len2, 0.0), 1.0)
    return math.hypot(apx - t * abx, apy - t * aby)


@njit(cache=True)
def _crosses(p0x: float, p0y: float, p1x: float, p1y: float, ax: float, ay: float, abx: float,
             aby: float) -> bool:
    """Whether the straight move p0 → p1 touches or crosses the segment a → a + ab."""
    mx, my = p1x - p0x, p1y - p0y
    d1 = abx * (p0y - ay) - aby * (p0x - ax)
    d2 = abx * (p1y - ay) - aby * (p1x - ax)
    d3 = mx * (ay - p0y) - my * (ax - p0x)
    bx, by = ax + abx, ay + aby
    d4 = mx * (by - p0y) - my * (bx - p0x)
    collinear = d1 == 0.0 and d2 == 0.0
    return d1 * d2 <= 0.0 and d3 * d4 <= 0.0 and not collinear


@njit(cache=True)
def _pedestrian_forces(pos: np.ndarray, vel: np.ndarray, dirs: np.ndarray, p: np.ndarray,
                       exps: np.ndarray) -> np.ndarray:
    """(N, 2) weighted elliptical repulsion between pedestrians, summed over partners in index order."""
    n = pos.shape[0]
    out = np.zeros((n, 2))
    if n < 2:
        return out
    v0, sigma, step_t, cos_fov, out_w = p[0], p[1], p[7], p[5], p[6]
    for i in range(n):
        for j in range(n):
            if j == i:
                continue
            fx, fy = _elliptical(pos[i, 0] - pos[j, 0], pos[i, 1] - pos[j, 1], vel[j, 0] * step_t,
                                 vel[j, 1] * step_t, v0, sigma, exps[i * n + j])
            w = _view_weight(dirs[i, 0], dirs[i, 1], fx, fy, cos_fov, out_w)
            out[i, 0] += fx * w
            out[i, 1] += fy * w
    return out


@njit(cache=True)
def _circle_forces(pos: np.ndarray, dirs: np.ndarray, circles: np.ndarray, circle_vel: np.ndarray,
                   p: np.ndarray, exps: np.ndarray) -> np.ndarray:
    """(N, 2) weighted repulsion of round obstacles, distances from their rims, with the steering around them."""
    n, c = pos.shape[0], circles.shape[0]
    out = np.zeros((n, 2))
    v0, sigma, step_t, cos_fov, out_w, steering = p[0], p[1], p[7], p[5], p[6], p[12]
    for i in range(n):
        ex, ey = dirs[i, 0], dirs[i, 1]
        for k in range(c):
            rx, ry = pos[i, 0] - circles[k, 0], pos[i, 1] - circles[k, 1]
            dist = max(math.sqrt(rx * rx + ry * ry), _EPS)
            scale = max(dist - circles[k, 2], 1e-3) / dist
            fx, fy = _elliptical(rx * scale, ry * scale, circle_vel[k, 0] * step_t, circle_vel[k, 1] * step_t,
                                 v0, sigma, exps[n * n + i * c + k])
            w = _view_weight(ex, ey, fx, fy, cos_fov, out_w)
            fx, fy = fx * w, fy * w
            if steering > 0:
                fx, fy = _steer(fx, fy, rx, ry, ex, ey, steering)
            out[i, 0] += fx
            out[i, 1] += fy
    return out


@njit(cache=True)
def _steer(fx: float, fy: float, rx: float, ry: float, ex: float, ey: float, fraction: float) -> tuple[float, float]:
    """f with ``fraction`` of its part against e turned sideways (the side of r across e, else the right)."""
    against = min(fx * ex + fy * ey, 0.0) * fraction
    along = rx * ex + ry * ey
    ax, ay = rx - along * ex, ry - along * ey
    norm = math.sqrt(ax * ax + ay * ay)
    if norm > 0.01:
        sx, sy = ax / max(norm, 1e-12), ay / max(norm, 1e-12)
    else:
        sx, sy = ey, -ex
    return fx - against * ex - against * sx, fy - against * ey - against * sy


@njit(cache=True)
def _wall_forces(pos: np.ndarray, dirs: np.ndarray, start: np.ndarray, delta: np.ndarray, inv_len2: np.ndarray,
                 ped_idx: np.ndarray, seg_idx: np.ndarray, p: np.ndarray, steer: bool, exps: np.ndarray) -> np.ndarray:
    """(N, 2) wall repulsion from the nearest point of each obstacle, steering only where the way is clear."""
    n, m = pos.shape[0], ped_idx.shape[0]
    u0_r, radius, near_m, cos_merge, look = p[13], p[8], p[14], p[10], p[11]
    far_m = max(near_m, look + radius)  # pairs beyond are neither near nor on the look-ahead stretch
    # offsets of every candidate pair; the near ones push
    dist = np.empty(m)
    nx = np.empty(m)
    ny = np.empty(m)
    near = np.zeros(m, dtype=np.bool_)
    for k in range(m):
        dx, dy, d = _offset(pos[ped_idx[k], 0], pos[ped_idx[k], 1], start, delta, inv_len2, seg_idx[k], far_m)
        dist[k] = d
        if d < near_m:
            near[k] = True
            dist[k] = max(d, _EPS)
            nx[k], ny[k] = dx / dist[k], dy / dist[k]
    kept = _nearest_per_direction(ped_idx, dist, nx, ny, near, n, cos_merge)
    # kept points push, summed in pair order
    out = np.zeros((n, 2))
    for k in range(m):
        if kept[k]:
            mag = u0_r * exps[exps.shape[0] - m + k]
            out[ped_idx[k], 0] += nx[k] * mag
            out[ped_idx[k], 1] += ny[k] * mag
    if not steer:
        return out
    # where no segment comes within a radius of the look-ahead stretch, drop the part against e
    blocked = np.zeros(n, dtype=np.bool_)
    for k in range(m):
        i, s = ped_idx[k], seg_idx[k]
        if blocked[i] or dist[k] > look + radius:  # pairs beyond look + radius cannot come near the stretch
            continue
        blocked[i] = _gap(pos[i, 0], pos[i, 1], dirs[i, 0], dirs[i, 1], look, start, delta, s) < radius
    for i in range(n):
        along = out[i, 0] * dirs[i, 0] + out[i, 1] * dirs[i, 1]
        if not blocked[i] and along < 0.0:
            out[i, 0] -= along * dirs[i, 0]
            out[i, 1] -= along * dirs[i, 1]
    return out


@njit(cache=True)
def _gap(px: float, py: float, ex: float, ey: float, look: float, start: np.ndarray, delta: np.ndarray,
         s: int) -> float:
    """Distance between the stretch p → p + look·e and segment s, metres (0 where they cross)."""
    qx, qy = px + look * ex, py + look * ey
    mx, my = qx - px, qy - py
    ax, ay, abx, aby = start[s, 0], start[s, 1], delta[s, 0], delta[s, 1]
    if _crosses(px, py, qx, qy, ax, ay, abx, aby):
        return 0.0
    return min(min(_point_to_segment(px, py, ax, ay, abx, aby), _point_to_segment(qx, qy, ax, ay, abx, aby)),
               min(_point_to_segment(ax, ay, px, py, mx, my),
                   _point_to_segment(ax + abx, ay + aby, px, py, mx, my)))


@njit(cache=True)
def _nearest_per_direction(ped: np.ndarray, dist: np.ndarray, nx: np.ndarray, ny: np.ndarray, near: np.ndarray,
                           n: int, cos_merge: float) -> np.ndarray:
    """(P,) True for the near points no closer near point of the same pedestrian sees within the merge angle.

    Closer means a smaller distance, or the same distance and an earlier pair (a stable sort by distance).
    """
    kept = np.zeros(ped.shape[0], dtype=np.bool_)
    # the near pairs grouped by pedestrian, in pair order within a group
    idx = np.nonzero(near)[0]
    ptr = np.zeros(n + 1, dtype=np.int64)
    for k in idx:
        ptr[ped[k] + 1] += 1
    ptr = np.cumsum(ptr)
    fill = ptr[:-1].copy()
    grouped = np.empty(idx.shape[0], dtype=np.int64)
    for k in idx:
        grouped[fill[ped[k]]] = k
        fill[ped[k]] += 1
    # a point is kept unless a closer one of its group lies within the merge angle
    for i in range(n):
        group = grouped[ptr[i]:ptr[i + 1]]
        for k in group:
            kept[k] = True
            for j in group:
                closer = dist[j] < dist[k] or (dist[j] == dist[k] and j < k)
                if closer and nx[k] * nx[j] + ny[k] * ny[j] > cos_merge:
                    kept[k] = False
                    break
    return kept


@njit(cache=True)
def social_force_kernel(pos: np.ndarray, vel: np.ndarray, dirs: np.ndarray, speeds: np.ndarray,
                        start: np.ndarray, delta: np.ndarray, inv_len2: np.ndarray, ped_idx: np.ndarray,
                        seg_idx: np.ndarray, circles: np.ndarray, circle_vel: np.ndarray, has_circles: bool,
                        p: np.ndarray, steer: bool, exps: np.ndarray) -> np.ndarray:
    """Total social-force acceleration (N, 2), m/s².

    Args:
        pos, vel, dirs: (N, 2) positions (m), velocities (m/s), unit desired directions. speeds: (N,) m/s.
        start, delta, inv_len2: (M, 2), (M, 2), (M,) prepared segments (:class:`~.social_force.Segments`).
        ped_idx, seg_idx: (P,) int64 candidate (pedestrian, segment) pairs.
        circles, circle_vel: (C, 3) ``[x, y, radius]`` (m) and (C, 2) m/s; ``has_circles`` False adds nothing.
        p: float64 parameters from :func:`simnav.agents.social_force.kernel_params`.
        steer: apply the look-ahead steering of walls.
        exps: the exponentials of the arguments of :func:`exponents`.
    """
    n = pos.shape[0]
    tau = p[4]
    acc = np.empty((n, 2))
    # driving term, then pedestrians, round obstacles and walls, added in that order
    for i in range(n):
        acc[i, 0] = (speeds[i] * dirs[i, 0] - vel[i, 0]) / tau
        acc[i, 1] = (speeds[i] * dirs[i, 1] - vel[i, 1]) / tau
    acc += _pedestrian_forces(pos, vel, dirs, p, exps)
    if has_circles:
        acc += _circle_forces(pos, dirs, circles, circle_vel, p, exps)
    if ped_idx.shape[0] > 0:
        acc += _wall_forces(pos, dirs, start, delta, inv_len2, ped_idx, seg_idx, p, steer, exps)
    return acc


@njit(cache=True)
def _push_out_of_walls(pos: np.ndarray, radius: float, start: np.ndarray, delta: np.ndarray,
                       inv_len2: np.ndarray, ped_idx: np.ndarray, seg_idx: np.ndarray) -> np.ndarray:
    """Push centres (in place) to ``radius + margin`` from every segment closer than ``radius + margin/2``.

    Returns the (N,) mask of pedestrians in contact with a wall.
    """
    n, m = pos.shape[0], ped_idx.shape[0]
    contact = np.zeros(n, dtype=np.bool_)
    target = radius + CONTACT_MARGIN_M
    push = np.zeros((n, 2))
    for _ in range(4):
        if m == 0:
            break
        push[:] = 0.0
        any_hit = False
        for k in range(m):
            i, s = ped_idx[k], seg_idx[k]
            dx, dy, d = _offset(pos[i, 0], pos[i, 1], start, delta, inv_len2, s, target + 0.5 * CONTACT_MARGIN_M)
            if d < target + 0.5 * CONTACT_MARGIN_M:
                contact[i] = True
            if not d < radius + 0.5 * CONTACT_MARGIN_M:
                continue
            any_hit = True
            if d < 1e-12:  # on the segment: its left normal
                tx, ty = delta[s, 0], delta[s, 1]
                length = max(math.sqrt(tx * tx + ty * ty), _EPS)
                ux, uy = -ty / length, tx / length
            else:
                ux, uy = dx / max(d, _EPS), dy / max(d, _EPS)
            push[i, 0] += ux * (target - d)
            push[i, 1] += uy * (target - d)
        if not any_hit:
            break
        pos += push
    return contact


@njit(cache=True)
def _separate_pedestrians(pos: np.ndarray, radius: float, pinned: np.ndarray) -> bool:
    """Move overlapping pairs apart (in place) to ``2·radius + margin``; a pinned one does not move."""
    n = pos.shape[0]
    if n < 2:
        return False
    delta_i = np.zeros((n, 2))
    delta_j = np.zeros((n, 2))
    any_hit = False
    for i in range(n):
        for j in range(i + 1, n):
            dx, dy = pos[i, 0] - pos[j, 0], pos[i, 1] - pos[j, 1]
            d = math.hypot(dx, dy)
            if not d < 2.0 * radius + 0.5 * CONTACT_MARGIN_M:
                continue
            any_hit = True
            if d < 1e-12:  # coincident centres: a fixed, index-dependent direction
                angle = 2.399963 * i
                ux, uy = math.cos(angle), math.sin(angle)
            else:
                ux, uy = dx / max(d, _EPS), dy / max(d, _EPS)
            w_i = 0.0 if pinned[i] else 1.0
            w_j = 0.0 if pinned[j] else 1.0
            total = w_i + w_j
            share_i = w_i / max(total, _EPS) if total > 0 else 0.5
            depth = 2.0 * radius + CONTACT_MARGIN_M - d
            px, py = ux * depth, uy * depth
            delta_i[i, 0] += px * share_i
            delta_i[i, 1] += py * share_i
            delta_j[j, 0] += px * (1.0 - share_i)
            delta_j[j, 1] += py * (1.0 - share_i)
    if any_hit:
        for i in range(n):
            pos[i, 0] = pos[i, 0] + delta_i[i, 0] - delta_j[i, 0]
            pos[i, 1] = pos[i, 1] + delta_i[i, 1] - delta_j[i, 1]
    return any_hit


@njit(cache=True)
def _push_out_of_circles(pos: np.ndarray, radius: float, circles: np.ndarray) -> bool:
    """Push centres (in place) out of the round obstacles ``[x, y, radius]`` to their rim + margin."""
    n, c = pos.shape[0], circles.shape[0]
    if c == 0 or n == 0:
        return False
    push = np.zeros((n, 2))
    any_hit = False
    for i in range(n):
        for k in range(c):
            dx, dy = pos[i, 0] - circles[k, 0], pos[i, 1] - circles[k, 1]
            d = math.sqrt(dx * dx + dy * dy)
            reach = circles[k, 2] + radius
            if not d < reach + 0.5 * CONTACT_MARGIN_M:
                continue
            any_hit = True
            ux, uy = (1.0, 0.0) if d < 1e-12 else (dx / max(d, _EPS), dy / max(d, _EPS))
            push[i, 0] += (reach + CONTACT_MARGIN_M - d) * ux
            push[i, 1] += (reach + CONTACT_MARGIN_M - d) * uy
    if any_hit:
        pos += push
    return any_hit


@njit(cache=True)
def _undo_crossings(pos: np.ndarray, prev: np.ndarray, start: np.ndarray, delta: np.ndarray,
                    ped_idx: np.ndarray, seg_idx: np.ndarray, pick: np.ndarray) -> bool:
    """Put back (in place) pedestrians whose move from ``prev`` touches or crosses a picked segment."""
    n = pos.shape[0]
    back = np.zeros(n, dtype=np.bool_)
    any_back = False
    for k in range(ped_idx.shape[0]):
        if not pick[k]:
            continue
        i, s = ped_idx[k], seg_idx[k]
        if _crosses(prev[i, 0], prev[i, 1], pos[i, 0], pos[i, 1], start[s, 0], start[s, 1], delta[s, 0],
                    delta[s, 1]):
            back[i] = True
            any_back = True
    for i in range(n):
        if back[i]:
            pos[i, 0], pos[i, 1] = prev[i, 0], prev[i, 1]
    return any_back


@njit(cache=True)
def resolve_overlaps_kernel(positions: np.ndarray, radius: float, start: np.ndarray, delta: np.ndarray,
                            inv_len2: np.ndarray, ped_idx: np.ndarray, seg_idx: np.ndarray, circles: np.ndarray,
                            iterations: int, prev: np.ndarray, has_prev: bool, check_crossing: np.ndarray,
                            guard: bool, slack_m: float) -> np.ndarray:
    """:func:`simnav.agents.social_force.resolve_overlaps_pairs` on flat arrays: (N, 2) corrected positions.

    Args:
        positions: (N, 2) centres, metres. radius: body radius, metres.
        start, delta, inv_len2: prepared segments. ped_idx, seg_idx: (P,) candidate pairs.
        circles: (C, 3) immovable round obstacles ``[x, y, radius]``, metres.
        iterations: maximum number of sweeps.
        prev: (N, 2) positions before the move (used when ``has_prev``).
        check_crossing: (P,) pairs whose segment may not be crossed (used when ``guard``).
        slack_m: reach beyond the radius and the move within which segments are kept.
    """
    n = positions.shape[0]
    pos = positions.copy()
    moved = positions.copy()
    step = np.zeros(n)
    if has_prev:
        for i in range(n):
            dx, dy = pos[i, 0] - prev[i, 0], pos[i, 1] - prev[i, 1]
            step[i] = math.sqrt(dx * dx + dy * dy)
    reach = radius + slack_m + (step.max() if n else 0.0)
    # the segments near enough to matter, with their distances
    m = ped_idx.shape[0]
    near = np.zeros(m, dtype=np.bool_)
    dist = np.zeros(m)
    for k in range(m):
        dist[k] = _offset(pos[ped_idx[k], 0], pos[ped_idx[k], 1], start, delta, inv_len2, seg_idx[k], reach)[2]
        near[k] = dist[k] < reach
    near_ped, near_seg, near_dist = ped_idx[near], seg_idx[near], dist[near]
    guarded = np.zeros(near_ped.shape[0], dtype=np.bool_)
    if has_prev and guard:
        guarded = check_crossing[near]
        # a segment crossed on the way from prev lies within the length of that way of its end
        first = guarded & (near_dist <= step[near_ped] + _EPS)
        _undo_crossings(pos, prev, start, delta, near_ped, near_seg, first)
    # sweeps of pedestrian separation and circle push-outs until nothing moves; walls go last
    contact = _push_out_of_walls(pos, radius, start, delta, inv_len2, near_ped, near_seg)
    for _ in range(max(iterations, 1)):
        moved_peds = _separate_pedestrians(pos, radius, contact)
        moved_circles = _push_out_of_circles(pos, radius, circles)
        if not (moved_peds or moved_circles):
            break
        contact = _push_out_of_walls(pos, radius, start, delta, inv_len2, near_ped, near_seg)
    if has_prev and guard:
        # pushes combined across a wall (e.g. squeezed by a door leaf): walls win
        way = np.empty(n)
        for i in range(n):
            ax, ay = pos[i, 0] - prev[i, 0], pos[i, 1] - prev[i, 1]
            bx, by = pos[i, 0] - moved[i, 0], pos[i, 1] - moved[i, 1]
            way[i] = math.sqrt(ax * ax + ay * ay) + math.sqrt(bx * bx + by * by)
        last = guarded & (near_dist <= way[near_ped] + _EPS)
        if _undo_crossings(pos, prev, start, delta, near_ped, near_seg, last):
            _push_out_of_walls(pos, radius, start, delta, inv_len2, near_ped, near_seg)
    return pos


@njit(cache=True)
def exponents(pos: np.ndarray, vel: np.ndarray, start: np.ndarray, delta: np.ndarray, inv_len2: np.ndarray,
              ped_idx: np.ndarray, seg_idx: np.ndarray, circles: np.ndarray, circle_vel: np.ndarray,
              p: np.ndarray) -> np.ndarray:
    """The arguments of every ``exp`` in :func:`social_force_kernel`, flat (N·N + N·C + P,).

    ``−b/σ`` of the pedestrian pairs (i, j) at ``i·N + j`` and of the pedestrian-circle pairs (i, k) at
    ``N·N + i·C + k``, then ``−d/R`` of the wall pairs (0 where not needed). numpy's vectorised ``exp`` and
    libm's differ in the last bit for a few per cent of arguments, so the caller takes ``np.exp`` of these, as
    the numpy formulation does, and the dynamics stay bit-identical to it.
    """
    n, c, m = pos.shape[0], circles.shape[0], ped_idx.shape[0]
    sigma, r_m, step_t, near_m = p[1], p[3], p[7], p[14]
    out = np.zeros(n * n + n * c + m)
    # pedestrian pairs, pedestrian-circle pairs (from the rim), wall pairs
    for i in range(n):
        for j in range(n):
            if j != i:
                b = _ellipse(pos[i, 0] - pos[j, 0], pos[i, 1] - pos[j, 1], vel[j, 0] * step_t,
                             vel[j, 1] * step_t)[0]
                out[i * n + j] = -b / sigma
        for k in range(c):
            rx, ry = pos[i, 0] - circles[k, 0], pos[i, 1] - circles[k, 1]
            dist = max(math.sqrt(rx * rx + ry * ry), _EPS)
            scale = max(dist - circles[k, 2], 1e-3) / dist
            b = _ellipse(rx * scale, ry * scale, circle_vel[k, 0] * step_t, circle_vel[k, 1] * step_t)[0]
            out[n * n + i * c + k] = -b / sigma
    for k in range(m):
        d = _offset(pos[ped_idx[k], 0], pos[ped_idx[k], 1], start, delta, inv_len2, seg_idx[k], near_m)[2]
        if d < near_m:
            out[n * n + n * c + k] = -max(d, _EPS) / r_m
    return out


@njit(cache=True)
def integrate_kernel(pos: np.ndarray, vel: np.ndarray, acc: np.ndarray, speeds: np.ndarray, dt_s: float,
                     max_speed_factor: float) -> tuple[np.ndarray, np.ndarray]:
    """Semi-implicit Euler step with ``|v| ≤ max_speed_factor·v⁰``: new (N, 2) positions (m) and velocities (m/s).

    Args:
        pos, vel, acc: (N, 2) metres, m/s, m/s². speeds: (N,) desired speeds v⁰, m/s. dt_s: seconds.
    """
    n = pos.shape[0]
    new_pos = np.empty((n, 2))
    new_vel = np.empty((n, 2))
    for i in range(n):
        vx, vy = vel[i, 0] + acc[i, 0] * dt_s, vel[i, 1] + acc[i, 1] * dt_s
        speed = math.sqrt(vx * vx + vy * vy)
        scale = min(speed, max_speed_factor * speeds[i]) / max(speed, _EPS)
        new_vel[i, 0], new_vel[i, 1] = vx * scale, vy * scale
        new_pos[i, 0], new_pos[i, 1] = pos[i, 0] + new_vel[i, 0] * dt_s, pos[i, 1] + new_vel[i, 1] * dt_s
    return new_pos, new_vel
