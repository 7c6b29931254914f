"""How long the robot cannot touch anything: MuJoCo's collision detection can be skipped meanwhile.

Only the robot's geoms can make contacts (everything else is fixed to the world or a mocap body, and no two of
those may collide). While every geom the robot may collide with stays farther from the robot's vertical axis than
the robot's footprint radius plus the distance the base can have travelled, collision detection finds nothing, and
the physics steps are the same without it. The test is conservative: each geom is bounded on the floor plane (world
x/y) by a disc, a stadium or a rectangle that contains its projection, the robot by the disc of its footprint
radius about its axis.

Shape rows, world x/y, metres: ``[kind, a, b, c, d, e, f, margin]`` with DISC ``[cx, cy, r]``, STADIUM
``[x0, y0, x1, y1, r]`` (a segment grown by r), RECT ``[cx, cy, ux, uy, hu, hv]`` (unit axis u, half sizes along u
and its normal), NEAR (unbounded, e.g. a plane: never clear); ``margin`` is the geom's contact margin.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
from numba import njit

DISC, STADIUM, RECT, NEAR = 0.0, 1.0, 2.0, 3.0
SHAPE_FIELDS = 8
SPEED_FACTOR = 1.5  # over max(base speed, largest command): 1 but for rounding (equal servo gains), sqrt(2) at most
PAD_M = 0.02  # extra clearance on top of the geoms' margins
CELL_M = 0.05  # cells of the table of clearances from the fixed geoms
MAX_CELLS = 1_000_000
_PLANE, _HFIELD, _SPHERE, _CAPSULE, _CYLINDER, _BOX = 0, 1, 2, 3, 5, 6  # mjtGeom codes
_VERTICAL_TOL = 1e-9
_LOCAL_FIELDS = 17  # a mocap geom: position (3) and row-major orientation (9) in its body, sizes (3), rbound, margin


class ContactClearance:
    """For how many of the next physics steps the robot certainly touches nothing.

    Args:
        model: the compiled scene.
        robot_body: body id of the robot (its geoms are the only ones that may collide).
        max_speed_m_s: largest commanded forward speed of the base, m/s.

    Attributes:
        usable: False when the scene breaks the assumptions (a body other than the robot that physics moves,
            explicit contact pairs, colliding non-robot geoms, a base that is not planar); :meth:`clear_steps` then
            always answers 0.
    """

    def __init__(self, model: mujoco.MjModel, robot_body: int, max_speed_m_s: float) -> None:
        robot = np.flatnonzero(model.geom_bodyid == robot_body)
        others = _collidable_with(model, robot)
        self.usable = _scene_fits(model, robot_body, robot)
        mocap = model.body_mocapid[model.geom_bodyid[others]]
        fixed, moving = others[mocap < 0], others[mocap >= 0]
        # the robot: footprint radius plus margins, the speed bound and the step
        self._robot = np.array([_footprint_radius(model, robot) + float(model.geom_margin[robot].max(initial=0.0))
                                + PAD_M, max_speed_m_s * SPEED_FACTOR, SPEED_FACTOR, model.opt.timestep,
                                *model.body_pos[robot_body, :2]])
        # the fixed geoms: shape rows, and a table of clearances from them filled as the robot goes
        self._fixed = _shapes(model, fixed, *_static_poses(model, fixed))
        self._table_origin, self._table = _table(self._fixed)
        # the mocap geoms, grouped by body: the mocap ids, their geoms' rows and a radius bounding them
        self._mocap, self._spans, self._local, self._types, self._reach = _mocap_geoms(model, moving)

    def clear_steps(self, data: mujoco.MjData, steps: int, base_q: np.ndarray, base_v: np.ndarray) -> int:
        """How many of the next ``steps`` physics steps certainly make no contact, from the current state: the
        mocap bodies as posed now (and until then), the base's joints at ``base_q`` (x m, y m, yaw) moving at
        ``base_v`` (vx, vy m/s, yaw rate), world frame."""
        if not self.usable:
            return 0
        return _clear_steps(steps, base_q, base_v, self._robot, self._fixed, self._table_origin, self._table,
                            data.mocap_pos, data.mocap_quat, self._mocap, self._spans, self._local, self._types,
                            self._reach)


def _collidable_with(model: mujoco.MjModel, robot: np.ndarray) -> np.ndarray:
    """Ids of the geoms outside the robot's body that the contype/conaffinity filter lets touch a robot geom."""
    contype, conaffinity = model.geom_contype, model.geom_conaffinity
    robot_type = np.bitwise_or.reduce(contype[robot], initial=0)
    robot_affinity = np.bitwise_or.reduce(conaffinity[robot], initial=0)
    ok = ((contype & robot_affinity) != 0) | ((conaffinity & robot_type) != 0)
    ok[robot] = False
    return np.flatnonzero(ok)


