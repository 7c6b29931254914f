"""Numba kernels of the crowd update: social forces, integration and the non-overlap projection over flat arrays.

Written with numpy, one crowd step of 10 people made a few hundred small array operations (closest points, masks,
index sums), ~1 ms of per-call overhead for a few microseconds of arithmetic. These kernels loop over the same
data and do the same floating-point operations in the same order as the array formulation in
:mod:`simnav.agents.social_force` (kept there as the reference and tested against it), so forces and positions
are identical to the bit. The one operation the entry points of the reference leave out is ``exp``: numpy's
vectorised ``exp`` and libm's (which compiled code calls) differ in the last bit for a few per cent of arguments,
so :func:`exponents` lists the arguments and :func:`simnav.agents.social_force.social_force_pairs` takes
``np.exp`` of them. The crowd's own step takes them, and the headings of the velocities, with libm inside one
call: one step lies within rounding of the reference (the dynamics carry such differences up to metres within a
minute; the same seed still gives the same crowd). Where only a comparison needs a ``hypot``, a cheaper
``sqrt(dx² + dy²)`` decides unless it lies within rounding of the threshold.

* :func:`exponents`, then :func:`social_force_kernel`: driving term, pedestrian and round-obstacle repulsion, wall
  repulsion with the merging of nearby wall points and the look-ahead steering.
* :func:`integrate_kernel`: the semi-implicit Euler step with the speed cap.
* :func:`resolve_overlaps_kernel`: undo wall crossings, push out of walls, separate pedestrians, push out of
  circles, in the sweeps of :func:`simnav.agents.social_force.resolve_overlaps_pairs`.
* The step of :class:`simnav.agents.crowd.Crowd` in two calls, around what the random generator does:
  :func:`crowd_plan_events` (pauses, waypoints; new goals and pauses are drawn in Python), then
  :func:`crowd_move`: :func:`crowd_prepare` (desired directions, candidate walls, the ``exp`` arguments),
  :func:`crowd_walk` (forces, Euler step, projection) and :func:`crowd_react` (yaws, face-offs, stuck
  pedestrians). They live here with the functions they call: a cached kernel is not recompiled when a function it
  calls in another file changes.

All positions are world-frame metres, velocities m/s, forces m/s². ``@njit(cache=True)``: compiled on first use,
then loaded from ``__pycache__``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_EPS = 1e-9
CONTACT_MARGIN_M = 1e-3  # clearance beyond touching, metres (social_force.CONTACT_MARGIN_M)
PUSH_SLACK_M = 0.25  # while nobody has moved farther in a projection, only walls this close to contact can push


@njit(cache=True, error_model="numpy")
def _ellipse(rx: float, ry: float, sx: float, sy: float, ell: np.ndarray, k: int) -> None:
    """(b, |r|, |r − s|, |r| + |r − s|) of the elliptical potential, for the offset r and the partner's step s,
    into column k of ``ell`` (4, K)."""
    ux, uy = rx - sx, ry - sy
    n1 = max(math.sqrt(rx * rx + ry * ry), _EPS)
    n2 = max(math.sqrt(ux * ux + uy * uy), _EPS)
    s2 = sx * sx + sy * sy
    total = n1 + n2
    ell[0, k], ell[1, k], ell[2, k], ell[3, k] = max(0.5 * math.sqrt(max(total * total - s2, 0.0)), _EPS), n1, n2, total


@njit(cache=True, error_model="numpy")
def _elliptical(rx: float, ry: float, sx: float, sy: float, v0: float, sigma: float, exp_b: float, ell: np.ndarray,
                k: int) -> tuple[float, float]:
    """``−∇V(b)`` for the offset r from a partner taking the step s (metres): (fx, fy) m/s².

    Column k of ``ell`` holds (b, |r|, |r − s|, |r| + |r − s|) from :func:`_ellipse` and ``exp_b`` is
    ``exp(−b/σ)``, both computed by :func:`exponents`.
    """
    b, n1, n2, total = ell[0, k], ell[1, k], ell[2, k], ell[3, k]
    scale = v0 / sigma * exp_b * total / (4.0 * b)
    return scale * (rx / n1 + (rx - sx) / n2), scale * (ry / n1 + (ry - sy) / n2)


@njit(cache=True, error_model="numpy")
def _view_weight(ex: float, ey: float, fx: float, fy: float, cos_half_fov: float, out_w: float) -> float:
    """1 when the source of the repulsion f lies within the field of view about e, else ``out_w``."""
    toward = -(ex * fx + ey * fy)
    norm = math.sqrt(fx * fx + fy * fy)
    return 1.0 if toward >= norm * cos_half_fov else out_w


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def _closer_than(px: float, py: float, ax: float, ay: float, abx: float, aby: float, limit: float) -> bool:
    """Whether the distance from p to the segment a → a + ab, ``hypot`` of the offset, is below ``limit`` (metres).

    ``hypot`` only near the limit: elsewhere ``dx² + dy²``, within a few ulps of its square, decides.
    """
    apx, apy = px - ax, py - ay
    len2 = max(abx * abx + aby * aby, 1e-18)
    t = min(max((apx * abx + apy * aby) / len2, 0.0), 1.0)
    dx, dy = apx - t * abx, apy - t * aby
    q = dx * dx + dy * dy
    if q > (1.01 * limit) ** 2:
        return False
    if q < (0.99 * limit) ** 2:
        return True
    return math.hypot(dx, dy) < limit


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def _pedestrian_forces(pos: np.ndarray, vel: np.ndarray, dirs: np.ndarray, p: np.ndarray, exps: np.ndarray,
                       ell: np.ndarray) -> np.ndarray:
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
                                 vel[j, 1] * step_t, v0, sigma, exps[i * n + j], ell, i * n + j)
            w = _view_weight(dirs[i, 0], dirs[i, 1], fx, fy, cos_fov, out_w)
            out[i, 0] += fx * w
            out[i, 1] += fy * w
    return out


@njit(cache=True, error_model="numpy")
def _circle_forces(pos: np.ndarray, dirs: np.ndarray, circles: np.ndarray, circle_vel: np.ndarray,
                   p: np.ndarray, exps: np.ndarray, ell: np.ndarray) -> np.ndarray:
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
                                 v0, sigma, exps[n * n + i * c + k], ell, n * n + i * c + k)
            w = _view_weight(ex, ey, fx, fy, cos_fov, out_w)
            fx, fy = fx * w, fy * w
            if steering > 0:
                fx, fy = _steer(fx, fy, rx, ry, ex, ey, steering)
            out[i, 0] += fx
            out[i, 1] += fy
    return out


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def _wall_forces(pos: np.ndarray, dirs: np.ndarray, start: np.ndarray, delta: np.ndarray, ped_idx: np.ndarray,
                 seg_idx: np.ndarray, offsets: np.ndarray, p: np.ndarray, steer: bool, exps: np.ndarray) -> np.ndarray:
    """(N, 2) wall repulsion from the nearest point of each obstacle, steering only where the way is clear."""
    n, m = pos.shape[0], ped_idx.shape[0]
    u0_r, radius, near_m, cos_merge, look = p[13], p[8], p[14], p[10], p[11]
    # the near pairs push, along their unit offsets
    dist = np.empty(m)
    nx = np.empty(m)
    ny = np.empty(m)
    near = np.zeros(m, dtype=np.bool_)
    for k in range(m):
        d = offsets[k, 2]
        dist[k] = d
        if d < near_m:
            near[k] = True
            dist[k] = max(d, _EPS)
            nx[k], ny[k] = offsets[k, 0] / dist[k], offsets[k, 1] / dist[k]
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
    # where no segment comes within a radius of the look-ahead stretch, drop the part against e (only those whose
    # wall force has such a part need the look ahead)
    along = np.empty(n)
    blocked = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        along[i] = out[i, 0] * dirs[i, 0] + out[i, 1] * dirs[i, 1]
    for k in range(m):
        i = ped_idx[k]
        if along[i] >= 0.0 or blocked[i] or dist[k] > look + radius:  # pairs beyond cannot come near the stretch
            continue
        blocked[i] = _near_stretch(pos[i, 0], pos[i, 1], dirs[i, 0], dirs[i, 1], look, start, delta, seg_idx[k], radius)
    for i in range(n):
        if not blocked[i] and along[i] < 0.0:
            out[i, 0] -= along[i] * dirs[i, 0]
            out[i, 1] -= along[i] * dirs[i, 1]
    return out


@njit(cache=True, error_model="numpy")
def _near_stretch(px: float, py: float, ex: float, ey: float, look: float, start: np.ndarray, delta: np.ndarray,
                  s: int, radius: float) -> bool:
    """Whether segment s comes within ``radius`` of the stretch p → p + look·e (crossing it included), metres."""
    ax, ay, abx, aby = start[s, 0], start[s, 1], delta[s, 0], delta[s, 1]
    # the stretch lies within look/2 of its middle: a segment clearly farther than look/2 + radius is not near
    if not _closer_than(px + 0.5 * look * ex, py + 0.5 * look * ey, ax, ay, abx, aby, 1.01 * (0.5 * look + radius)):
        return False
    qx, qy = px + look * ex, py + look * ey
    mx, my = qx - px, qy - py
    return (_crosses(px, py, qx, qy, ax, ay, abx, aby) or _closer_than(px, py, ax, ay, abx, aby, radius)
            or _closer_than(qx, qy, ax, ay, abx, aby, radius) or _closer_than(ax, ay, px, py, mx, my, radius)
            or _closer_than(ax + abx, ay + aby, px, py, mx, my, radius))


@njit(cache=True, error_model="numpy")
def _nearest_per_direction(ped: np.ndarray, dist: np.ndarray, nx: np.ndarray, ny: np.ndarray, near: np.ndarray,
                           n: int, cos_merge: float) -> np.ndarray:
    """(P,) True for the near points no closer near point of the same pedestrian sees within the merge angle.

    Closer means a smaller distance, or the same distance and an earlier pair (a stable sort by distance).
    """
    kept = np.zeros(ped.shape[0], dtype=np.bool_)
    # the near pairs grouped by pedestrian, in pair order within a group
    ptr = np.zeros(n + 1, dtype=np.int64)
    for k in range(ped.shape[0]):
        if near[k]:
            ptr[ped[k] + 1] += 1
    for i in range(n):
        ptr[i + 1] += ptr[i]
    fill = ptr[:n].copy()
    grouped = np.empty(ptr[n], dtype=np.int64)
    for k in range(ped.shape[0]):
        if near[k]:
            grouped[fill[ped[k]]] = k
            fill[ped[k]] += 1
    for i in range(n):
        _merge_group(grouped[ptr[i]:ptr[i + 1]], dist, nx, ny, cos_merge, kept)
    return kept


@njit(cache=True, error_model="numpy")
def _merge_group(group: np.ndarray, dist: np.ndarray, nx: np.ndarray, ny: np.ndarray, cos_merge: float,
                 kept: np.ndarray) -> None:
    """Mark (in ``kept``) the points of one pedestrian's group (pair indices, ascending) that no closer point of the
    group sees within the merge angle.

    The group is ordered by distance first (a stable insertion sort: ties keep the pair order), so the closer
    points of each are those before it, and its check stops at the first of them that sees it.
    """
    g = group.shape[0]
    order = group.copy()
    for a in range(1, g):
        k, d, b = order[a], dist[order[a]], a
        while b > 0 and dist[order[b - 1]] > d:
            order[b] = order[b - 1]
            b -= 1
        order[b] = k
    for a in range(g):
        k = order[a]
        kx, ky = nx[k], ny[k]
        kept[k] = True
        for b in range(a):
            j = order[b]
            if kx * nx[j] + ky * ny[j] > cos_merge:
                kept[k] = False
                break


@njit(cache=True, error_model="numpy")
def social_force_kernel(pos: np.ndarray, vel: np.ndarray, dirs: np.ndarray, speeds: np.ndarray,
                        start: np.ndarray, delta: np.ndarray, ped_idx: np.ndarray, seg_idx: np.ndarray,
                        offsets: np.ndarray, circles: np.ndarray, circle_vel: np.ndarray, has_circles: bool,
                        p: np.ndarray, steer: bool, exps: np.ndarray, ell: np.ndarray) -> np.ndarray:
    """Total social-force acceleration (N, 2), m/s².

    Args:
        pos, vel, dirs: (N, 2) positions (m), velocities (m/s), unit desired directions. speeds: (N,) m/s.
        start, delta: (M, 2) prepared segments (:class:`~.social_force.Segments`).
        ped_idx, seg_idx: (P,) int64 candidate (pedestrian, segment) pairs.
        offsets: (P, 3) their :func:`wall_offsets`.
        circles, circle_vel: (C, 3) ``[x, y, radius]`` (m) and (C, 2) m/s; ``has_circles`` False adds nothing.
        p: float64 parameters from :func:`simnav.agents.social_force.kernel_params`.
        steer: apply the look-ahead steering of walls.
        exps, ell: the exponentials of the arguments, and the ellipses, from :func:`exponents`.
    """
    n = pos.shape[0]
    tau = p[4]
    acc = np.empty((n, 2))
    # driving term, then pedestrians, round obstacles and walls, added in that order
    for i in range(n):
        acc[i, 0] = (speeds[i] * dirs[i, 0] - vel[i, 0]) / tau
        acc[i, 1] = (speeds[i] * dirs[i, 1] - vel[i, 1]) / tau
    acc += _pedestrian_forces(pos, vel, dirs, p, exps, ell)
    if has_circles:
        acc += _circle_forces(pos, dirs, circles, circle_vel, p, exps, ell)
    if ped_idx.shape[0] > 0:
        acc += _wall_forces(pos, dirs, start, delta, ped_idx, seg_idx, offsets, p, steer, exps)
    return acc


@njit(cache=True, error_model="numpy")
def _push_out_of_walls(pos: np.ndarray, radius: float, walls: tuple, near: tuple, ref: np.ndarray) -> np.ndarray:
    """Push centres (in place) to ``radius + margin`` from every segment closer than ``radius + margin/2``.

    ``walls`` = (start, delta, inv_len2); ``near`` = (pedestrian and segment indices (P,), their distances from
    the centres at ``ref`` (N, 2), the indices of the pairs at most PUSH_SLACK_M farther than contact there, all
    the indices): a pair farther than contact by more than its centre has moved since is skipped. Returns the (N,)
    mask of pedestrians in contact with a wall.
    """
    start, delta, inv_len2 = walls
    ped_idx, seg_idx, ref_dist, close, every = near
    n, m = pos.shape[0], ped_idx.shape[0]
    contact = np.zeros(n, dtype=np.bool_)
    target = radius + CONTACT_MARGIN_M
    push = np.zeros((n, 2))
    shift = np.empty(n)
    for _ in range(4):
        if m == 0:
            break
        push[:] = 0.0
        any_hit = False
        for i in range(n):
            dx, dy = pos[i, 0] - ref[i, 0], pos[i, 1] - ref[i, 1]
            shift[i] = math.sqrt(dx * dx + dy * dy)
        for k in close if shift.max() <= PUSH_SLACK_M else every:
            i, s = ped_idx[k], seg_idx[k]
            if ref_dist[k] - shift[i] > target + CONTACT_MARGIN_M:  # out of reach (half a margin spare for rounding)
                continue
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


@njit(cache=True, error_model="numpy")
def _separate_pedestrians(pos: np.ndarray, radius: float, pinned: np.ndarray) -> bool:
    """Move overlapping pairs apart (in place) to ``2·radius + margin``; a pinned one does not move."""
    n = pos.shape[0]
    if n < 2:
        return False
    delta_i = np.zeros((n, 2))
    delta_j = np.zeros((n, 2))
    any_hit = False
    far = (1.01 * (2.0 * radius + 0.5 * CONTACT_MARGIN_M)) ** 2  # farther apart (squared): not in contact
    for i in range(n):
        for j in range(i + 1, n):
            dx, dy = pos[i, 0] - pos[j, 0], pos[i, 1] - pos[j, 1]
            if dx * dx + dy * dy <= far:
                any_hit |= _separate_pair(pos, i, j, radius, pinned, delta_i, delta_j)
    if any_hit:
        for i in range(n):
            pos[i, 0] = pos[i, 0] + delta_i[i, 0] - delta_j[i, 0]
            pos[i, 1] = pos[i, 1] + delta_i[i, 1] - delta_j[i, 1]
    return any_hit


@njit(cache=True, error_model="numpy")
def _separate_pair(pos: np.ndarray, i: int, j: int, radius: float, pinned: np.ndarray, delta_i: np.ndarray,
                   delta_j: np.ndarray) -> bool:
    """Add the push apart of pedestrians i and j, if in contact, to ``delta_i[i]`` and ``delta_j[j]``."""
    dx, dy = pos[i, 0] - pos[j, 0], pos[i, 1] - pos[j, 1]
    d = math.hypot(dx, dy)
    if not d < 2.0 * radius + 0.5 * CONTACT_MARGIN_M:
        return False
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
    return True


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def _undo_crossings(pos: np.ndarray, prev: np.ndarray, walls: tuple, ped_idx: np.ndarray, seg_idx: np.ndarray,
                    guarded: np.ndarray, ref: np.ndarray, dist: np.ndarray, way: np.ndarray) -> bool:
    """Put back (in place) pedestrians whose move from ``prev`` touches or crosses a guarded segment.

    Only the guarded pairs whose distance from ``ref`` (:func:`_near_pairs`) is within the pedestrian's ``way``
    (N,) (+ 1 nm) can be crossed: a segment crossed on the way from prev lies within the length of that way of its
    end. ``walls`` = (start, delta, inv_len2).
    """
    start, delta = walls[0], walls[1]
    n = pos.shape[0]
    back = np.zeros(n, dtype=np.bool_)
    any_back = False
    for k in range(ped_idx.shape[0]):
        i, s = ped_idx[k], seg_idx[k]
        if not (guarded[k] and _below(dist[k], way[i] + _EPS, False, ref[i, 0], ref[i, 1], walls, s)):
            continue
        if _crosses(prev[i, 0], prev[i, 1], pos[i, 0], pos[i, 1], start[s, 0], start[s, 1], delta[s, 0],
                    delta[s, 1]):
            back[i] = True
            any_back = True
    for i in range(n):
        if back[i]:
            pos[i, 0], pos[i, 1] = prev[i, 0], prev[i, 1]
    return any_back


@njit(cache=True, error_model="numpy")
def _near_pairs(pos: np.ndarray, walls: tuple, ped_idx: np.ndarray, seg_idx: np.ndarray, check_crossing: np.ndarray,
                guard: bool, reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pairs closer than ``reach`` (metres), in pair order: pedestrian and segment indices, distances (the
    cheap ``sqrt`` of :func:`_offset`: compare them with :func:`_below`), and whether the segment may not be
    crossed (``check_crossing`` when ``guard``, else False). ``walls`` = (start, delta, inv_len2)."""
    start, delta, inv_len2 = walls
    m = ped_idx.shape[0]
    ped, seg, dist, guarded = np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m), np.zeros(m, np.bool_)
    count = 0
    for k in range(m):
        i, s = ped_idx[k], seg_idx[k]
        d = _offset(pos[i, 0], pos[i, 1], start, delta, inv_len2, s, 0.0)[2]
        if _below(d, reach, True, pos[i, 0], pos[i, 1], walls, s):
            ped[count], seg[count], dist[count] = i, s, d
            guarded[count] = guard and check_crossing[k]
            count += 1
    return ped[:count], seg[:count], dist[:count], guarded[:count]