def _scene_fits(model: mujoco.MjModel, robot_body: int, robot: np.ndarray) -> bool:
    """The robot is the only body that physics moves and has a planar base, every other body hangs from the
    world (fixed to it or a mocap body, posed by it alone), there are no explicit pairs, and no two geoms outside
    the robot's body may collide with each other."""
    if model.npair or robot.size == 0 or not _planar_base(model, robot_body):
        return False
    others = np.setdiff1d(np.arange(1, model.nbody), [robot_body])
    if np.any(model.body_parentid[others] != 0) or np.any(model.body_dofnum[others] != 0):
        return False
    rest = np.setdiff1d(np.arange(model.ngeom), robot)
    kinds = {(int(a), int(b)) for a, b in zip(model.geom_contype[rest], model.geom_conaffinity[rest], strict=True)}
    return not any((t1 & a2) or (t2 & a1) for t1, a1 in kinds for t2, a2 in kinds)


def _planar_base(model: mujoco.MjModel, robot_body: int) -> bool:
    """The robot body is an upright child of the world on slides along world x and y then a hinge about z through
    its origin: the slides alone move its origin, and its geoms turn about that axis."""
    joints = np.flatnonzero(model.jnt_bodyid == robot_body)
    kinds = [int(model.jnt_type[j]) for j in joints]
    slide, hinge = mujoco.mjtJoint.mjJNT_SLIDE, mujoco.mjtJoint.mjJNT_HINGE
    if model.body_parentid[robot_body] != 0 or kinds != [slide, slide, hinge]:
        return False
    axes_ok = np.array_equal(model.jnt_axis[joints], np.eye(3)) and not np.any(model.jnt_pos[joints[2]])
    return axes_ok and np.array_equal(model.body_quat[robot_body], [1.0, 0.0, 0.0, 0.0])


def _footprint_radius(model: mujoco.MjModel, robot: np.ndarray) -> float:
    """Largest horizontal distance of a robot geom point from the robot body's vertical axis, m (mesh vertices;
    other geoms by their bounding spheres)."""
    radius = 0.0
    for g, mat in zip(robot, _quat_mats(model.geom_quat[robot]), strict=True):
        pos, mesh = model.geom_pos[g], model.geom_dataid[g]
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH and mesh >= 0:
            adr, num = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
            pts = pos + model.mesh_vert[adr:adr + num].astype(float) @ mat.reshape(3, 3).T
            radius = max(radius, float(np.hypot(pts[:, 0], pts[:, 1]).max()))
        else:
            radius = max(radius, float(np.hypot(pos[0], pos[1]) + model.geom_rbound[g]))
    return radius