@njit(cache=True, error_model="numpy")
def _below(d: float, limit: float, strict: bool, px: float, py: float, walls: tuple, s: int) -> bool:
    """Whether the distance from p to segment s (``hypot`` of the offset, as :func:`_offset` gives it near) is below
    ``limit`` (> 0), or at most it when not ``strict`` (metres); ``d`` is its ``sqrt`` estimate, within a few ulps:
    it decides unless that close to the limit."""
    if d < limit * (1.0 - 1e-12):
        return True
    if d > limit * (1.0 + 1e-12):
        return False
    exact = _offset(px, py, walls[0], walls[1], walls[2], s)[2]
    return exact < limit if strict else exact <= limit


@njit(cache=True, error_model="numpy")
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
    step = np.zeros(n)
    if has_prev:
        for i in range(n):
            dx, dy = pos[i, 0] - prev[i, 0], pos[i, 1] - prev[i, 1]
            step[i] = math.sqrt(dx * dx + dy * dy)
    reach = radius + slack_m + (step.max() if n else 0.0)
    guard = has_prev and guard
    walls = (start, delta, inv_len2)
    ped, seg, dist, guarded = _near_pairs(pos, walls, ped_idx, seg_idx, check_crossing, guard, reach)
    if guard:
        _undo_crossings(pos, prev, walls, ped, seg, guarded, positions, dist, step)
    # sweeps of pedestrian separation and circle push-outs until nothing moves; walls go last
    near = (ped, seg, dist, _within(dist, radius + 2.0 * CONTACT_MARGIN_M + PUSH_SLACK_M), np.arange(ped.shape[0]))
    contact = _push_out_of_walls(pos, radius, walls, near, positions)
    for _ in range(max(iterations, 1)):
        moved_peds = _separate_pedestrians(pos, radius, contact)
        moved_circles = _push_out_of_circles(pos, radius, circles)
        if not (moved_peds or moved_circles):
            break
        contact = _push_out_of_walls(pos, radius, walls, near, positions)
    if guard:
        # pushes combined across a wall (e.g. squeezed by a door leaf): walls win
        way = np.empty(n)
        for i in range(n):
            ax, ay = pos[i, 0] - prev[i, 0], pos[i, 1] - prev[i, 1]
            bx, by = pos[i, 0] - positions[i, 0], pos[i, 1] - positions[i, 1]
            way[i] = math.sqrt(ax * ax + ay * ay) + math.sqrt(bx * bx + by * by)
        if _undo_crossings(pos, prev, walls, ped, seg, guarded, positions, dist, way):
            _push_out_of_walls(pos, radius, walls, near, positions)
    return pos


@njit(cache=True, error_model="numpy")
def wall_far_m(p: np.ndarray) -> float:
    """Distance beyond which a wall pair neither pushes nor reaches the look-ahead stretch, metres."""
    return max(p[14], p[11] + p[8])


@njit(cache=True, error_model="numpy")
def wall_offsets(pos: np.ndarray, start: np.ndarray, delta: np.ndarray, inv_len2: np.ndarray, ped_idx: np.ndarray,
                 seg_idx: np.ndarray, far_m: float) -> np.ndarray:
    """(P, 3) vectors from the closest point of segment ``seg_idx[k]`` to ``pos[ped_idx[k]]`` and their lengths
    (metres; exact up to ``far_m``, see :func:`_offset`)."""
    m = ped_idx.shape[0]
    out = np.empty((m, 3))
    for k in range(m):
        i = ped_idx[k]
        out[k, 0], out[k, 1], out[k, 2] = _offset(pos[i, 0], pos[i, 1], start, delta, inv_len2, seg_idx[k], far_m)
    return out


@njit(cache=True, error_model="numpy")
def exponents(pos: np.ndarray, vel: np.ndarray, offsets: np.ndarray, circles: np.ndarray, circle_vel: np.ndarray,
              p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The arguments of every ``exp`` in :func:`social_force_kernel`, flat (N·N + N·C + P,), and the ellipses.

    ``−b/σ`` of the pedestrian pairs (i, j) at ``i·N + j`` and of the pedestrian-circle pairs (i, k) at
    ``N·N + i·C + k``, then ``−d/R`` of the wall pairs (``offsets``, (P, 3) from :func:`wall_offsets` with
    :func:`wall_far_m`; 0 where not needed). numpy's vectorised ``exp`` and libm's differ in the last bit for a
    few per cent of arguments, so a caller that must match the numpy formulation to the bit takes ``np.exp`` of
    these, as it does. The ellipses, (4, N·N + N·C), are (b, |r|, |r − s|, |r| + |r − s|) of the
    pedestrian and pedestrian-circle pairs at the same indices (:func:`_ellipse`), for the forces.
    """
    n, c, m = pos.shape[0], circles.shape[0], offsets.shape[0]
    sigma, r_m, step_t, near_m = p[1], p[3], p[7], p[14]
    out = np.zeros(n * n + n * c + m)
    ell = np.empty((4, n * n + n * c))
    xs, ys, sx, sy = np.empty(n), np.empty(n), np.empty(n), np.empty(n)  # the pairs' loop reads them contiguously
    for j in range(n):
        xs[j], ys[j], sx[j], sy[j] = pos[j, 0], pos[j, 1], vel[j, 0] * step_t, vel[j, 1] * step_t
    # pedestrian pairs (the pair (i, i) too, without a branch: its argument is reset, its ellipse unused),
    # pedestrian-circle pairs (from the rim), wall pairs
    for i in range(n):
        for j in range(n):
            _ellipse(xs[i] - xs[j], ys[i] - ys[j], sx[j], sy[j], ell, i * n + j)
            out[i * n + j] = -ell[0, i * n + j] / sigma
        out[i * n + i] = 0.0
        for k in range(c):
            rx, ry = pos[i, 0] - circles[k, 0], pos[i, 1] - circles[k, 1]
            dist = max(math.sqrt(rx * rx + ry * ry), _EPS)
            scale = max(dist - circles[k, 2], 1e-3) / dist
            row = n * n + i * c + k
            _ellipse(rx * scale, ry * scale, circle_vel[k, 0] * step_t, circle_vel[k, 1] * step_t, ell, row)
            out[row] = -ell[0, row] / sigma
    for k in range(m):
        d = offsets[k, 2]
        if d < near_m:
            out[n * n + n * c + k] = -max(d, _EPS) / r_m
    return out, ell


@njit(cache=True, error_model="numpy")
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


# ------------------------------------------------------------------------------------------- the crowd step
@njit(cache=True, error_model="numpy")
def grid_pairs(points: np.ndarray, origin: np.ndarray, cell_m: float, nx: int, ny: int, ptr: np.ndarray,
               idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`~simnav.agents.crowd.SegmentGrid.pairs` on the grid's flat cell lists ``idx[ptr[c]:ptr[c + 1]]``
    (cell c = ix·ny + iy): (P,) point and (P,) segment indices, each point's in its cell's order."""
    n = points.shape[0]
    cell = np.full(n, -1, dtype=np.int64)
    total = 0
    # each point's cell (-1 outside the grid), then its segments in cell-list order
    for i in range(n):
        ix = np.int64(math.floor((points[i, 0] - origin[0]) / cell_m))
        iy = np.int64(math.floor((points[i, 1] - origin[1]) / cell_m))
        if 0 <= ix < nx and 0 <= iy < ny:
            cell[i] = ix * ny + iy
            total += ptr[cell[i] + 1] - ptr[cell[i]]
    ped = np.empty(total, dtype=np.int64)
    seg = np.empty(total, dtype=np.int64)
    k = 0
    for i in range(n):
        if cell[i] < 0:
            continue
        for j in range(ptr[cell[i]], ptr[cell[i] + 1]):
            ped[k], seg[k] = i, idx[j]
            k += 1
    return ped, seg


@njit(cache=True, error_model="numpy")
def grid_lists(origin: np.ndarray, cell_m: float, nx: int, ny: int, start: np.ndarray, delta: np.ndarray,
               inv_len2: np.ndarray, reach_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The cell lists of a grid (origin (2,), cells ``cell_m`` wide, metres): per cell c = ix·ny + iy, the prepared
    segments no farther than ``reach_m`` from its centre, ascending; cell pointers (nx·ny + 1,) and the lists."""
    ptr = np.zeros(nx * ny + 1, dtype=np.int64)
    for c in range(nx * ny):
        ptr[c + 1] = ptr[c] + _cell_list(origin, cell_m, ny, c, start, delta, inv_len2, reach_m, ptr[:0])
    idx = np.empty(ptr[-1], dtype=np.int64)
    for c in range(nx * ny):
        _cell_list(origin, cell_m, ny, c, start, delta, inv_len2, reach_m, idx[ptr[c]:ptr[c + 1]])
    return ptr, idx


@njit(cache=True, error_model="numpy")
def _cell_list(origin: np.ndarray, cell_m: float, ny: int, c: int, start: np.ndarray, delta: np.ndarray,
               inv_len2: np.ndarray, reach_m: float, out: np.ndarray) -> int:
    """How many segments lie within ``reach_m`` of the centre of cell c (see :func:`grid_lists`); they are written
    to ``out`` when it has room for them."""
    cx, cy = origin[0] + (c // ny + 0.5) * cell_m, origin[1] + (c % ny + 0.5) * cell_m
    count = 0
    for s in range(start.shape[0]):
        if _offset(cx, cy, start, delta, inv_len2, s, reach_m)[2] <= reach_m:
            if count < out.shape[0]:
                out[count] = s
            count += 1
    return count


@njit(cache=True, error_model="numpy")
def crowd_plan_events(pause_s: np.ndarray, arrived: np.ndarray, dt_s: float, plans: tuple, circles: np.ndarray,
                      limits: tuple[float, float, float, float], walls: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Run the pauses (N,) of those who arrived down by ``dt_s`` seconds (in place).

    Returns the indices of those whose pause is over (due for a new goal), and, when there are none, the events of
    :func:`crowd_advance` (else none: the caller plans, then calls :func:`crowd_advance`).
    """
    n = pause_s.shape[0]
    due = np.empty(n, dtype=np.int64)
    count = 0
    for i in range(n):
        if arrived[i]:
            pause_s[i] -= dt_s
            if pause_s[i] <= 0.0:
                due[count] = i
                count += 1
    if count:
        return due[:count], np.empty((0, 2), dtype=np.int64)
    return due[:0], crowd_advance(arrived, plans, circles, limits, walls)


@njit(cache=True, error_model="numpy")
def crowd_advance(arrived: np.ndarray, plans: tuple, circles: np.ndarray,
                  limits: tuple[float, float, float, float], walls: tuple) -> np.ndarray:
    """Move the walking pedestrians within reach of their targets on along their paths (in place).

    ``plans`` = (pos (N, 2), targets (N, 2), paths (N, K, 2) (metres), waypoint indices (N,), index of the goal
    in each path (N,)); ``limits`` = (reach of the goal, of the other waypoints, pedestrian radius, occupied
    margin), metres; ``walls`` = (start (M, 2), delta (M, 2)) of the static wall segments, metres. Within reach:
    closer than that, plus :func:`_occupied_extra` of the (C, 3) ``circles`` (a robot standing on the target:
    nobody walks onto someone else's spot, so without it, people whose next roadmap node a robot stands on would
    circle it for ever) when the waypoint after the target is in sight (or the target is the goal): else a
    person in a doorway, with a robot on the node outside it, headed for the node after it straight into the
    door jamb and stayed pressed there. A pedestrian takes the next waypoints until one is out of reach (then
    without the extra), or arrives.

    Returns:
        (E, 2) events [pedestrian, kind], ascending: kind 0, it arrived (and needs a pause); kind 1, the distance
        of its new target lies within the rounding of the reach (the caller measures it with ``np.linalg.norm``,
        as the reference does, and walks on from there).
    """
    pos, target, paths, wp, last_wp = plans
    goal_m, waypoint_m, radius_m, margin_m = limits
    reached = _reached(pos, target, paths, wp, last_wp, arrived, circles, limits, walls)
    events = np.empty((reached.shape[0], 2), dtype=np.int64)
    count = 0
    for i in reached:
        while True:
            if wp[i] == last_wp[i]:
                arrived[i] = True
                events[count, 0], events[count, 1] = i, 0
                count += 1
                break
            wp[i] += 1
            target[i, 0], target[i, 1] = paths[i, wp[i], 0], paths[i, wp[i], 1]
            reach2 = (goal_m if wp[i] == last_wp[i] else waypoint_m) ** 2
            dx, dy = target[i, 0] - pos[i, 0], target[i, 1] - pos[i, 1]
            if dx * dx + dy * dy >= reach2 * (1.0 + 1e-12):
                break
            if dx * dx + dy * dy > reach2 * (1.0 - 1e-12):
                events[count, 0], events[count, 1] = i, 1
                count += 1
                break
    return events[:count]


@njit(cache=True, error_model="numpy")
def _reached(pos: np.ndarray, target: np.ndarray, paths: np.ndarray, wp: np.ndarray, last_wp: np.ndarray,
             arrived: np.ndarray, circles: np.ndarray, limits: tuple[float, float, float, float],
             walls: tuple) -> np.ndarray:
    """Indices of the walking pedestrians within reach of their targets (see :func:`crowd_advance`)."""
    goal_m, waypoint_m, radius_m, margin_m = limits
    n = pos.shape[0]
    extra = _occupied_extra(target, circles, radius_m, margin_m) if circles.shape[0] else np.zeros(n)
    out = np.empty(n, dtype=np.int64)
    count = 0
    for i in range(n):
        if arrived[i]:
            continue
        dx, dy = target[i, 0] - pos[i, 0], target[i, 1] - pos[i, 1]
        last = wp[i] == last_wp[i]
        dist, reach = math.sqrt(dx * dx + dy * dy), goal_m if last else waypoint_m
        if dist >= reach + extra[i]:
            continue
        if dist >= reach and not last:  # reached only thanks to a robot on the target
            nxt = paths[i, wp[i] + 1]
            if not _in_sight(pos[i, 0], pos[i, 1], nxt[0], nxt[1], walls[0], walls[1]):
                continue
        out[count] = i
        count += 1
    return out[:count]


@njit(cache=True, error_model="numpy")
def _in_sight(px: float, py: float, qx: float, qy: float, start: np.ndarray, delta: np.ndarray) -> bool:
    """Whether the straight segment p → q touches none of the (M, 2) segments start → start + delta."""
    for s in range(start.shape[0]):
        if _crosses(px, py, qx, qy, start[s, 0], start[s, 1], delta[s, 0], delta[s, 1]):
            return False
    return True


@njit(cache=True, error_model="numpy")
def _occupied_extra(targets: np.ndarray, circles: np.ndarray, radius_m: float, margin_m: float) -> np.ndarray:
    """(N,) the largest ``circle radius + radius_m`` over the circles (C, 3) whose rim comes within ``margin_m``
    of the pedestrian's rim about its target (N, 2), else 0 (all metres)."""
    n = targets.shape[0]
    out = np.zeros(n)
    for i in range(n):
        best = -np.inf
        for k in range(circles.shape[0]):
            dx, dy = targets[i, 0] - circles[k, 0], targets[i, 1] - circles[k, 1]
            gap = math.sqrt(dx * dx + dy * dy) - circles[k, 2] - radius_m
            best = max(best, circles[k, 2] + radius_m if gap < margin_m else 0.0)
        out[i] = best
    return out


@njit(cache=True, error_model="numpy")
def crowd_prepare(pos: np.ndarray, vel: np.ndarray, dirs: np.ndarray, target: np.ndarray, yield_s: np.ndarray,
                  yield_dir: np.ndarray, speeds: np.ndarray, arrived: np.ndarray, yield_factor: float, grid: tuple,
                  walls: tuple, dyn: np.ndarray, circles: np.ndarray, circle_vel: np.ndarray, p: np.ndarray) -> tuple:
    """The crowd step up to the exponentials.

    Points ``dirs`` (N, 2) at the targets (in place; :func:`_desired_update`), writes the moving segments ``dyn``
    (D, 2, 2) into ``walls`` = (start, delta, inv_len2, number of static walls M), lists the candidate pairs (the
    ``grid`` of :func:`grid_pairs`, then every pedestrian with each moving segment) and their offsets, and the
    :func:`exponents` of the pairs that can push (within :func:`wall_far_m`).

    Returns:
        (N,) drive speeds (m/s), (P,) pedestrian and (P,) segment indices of the candidate pairs, (P, 3) their
        offsets (:func:`wall_offsets`; the lengths as ``sqrt(dx² + dy²)``, within an ulp of numpy's ``hypot``
        and cheaper), (F,) indices of the pairs that can push, the exponent arguments and the ellipses.
    """
    drive = _desired_update(dirs, target, pos, yield_s, yield_dir, speeds, arrived, yield_factor)
    start, delta, inv_len2, m = walls
    _set_segments(start, delta, inv_len2, m, dyn)
    ped, seg = _pairs(pos, grid, m, dyn.shape[0])
    offsets = wall_offsets(pos, start, delta, inv_len2, ped, seg, 0.0)  # lengths: sqrt(dx² + dy²), not hypot
    forced = _within(offsets[:, 2], wall_far_m(p))
    args, ell = exponents(pos, vel, _take_rows(offsets, forced), circles, circle_vel, p)
    return drive, ped, seg, offsets, forced, args, ell


@njit(cache=True, error_model="numpy")
def _desired_update(dirs: np.ndarray, target: np.ndarray, pos: np.ndarray, yield_s: np.ndarray,
                    yield_dir: np.ndarray, speeds: np.ndarray, arrived: np.ndarray, yield_factor: float) -> np.ndarray:
    """Point ``dirs`` (N, 2, in place) at the targets, or along ``yield_dir`` while yielding; (N,) drive speeds.

    A pedestrian within 1 µm of its target keeps its direction; one yielding walks at ``yield_factor`` of its
    speed, one that has arrived stands (0). Positions in metres, speeds in m/s.
    """
    n = pos.shape[0]
    out = np.empty(n)
    for i in range(n):
        dx, dy = target[i, 0] - pos[i, 0], target[i, 1] - pos[i, 1]
        dist = math.sqrt(dx * dx + dy * dy)
        if dist > 1e-6:
            dirs[i, 0], dirs[i, 1] = dx / dist, dy / dist
        speed = speeds[i]
        if yield_s[i] > 0.0:
            dirs[i, 0], dirs[i, 1] = yield_dir[i, 0], yield_dir[i, 1]
            speed = yield_factor * speeds[i]
        out[i] = 0.0 if arrived[i] else speed
    return out


@njit(cache=True, error_model="numpy")
def _set_segments(start: np.ndarray, delta: np.ndarray, inv_len2: np.ndarray, m: int, dyn: np.ndarray) -> None:
    """Write the (D, 2, 2) segments ``dyn`` (metres) after the first m prepared segments, as
    :class:`~simnav.agents.social_force.Segments` prepares them."""
    for d in range(dyn.shape[0]):
        k = m + d
        dx, dy = dyn[d, 1, 0] - dyn[d, 0, 0], dyn[d, 1, 1] - dyn[d, 0, 1]
        start[k, 0], start[k, 1] = dyn[d, 0, 0], dyn[d, 0, 1]
        delta[k, 0], delta[k, 1] = dx, dy
        inv_len2[k] = 1.0 / max(dx * dx + dy * dy, 1e-18)


@njit(cache=True, error_model="numpy")
def _pairs(points: np.ndarray, grid: tuple, m: int, d_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Candidate (point, segment) pairs, two (P,) arrays: the ``grid``'s (:func:`grid_pairs`), then every point with
    each of the ``d_count`` moving segments m, m + 1, ..."""
    ped, seg = grid_pairs(points, grid[0], grid[1], grid[2], grid[3], grid[4], grid[5])
    if d_count == 0:
        return ped, seg
    n, g = points.shape[0], ped.shape[0]
    all_ped, all_seg = np.empty(g + n * d_count, dtype=np.int64), np.empty(g + n * d_count, dtype=np.int64)
    for k in range(g):
        all_ped[k], all_seg[k] = ped[k], seg[k]
    for i in range(n):
        for d in range(d_count):
            all_ped[g + i * d_count + d], all_seg[g + i * d_count + d] = i, m + d
    return all_ped, all_seg


@njit(cache=True, error_model="numpy")
def _within(values: np.ndarray, limit: float) -> np.ndarray:
    """Indices (ascending) of the (P,) ``values`` at most ``limit``."""
    out = np.empty(values.shape[0], dtype=np.int64)
    count = 0
    for k in range(values.shape[0]):
        if values[k] <= limit:
            out[count] = k
            count += 1
    return out[:count]


@njit(cache=True, error_model="numpy")
def _take(values: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The entries ``idx`` (K,) of ``values`` (P,)."""
    out = np.empty(idx.shape[0], dtype=values.dtype)
    for r in range(idx.shape[0]):
        out[r] = values[idx[r]]
    return out


@njit(cache=True, error_model="numpy")
def _take_rows(values: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The rows ``idx`` (K,) of ``values`` (P, W)."""
    out = np.empty((idx.shape[0], values.shape[1]), dtype=values.dtype)
    for r in range(idx.shape[0]):
        for c in range(values.shape[1]):
            out[r, c] = values[idx[r], c]
    return out


@njit(cache=True, error_model="numpy")
def crowd_walk(pos: np.ndarray, vel: np.ndarray, dirs: np.ndarray, drive: np.ndarray, speeds: np.ndarray,
               walls: tuple, pairs: tuple, offsets: np.ndarray, forced: np.ndarray, circles: np.ndarray,
               circle_vel: np.ndarray, has_circles: bool, p: np.ndarray, steer: bool, exps: np.ndarray,
               ell: np.ndarray, dt_s: float, max_speed_factor: float, radius_m: float, sweeps: int, slack_m: float,
               reach: tuple) -> tuple:
    """The crowd step from the exponentials on (the arguments from :func:`crowd_prepare`).

    Forces, the Euler step, the projection (:func:`resolve_overlaps_kernel` with ``sweeps`` and ``slack_m``; the
    static walls, the first M of ``walls``, may not be crossed). The projection needs the walls within
    ``radius + slack + move`` of the moved centres, which lie within ``radius + slack + 2·(largest move)`` of the
    old ones. ``pairs`` = (pedestrian indices, segment indices) of the candidates; ``reach`` = (how far from the
    old centres they list all the walls, m; the largest move for which the ``grid`` of :func:`grid_pairs` does, m;
    that grid): the projection takes the candidates while they cover it, else the grid's around the old centres,
    or, beyond its move, around the new ones.

    Returns:
        The new (N, 2) positions (m) and velocities (m/s).
    """
    start, delta, inv_len2, m = walls
    near_reach_m, max_move_m, grid = reach
    ped, seg = pairs
    acc = social_force_kernel(pos, vel, dirs, drive, start, delta, _take(ped, forced), _take(seg, forced),
                              _take_rows(offsets, forced), circles, circle_vel, has_circles, p, steer, exps, ell)
    moved = integrate_kernel(pos, vel, acc, speeds, dt_s, max_speed_factor)[0]
    largest = _largest_step(pos, moved)
    cover_m = radius_m + slack_m + 2.0 * largest + 1e-9  # (1 nm: more than the rounding of the distances)
    if cover_m <= near_reach_m:
        kept = _within(offsets[:, 2], cover_m)
        ped, seg = _take(ped, kept), _take(seg, kept)
    else:
        ped, seg = _pairs(moved if largest > max_move_m else pos, grid, m, start.shape[0] - m)
    static = np.empty(seg.shape[0], dtype=np.bool_)
    for k in range(seg.shape[0]):
        static[k] = seg[k] < m
    resolved = resolve_overlaps_kernel(moved, radius_m, start, delta, inv_len2, ped, seg, circles, sweeps, pos, True,
                                       static, True, slack_m)
    new_vel = np.empty_like(pos)
    for i in range(pos.shape[0]):
        new_vel[i, 0], new_vel[i, 1] = (resolved[i, 0] - pos[i, 0]) / dt_s, (resolved[i, 1] - pos[i, 1]) / dt_s
    return resolved, new_vel


@njit(cache=True, error_model="numpy")
def crowd_move(motion: tuple, intent: tuple, watch: tuple, scene: tuple, p: np.ndarray, rules: tuple,
               time_s: float, dt_s: float) -> tuple:
    """The crowd step after the plans in one call: :func:`crowd_prepare`, the exponentials, :func:`crowd_walk`,
    the headings of the new velocities and :func:`crowd_react`.

    Args:
        motion: (positions (N, 2) m, velocities (N, 2) m/s, yaws (N,) rad), replaced by the step.
        intent: (desired directions (N, 2), targets (N, 2) m, yield times (N,) s, yield directions (N, 2), desired
            speeds (N,) m/s, arrived (N,) bool), changed in place.
        watch: (blocked times (N,) s, priorities (N,), progress anchors (N, 2) m, their times (N,) s and the
            targets (N, 2) m the anchors were set towards), changed in place.
        scene: (the near ``grid`` of :func:`grid_pairs`, ``walls`` = (start, delta, inv_len2, number of static
            walls M), ``reach`` of :func:`crowd_walk`, moving segments (D, 2, 2) m, circles (C, 3) m, their
            velocities (C, 2) m/s, whether there are circles).
        p: the force parameters (:func:`simnav.agents.social_force.kernel_params`).
        rules: (yield speed factor, steer, speed cap factor, radius m, projection sweeps, slack m, and the
            ``turning``, ``blocking`` and ``stuck`` rules of :func:`crowd_react`).
        time_s: the crowd's time after the step, s. dt_s: the step, s.

    Returns:
        New positions (N, 2) m, velocities (N, 2) m/s, yaws (N,) rad, yaw rates (N,) rad/s, and the (E, 2) events
        of :func:`crowd_react`.
    """
    pos, vel, yaw = motion
    dirs, target, yield_s, yield_dir, speeds, arrived = intent
    blocked_s, priority, anchor_xy, anchor_t, anchor_goal = watch
    grid, walls, reach, dyn, circles, circle_vel, has_circles = scene
    yield_factor, steer, max_speed_factor, radius_m, sweeps, slack_m, turning, blocking, stuck = rules
    # forces, the Euler step and the projection
    drive, ped, seg, offsets, forced, args, ell = crowd_prepare(pos, vel, dirs, target, yield_s, yield_dir, speeds,
                                                                arrived, yield_factor, grid, walls, dyn, circles,
                                                                circle_vel, p)
    new_pos, new_vel = crowd_walk(pos, vel, dirs, drive, speeds, walls, (ped, seg), offsets, forced, circles,
                                  circle_vel, has_circles, p, steer, np.exp(args), ell, dt_s, max_speed_factor,
                                  radius_m, sweeps, slack_m, reach)
    # headings of the new velocities, then yaws, face-offs and stuck pedestrians
    heading = np.empty(new_vel.shape[0])
    for i in range(new_vel.shape[0]):
        heading[i] = math.atan2(new_vel[i, 1], new_vel[i, 0])
    new_yaw, rate, events = crowd_react(new_pos, new_vel, heading, yaw, dirs, target, arrived, yield_s, blocked_s,
                                        priority, circles, radius_m, (anchor_xy, anchor_t, anchor_goal), time_s, dt_s,
                                        turning, blocking, stuck)
    return new_pos, new_vel, new_yaw, rate, events


@njit(cache=True, error_model="numpy")
def _largest_step(before: np.ndarray, after: np.ndarray) -> float:
    """The longest of the (N, 2) moves ``after − before``, metres (−inf for nobody)."""
    out = -np.inf
    for i in range(before.shape[0]):
        dx, dy = after[i, 0] - before[i, 0], after[i, 1] - before[i, 1]
        out = max(out, math.sqrt(dx * dx + dy * dy))
    return out


@njit(cache=True, error_model="numpy")
def crowd_react(pos: np.ndarray, vel: np.ndarray, heading: np.ndarray, yaw: np.ndarray, dirs: np.ndarray,
                target: np.ndarray, arrived: np.ndarray, yield_s: np.ndarray, blocked_s: np.ndarray,
                priority: np.ndarray, circles: np.ndarray, radius_m: float, anchors: tuple, time_s: float, dt_s: float,
                turning: tuple[float, float, float], blocking: tuple[float, float, float, float, float],
                stuck: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The crowd step after the move: :func:`_turn`, :func:`_blocking` and :func:`_stuck` with their rules
    (``turning``, ``blocking``, ``stuck``), the state arrays updated in place; ``anchors`` = (positions (N, 2) m,
    times (N,) s, targets (N, 2) m) of :func:`_stuck`.

    Returns:
        New yaws, yaw rates, and (E, 2) events [pedestrian, blocker]: those who step back with the one they step
        back from, then those stuck, with blocker −1.
    """
    new_yaw, rate = _turn(vel, heading, yaw, dt_s, turning)
    steps_back, blocker = _blocking(pos, vel, dirs, arrived, yield_s, blocked_s, priority, circles, radius_m, dt_s,
                                    blocking)
    stuck_idx = _stuck(pos, target, arrived, anchors[0], anchors[1], anchors[2], time_s, stuck)
    b = steps_back.shape[0]
    events = np.empty((b + stuck_idx.shape[0], 2), dtype=np.int64)
    for e in range(events.shape[0]):
        i = steps_back[e] if e < b else stuck_idx[e - b]
        events[e, 0], events[e, 1] = i, blocker[i] if e < b else -1
    return new_yaw, rate, events


@njit(cache=True, error_model="numpy")
def _wrap(angle_rad: float) -> float:
    """``angle_rad`` wrapped to [-π, π) as :func:`simnav.agents.crowd.wrap_angle` does."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True, error_model="numpy")
def _turn(vel: np.ndarray, heading: np.ndarray, yaw: np.ndarray, dt_s: float,
          turning: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Turn towards the (N,) headings of the (N, 2) velocities (m/s): new yaws (rad) and yaw rates (rad/s).

    ``turning`` = (time constant s, largest rate rad/s, speed m/s up to which nobody turns).
    """
    time_constant_s, max_rate, moving_m_s = turning
    n = yaw.shape[0]
    gain = min(1.0, dt_s / time_constant_s) / dt_s
    new_yaw, rate = np.empty(n), np.empty(n)
    for i in range(n):
        rate[i] = min(max(_wrap(heading[i] - yaw[i]) * gain, -max_rate), max_rate)
        if math.sqrt(vel[i, 0] * vel[i, 0] + vel[i, 1] * vel[i, 1]) <= moving_m_s:
            rate[i] = 0.0
        new_yaw[i] = _wrap(yaw[i] + rate[i] * dt_s)
    return new_yaw, rate


@njit(cache=True, error_model="numpy")
def _blocking(pos: np.ndarray, vel: np.ndarray, dirs: np.ndarray, arrived: np.ndarray, yield_s: np.ndarray,
              blocked_s: np.ndarray, priority: np.ndarray, circles: np.ndarray, radius_m: float, dt_s: float,
              blocking: tuple[float, float, float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Face-offs: who steps aside now (see :class:`simnav.agents.crowd.Crowd`).

    ``blocking`` = (distance m, cosine of the half-angle, speed m/s, yield after s, yield anyway after s). A
    pedestrian is blocked while slower than that speed with someone within the distance ahead (inside the
    half-angle about ``dirs``; for a circle, the distance between the rims plus twice ``radius_m``). It steps back
    after the first time if the closest one has a higher ``priority`` (circles: the highest), after the second
    anyway. Runs the yields (N,) down and counts the blocked times (N,), in place.

    Returns:
        The indices of those who step back, and (N,) the closest in each one's way (a pedestrian, or N + the
        index of a circle; 0 for nobody).
    """
    distance_m, cos_half_angle, slow_m_s, yield_after_s, force_after_s = blocking
    n, c = pos.shape[0], circles.shape[0]
    for i in range(n):
        yield_s[i] = max(yield_s[i] - dt_s, 0.0)
    if n == 0 or n + c < 2:
        return np.empty(0, dtype=np.int64), np.zeros(n, dtype=np.int64)
    others, reach = np.empty((n + c, 2)), np.full(n + c, distance_m)
    for i in range(n):
        others[i, 0], others[i, 1] = pos[i, 0], pos[i, 1]
    for k in range(c):
        others[n + k, 0], others[n + k, 1] = circles[k, 0], circles[k, 1]
        reach[n + k] = distance_m + circles[k, 2] - radius_m
    in_way, blocker = closest_in_way(pos, dirs, others, reach, cos_half_angle)
    out = np.empty(n, dtype=np.int64)
    count = 0
    for i in range(n):
        slow = math.sqrt(vel[i, 0] * vel[i, 0] + vel[i, 1] * vel[i, 1]) < slow_m_s
        blocked = slow and not arrived[i] and yield_s[i] <= 0.0 and in_way[i]
        blocked_s[i] = blocked_s[i] + dt_s if blocked else 0.0
        outranked = priority[i] < (priority[blocker[i]] if blocker[i] < n else np.inf)
        if blocked_s[i] >= yield_after_s and outranked or blocked_s[i] >= force_after_s:
            out[count] = i
            count += 1
    return out[:count], blocker


@njit(cache=True, error_model="numpy")
def closest_in_way(pos: np.ndarray, dirs: np.ndarray, others: np.ndarray, reach: np.ndarray,
                   cos_half_angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Who stands in each pedestrian's way: (N,) whether anyone does, and (N,) the index of the closest (else 0).

    Args:
        pos: (N, 2) pedestrian centres, metres. dirs: (N, 2) unit desired directions.
        others: (K, 2) centres of the N pedestrians, then of the round obstacles, metres.
        reach: (K,) how far ahead each of ``others`` counts as in the way, metres.
        cos_half_angle: cosine of the half-angle of the cone ahead.
    """
    n, k_count = pos.shape[0], others.shape[0]
    in_way = np.zeros(n, dtype=np.bool_)
    blocker = np.zeros(n, dtype=np.int64)
    for i in range(n):
        best = np.inf
        for k in range(k_count):
            rx, ry = others[k, 0] - pos[i, 0], others[k, 1] - pos[i, 1]
            if rx * rx + ry * ry >= 1.0201 * reach[k] * reach[k]:  # beyond 1.01·reach: out of reach
                continue
            dist = math.sqrt(rx * rx + ry * ry)
            if k == i:
                dist += 1e9
            if rx * dirs[i, 0] + ry * dirs[i, 1] >= dist * cos_half_angle and dist < reach[k]:
                in_way[i] = True
                if dist < best:
                    best, blocker[i] = dist, k
    return in_way, blocker


@njit(cache=True, error_model="numpy")
def _stuck(pos: np.ndarray, target: np.ndarray, arrived: np.ndarray, anchor_xy: np.ndarray, anchor_t: np.ndarray,
           anchor_goal: np.ndarray, time_s: float, stuck: tuple[float, float]) -> np.ndarray:
    """Indices of those who came less than ``stuck[0]`` metres closer to their target (N, 2) in ``stuck[1]`` seconds
    (walking to and fro in front of someone who does not give way is no progress).

    The anchors (N, 2), their times (N,) and the targets they were set towards (N, 2) move (in place) to whoever
    made that progress, has a new target or has arrived.
    """
    progress_m, time_limit_s = stuck
    n = pos.shape[0]
    out = np.empty(n, dtype=np.int64)
    count = 0
    for i in range(n):
        tx, ty = target[i, 0], target[i, 1]
        new_target = tx != anchor_goal[i, 0] or ty != anchor_goal[i, 1]
        closer = math.hypot(anchor_xy[i, 0] - tx, anchor_xy[i, 1] - ty) - math.hypot(pos[i, 0] - tx, pos[i, 1] - ty)
        if closer >= progress_m or new_target or arrived[i]:
            anchor_xy[i, 0], anchor_xy[i, 1] = pos[i, 0], pos[i, 1]
            anchor_goal[i, 0], anchor_goal[i, 1] = tx, ty
            anchor_t[i] = time_s
        if time_s - anchor_t[i] >= time_limit_s:
            out[count] = i
            count += 1
    return out[:count]