def _static_poses(model: mujoco.MjModel, geoms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(G, 3) world positions and (G, 9) row-major orientations of geoms fixed to the world (a kinematics pass on
    fresh data)."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    return data.geom_xpos[geoms].copy(), data.geom_xmat[geoms].copy()


def _quat_mats(quats: np.ndarray) -> np.ndarray:
    """(N, 9) row-major rotation matrices of (N, 4) unit quaternions (w, x, y, z)."""
    out = np.empty((len(quats), 9))
    for k, q in enumerate(quats):
        mujoco.mju_quat2Mat(out[k], np.asarray(q, dtype=float))
    return out


def _shapes(model: mujoco.MjModel, geoms: np.ndarray, xpos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
    """(G, SHAPE_FIELDS) floor-plane rows of the geoms at the (G, 3) positions and (G, 9) orientations."""
    out = np.empty((len(geoms), SHAPE_FIELDS))
    for k, g in enumerate(geoms):
        s0, s1, s2 = model.geom_size[g].tolist()
        _shape_row(int(model.geom_type[g]), s0, s1, s2, float(model.geom_rbound[g]), xpos[k], xmat[k], out, k)
        out[k, 7] = model.geom_margin[g]
    return out


def _table(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The origin (x, y, cell size) and the (NX, NY) table, all NaN (not computed yet), of the clearances from
    the fixed geoms over their extent plus 2 m, cells of CELL_M or more (at most MAX_CELLS cells)."""
    bounded = rows[rows[:, 0] != NEAR]
    if len(bounded) == 0:
        return np.array([0.0, 0.0, CELL_M]), np.full((0, 0), np.nan)
    xs, ys = bounded[:, [1, 3]], bounded[:, [2, 4]]  # centres, and a stadium's second end
    xs[bounded[:, 0] != STADIUM, 1] = xs[bounded[:, 0] != STADIUM, 0]
    ys[bounded[:, 0] != STADIUM, 1] = ys[bounded[:, 0] != STADIUM, 0]
    lo, hi = np.array([xs.min(), ys.min()]) - 2.0, np.array([xs.max(), ys.max()]) + 2.0
    cell = max(CELL_M, math.sqrt(float(np.prod(hi - lo)) / MAX_CELLS))
    shape = np.ceil((hi - lo) / cell).astype(int)
    return np.array([lo[0], lo[1], cell]), np.full(tuple(shape), np.nan)


def _mocap_geoms(model: mujoco.MjModel, geoms: np.ndarray) -> tuple[np.ndarray, ...]:
    """The mocap geoms grouped by body: (B,) mocap ids, (B + 1,) spans of each body's geoms, (M, _LOCAL_FIELDS)
    geoms in their bodies, (M,) geom types, (B,) radius about the body origin bounding its geoms plus margins."""
    geoms = geoms[np.argsort(model.geom_bodyid[geoms], kind="stable")]
    bodies, starts = np.unique(model.geom_bodyid[geoms], return_index=True)
    local = np.column_stack([model.geom_pos[geoms], _quat_mats(model.geom_quat[geoms]), model.geom_size[geoms],
                             model.geom_rbound[geoms], model.geom_margin[geoms]]).reshape(-1, _LOCAL_FIELDS)
    reach = np.linalg.norm(model.geom_pos[geoms], axis=1) + model.geom_rbound[geoms] + model.geom_margin[geoms]
    spans = np.append(starts, len(geoms)).astype(np.int64)
    body_reach = np.array([reach[a:b].max() for a, b in zip(spans[:-1], spans[1:], strict=True)])
    return (model.body_mocapid[bodies].astype(np.int64), spans, local, model.geom_type[geoms].astype(np.int64),
            body_reach.reshape(-1))


@njit(cache=True, error_model="numpy")
def _clear_steps(steps: int, base_q: np.ndarray, base_v: np.ndarray, robot: np.ndarray, fixed: np.ndarray,
                 table_origin: np.ndarray, table: np.ndarray, mocap_pos: np.ndarray, mocap_quat: np.ndarray,
                 mocap: np.ndarray, spans: np.ndarray, local: np.ndarray, types: np.ndarray,
                 body_reach: np.ndarray) -> int:
    """:meth:`ContactClearance.clear_steps`: ``robot`` = (footprint radius plus margins and pad m, largest command
    times SPEED_FACTOR m/s, SPEED_FACTOR, step s, body offset x, y m). The base travels at most ``step_m`` a step,
    so the steps before the room left around the footprint is used up are clear."""
    vx, vy = base_v[0], base_v[1]
    step_m = max(math.sqrt(vx * vx + vy * vy) * robot[2], robot[1]) * robot[3]
    px, py = robot[4] + base_q[0], robot[5] + base_q[1]
    room = _fixed_clearance(px, py, fixed, table_origin, table) - robot[0]
    if room < steps * step_m:  # the table's bound falls short of the horizon: the exact distance
        room = _nearest(px, py, fixed) - robot[0]
    room = min(room, steps * step_m)
    if room <= 0.0:
        return 0
    room = _mocap_room(px, py, robot[0], room, mocap_pos, mocap_quat, mocap, spans, local, types, body_reach)
    return min(steps, int(room / step_m)) if room > 0.0 else 0


@njit(cache=True, error_model="numpy")
def _fixed_clearance(px: float, py: float, rows: np.ndarray, origin: np.ndarray, table: np.ndarray) -> float:
    """A lower bound of the floor-plane distance from ``(px, py)`` to the fixed geoms less their margins, m: the
    table's cell (computed on first use at the cell centre, less the half diagonal), or exact off the table."""
    cell = origin[2]
    i, j = int(math.floor((px - origin[0]) / cell)), int(math.floor((py - origin[1]) / cell))
    if not (0 <= i < table.shape[0] and 0 <= j < table.shape[1]):
        return _nearest(px, py, rows)
    if math.isnan(table[i, j]):
        table[i, j] = _nearest(origin[0] + (i + 0.5) * cell, origin[1] + (j + 0.5) * cell, rows) - 0.7072 * cell
    return table[i, j]


@njit(cache=True, error_model="numpy")
def _nearest(px: float, py: float, rows: np.ndarray) -> float:
    """Smallest floor-plane distance from ``(px, py)`` to the shape rows less their margins, m (inf for none)."""
    out = np.inf
    for k in range(rows.shape[0]):
        out = min(out, _gap(px, py, rows, k) - rows[k, 7])
    return out


@njit(cache=True, error_model="numpy")
def _mocap_room(px: float, py: float, radius_m: float, room_m: float, mocap_pos: np.ndarray, mocap_quat: np.ndarray,
                mocap: np.ndarray, spans: np.ndarray, local: np.ndarray, types: np.ndarray,
                body_reach: np.ndarray) -> float:
    """``room_m`` or less: the smallest floor-plane distance from ``(px, py)`` to a mocap geom, less its margin and
    ``radius_m`` (arguments of :func:`_mocap_geoms`; bodies posed by ``mocap_pos`` (B, 3) and ``mocap_quat``
    (B, 4))."""
    row, xpos, body_mat, xmat = np.empty((1, SHAPE_FIELDS)), np.empty(3), np.empty(9), np.empty(9)
    for b in range(mocap.shape[0]):
        m = mocap[b]
        dx, dy = px - mocap_pos[m, 0], py - mocap_pos[m, 1]
        if math.sqrt(dx * dx + dy * dy) - body_reach[b] - radius_m >= room_m:
            continue  # the whole body is farther, however it is turned
        _quat_to_mat(mocap_quat[m, 0], mocap_quat[m, 1], mocap_quat[m, 2], mocap_quat[m, 3], body_mat)
        for k in range(spans[b], spans[b + 1]):
            for i in range(3):
                xpos[i] = mocap_pos[m, i]
                for j in range(3):
                    xpos[i] += body_mat[3 * i + j] * local[k, j]
                    xmat[3 * i + j] = (body_mat[3 * i] * local[k, 3 + j] + body_mat[3 * i + 1] * local[k, 6 + j]
                                       + body_mat[3 * i + 2] * local[k, 9 + j])
            _shape_row(types[k], local[k, 12], local[k, 13], local[k, 14], local[k, 15], xpos, xmat, row, 0)
            room_m = min(room_m, _gap(px, py, row, 0) - local[k, 16] - radius_m)
    return room_m


@njit(cache=True, error_model="numpy")
def _shape_row(geom_type: int, size0: float, size1: float, size2: float, rbound_m: float, xpos: np.ndarray,
               xmat: np.ndarray, out: np.ndarray, k: int) -> None:
    """Row ``k`` of ``out`` (R, SHAPE_FIELDS), but its margin: the floor-plane bound of a geom of sizes
    ``size0..2`` at world position ``xpos`` (3,) and orientation ``xmat`` (9,): a sphere a disc, a capsule or
    cylinder the stadium of its axis segment, a box with a vertical axis its rectangle, a plane or height field
    NEAR, anything else the disc of ``rbound_m``."""
    for i in range(SHAPE_FIELDS - 1):
        out[k, i] = 0.0
    cx, cy = xpos[0], xpos[1]
    up = _upright_axis(xmat) if geom_type == _BOX else -1
    if geom_type == _PLANE or geom_type == _HFIELD:
        out[k, 0] = NEAR
    elif geom_type == _SPHERE:
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = DISC, cx, cy, size0
    elif geom_type == _CAPSULE or geom_type == _CYLINDER:
        ax, ay = xmat[2] * size1, xmat[5] * size1  # half axis (the matrix's third column)
        out[k, 0], out[k, 1], out[k, 2], out[k, 3], out[k, 4] = STADIUM, cx - ax, cy - ay, cx + ax, cy + ay
        out[k, 5] = size0
    elif up >= 0:
        # the other two axes are horizontal: the footprint is the rectangle of their half sizes
        a = (up + 1) % 3
        ux, uy = xmat[a], xmat[3 + a]
        norm = math.sqrt(ux * ux + uy * uy)
        sizes = (size0, size1, size2)
        out[k, 0], out[k, 1], out[k, 2], out[k, 3], out[k, 4] = RECT, cx, cy, ux / norm, uy / norm
        out[k, 5], out[k, 6] = sizes[a], sizes[(up + 2) % 3]
    else:
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = DISC, cx, cy, rbound_m


@njit(cache=True, error_model="numpy")
def _upright_axis(xmat: np.ndarray) -> int:
    """Index of the geom axis along world z (row 3 of the row-major ``xmat``), or -1."""
    for k in range(3):
        if abs(xmat[6 + k]) >= 1.0 - _VERTICAL_TOL:
            return k
    return -1


@njit(cache=True, error_model="numpy")
def _gap(px: float, py: float, rows: np.ndarray, k: int) -> float:
    """Floor-plane distance from ``(px, py)`` to the shape of row ``k`` of ``rows``, m (negative inside; -inf for
    NEAR)."""
    kind = rows[k, 0]
    if kind == DISC:
        dx, dy = px - rows[k, 1], py - rows[k, 2]
        return math.sqrt(dx * dx + dy * dy) - rows[k, 3]
    if kind == STADIUM:
        ex, ey = rows[k, 3] - rows[k, 1], rows[k, 4] - rows[k, 2]
        dx, dy = px - rows[k, 1], py - rows[k, 2]
        length2 = ex * ex + ey * ey
        t = 0.0 if length2 <= 0.0 else min(max((dx * ex + dy * ey) / length2, 0.0), 1.0)
        dx, dy = dx - t * ex, dy - t * ey
        return math.sqrt(dx * dx + dy * dy) - rows[k, 5]
    if kind == RECT:
        dx, dy = px - rows[k, 1], py - rows[k, 2]
        pu, pv = dx * rows[k, 3] + dy * rows[k, 4], -dx * rows[k, 4] + dy * rows[k, 3]
        gu, gv = max(abs(pu) - rows[k, 5], 0.0), max(abs(pv) - rows[k, 6], 0.0)
        return math.sqrt(gu * gu + gv * gv)
    return -np.inf


@njit(cache=True, error_model="numpy")
def _quat_to_mat(w: float, x: float, y: float, z: float, out: np.ndarray) -> None:
    """Row-major rotation matrix (9,) of the quaternion (w, x, y, z), normalised first."""
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / norm, x / norm, y / norm, z / norm
    out[0], out[1], out[2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    out[3], out[4], out[5] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    out[6], out[7], out[8] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
