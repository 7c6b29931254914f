"""The 3D-PTG navigator in closed loop with a kinematic unicycle (no simulator): behaviour of §6.C."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from simnav.geometry import se2
from simnav.navigation.bands import Band, sort_into_bands
from simnav.navigation.navigator import NavCommand, NavigatorConfig, ReactiveNavigator3D
from simnav.navigation.ptgspace import PTGSpace

BASE = Band("base", 0.0, 0.5, np.array([[0.3, -0.3], [0.3, 0.3], [-0.3, 0.3], [-0.3, -0.3]]))
MAST = Band("mast", 0.5, 1.0, np.array([[0.05, -0.1], [0.05, 0.1], [-0.05, 0.1], [-0.05, -0.1]]))
V_MAX, W_MAX = 0.6, math.radians(90)
CONFIG = NavigatorConfig(num_paths=61, ref_distance_m=3.0, memory=False)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> str:
    return str(tmp_path_factory.mktemp("ptg-cache"))


def make_nav(cache_dir: str, bands=(BASE, MAST), **overrides) -> ReactiveNavigator3D:
    cfg = NavigatorConfig(**{**CONFIG.__dict__, **overrides})
    return ReactiveNavigator3D(list(bands), V_MAX, W_MAX, max_acc_m_s2=1.0, max_ang_acc_rad_s2=3.0, config=cfg,
                               cache_dir=cache_dir)


def drive(nav: ReactiveNavigator3D, obstacles_world: np.ndarray, target_xy, seconds: float,
          start=(0.0, 0.0, 0.0), dt: float = 0.05):
    """Closed loop: points in the world, a unicycle that executes the commands exactly. Returns poses and commands."""
    nav.set_target(target_xy)
    T = se2.from_xy_yaw(*start)
    poses, commands = [T], []
    for k in range(int(seconds / dt)):
        T_base_world = se2.inverse(T)
        pts = np.column_stack([se2.transform_points(T_base_world, obstacles_world[:, :2]), obstacles_world[:, 2]]) \
            if len(obstacles_world) else np.zeros((0, 3))
        cmd = nav.step(k * dt, T, pts)
        commands.append(cmd)
        if cmd.state == "reached":
            break
        T = T @ se2.exp([cmd.v_m_s * dt, 0.0, cmd.w_rad_s * dt])
        poses.append(T)
    return np.array(poses), commands


def wall(x0, y0, x1, y1, z=0.2, step=0.04) -> np.ndarray:
    n = int(math.hypot(x1 - x0, y1 - y0) / step) + 1
    return np.column_stack([np.linspace(x0, x1, n), np.linspace(y0, y1, n), np.full(n, z)])


def footprint_distance(poses: np.ndarray, points_xy: np.ndarray, polygon: np.ndarray) -> float:
    """Smallest distance between the robot polygon (at every pose) and the points."""
    from shapely.geometry import MultiPoint, Polygon

    cloud = MultiPoint(points_xy.tolist())
    return min(Polygon(se2.transform_points(T, polygon)).distance(cloud) for T in poses)


def test_empty_world_goes_straight_to_the_target(cache_dir) -> None:
    nav = make_nav(cache_dir)
    poses, commands = drive(nav, np.zeros((0, 3)), (3.0, 0.0), 20.0)
    assert commands[-1].state == "reached"
    assert np.max(np.abs(poses[:, 1, 2])) < 0.02                     # no sideways detour
    assert max(abs(c.w_rad_s) for c in commands) < 0.05
    assert max(c.v_m_s for c in commands) == pytest.approx(V_MAX, rel=0.05)
    assert np.linalg.norm(poses[-1][:2, 2] - [3.0, 0.0]) <= CONFIG.target_allowed_distance_m + 0.05
    # it slows down on the approach
    assert commands[-2].v_m_s < 0.5 * V_MAX


def test_a_wall_across_the_way_stops_the_robot_before_it(cache_dir) -> None:
    nav = make_nav(cache_dir)
    obstacles = wall(2.0, -30.0, 2.0, 30.0)
    # the goal lies just behind the wall: the robot could not stand there
    poses, commands = drive(nav, obstacles, (2.2, 0.0), 15.0)
    assert commands[-1].state == "blocked"
    assert abs(commands[-1].v_m_s) < 0.01
    assert footprint_distance(poses, obstacles[:, :2], BASE.polygon) > 0.02
    assert np.max(poses[:, 0, 2]) < 2.0 - 0.3
    assert np.max(np.abs(poses[:, 1, 2])) < 0.3       # it came at it and stopped, no search along the wall


@pytest.mark.parametrize("behind_free", [True, False])
def test_in_front_of_a_taken_goal_the_robot_makes_room_now_and_then(cache_dir, behind_free) -> None:
    # someone stands on the goal 1 m ahead, 0.9 m away; the robot stops before them, then after recovery_retry_s
    # of waiting backs away slowly for recovery_duration_s, unless something stands right behind it
    nav = make_nav(cache_dir)
    nav.set_target((1.0, 0.0))
    person = np.array([[0.9, 0.0, 0.2]])
    behind = np.zeros((0, 3)) if behind_free else np.array([[-0.45, 0.0, 0.2]])
    cfg, dt = nav.config, 0.05
    commands = [nav.step(k * dt, np.eye(3), np.vstack([person, behind])) for k in range(int(14.0 / dt))]
    assert all(c.state == "blocked" for c in commands[5:])
    backing = [k * dt for k, c in enumerate(commands) if c.v_m_s < 0]
    if not behind_free:
        assert not backing
        return
    assert min(backing) >= cfg.recovery_retry_s
    assert max(backing) <= cfg.recovery_retry_s + cfg.recovery_duration_s + 0.5
    assert min(c.v_m_s for c in commands) == pytest.approx(-cfg.recovery_speed_m_s)


def test_a_goal_is_reached_when_only_its_far_part_is_taken(cache_dir) -> None:
    # someone stands just past the goal: the robot would touch them on the goal itself, not 0.3 m before it
    nav = make_nav(cache_dir)
    person = np.array([[3.25, 0.0, 0.2]])
    poses, commands = drive(nav, person, (3.0, 0.0), 20.0)
    assert commands[-1].state == "reached"
    assert "blocked" not in {c.state for c in commands}
    assert footprint_distance(poses, person[:, :2], BASE.polygon) > 0.02


def test_a_goal_beyond_a_long_wall_is_searched_for_without_touching_the_wall(cache_dir) -> None:
    nav = make_nav(cache_dir)
    obstacles = wall(2.0, -30.0, 2.0, 30.0)
    poses, commands = drive(nav, obstacles, (5.0, 0.0), 20.0)
    assert commands[-1].state != "reached"
    assert footprint_distance(poses, obstacles[:, :2], BASE.polygon) > 0.02


def _drive_in_then_blocked(nav: ReactiveNavigator3D, yaw_after_rad: float) -> NavCommand:
    """The robot drives 0.6 m along +x (free), turns to ``yaw_after_rad``; then a point appears inside its base."""
    nav.set_target((3.0, 0.0))
    t = 0.0
    for k in range(31):
        t = 0.05 * k
        nav.step(t, se2.from_xy_yaw(0.02 * k, 0.0, 0.0), np.zeros((0, 3)))
    T = se2.from_xy_yaw(0.6, 0.0, yaw_after_rad)
    for k in range(1, 31):  # 1.5 s: braking from the drive, then recovery
        cmd = nav.step(t + 0.05 * k, T, np.array([[0.2, 0.0, 0.2]]))
    return cmd


def test_an_obstacle_inside_the_footprint_makes_the_robot_back_away_along_its_path(cache_dir) -> None:
    cmd = _drive_in_then_blocked(make_nav(cache_dir), 0.0)
    assert cmd.state == "recovering"
    assert cmd.v_m_s < 0.0


def test_after_waiting_a_while_the_robot_backs_away_again(cache_dir) -> None:
    nav = make_nav(cache_dir)
    cmd = _drive_in_then_blocked(nav, 0.0)
    assert cmd.state == "recovering"
    T, states = se2.from_xy_yaw(0.6, 0.0, 0.0), []
    for k in range(1, 301):  # 15 s more, still boxed in (the robot is held in place)
        states.append(nav.step(1.5 + 0.05 * k, T, np.array([[0.2, 0.0, 0.2]])).state)
    first_wait = states.index("waiting")
    assert "recovering" in states[first_wait:]
    again = states.index("recovering", first_wait)
    cfg = nav.config
    assert (again - first_wait) * 0.05 == pytest.approx(cfg.recovery_retry_s, abs=0.5)


def test_the_robot_does_not_back_into_space_it_has_not_driven_through(cache_dir) -> None:
    # after turning 90 degrees the space behind was never driven through (nor seen: lidars look ahead)
    cmd = _drive_in_then_blocked(make_nav(cache_dir), math.pi / 2)
    assert cmd.state == "waiting"
    assert cmd.v_m_s == pytest.approx(0.0)


def test_a_point_above_the_low_band_only_blocks_the_band_it_is_in(cache_dir) -> None:
    space = PTGSpace("C", [BASE, MAST], V_MAX, W_MAX, 61, 3.0, 0.05, cache_dir)
    k0 = space.num_paths // 2  # the straight path
    # beside the mast, above the base: the base passes under it, the mast passes beside it
    above = sort_into_bands(np.array([[1.0, 0.2, 0.7]]), [BASE, MAST], max_xy_m=3.3)
    assert space.tp_limits(space.prepare(above))[k0] == pytest.approx(1.0)
    # the same (x, y) at base height blocks the straight path where the base front reaches it
    low = sort_into_bands(np.array([[1.0, 0.2, 0.3]]), [BASE, MAST], max_xy_m=3.3)
    assert space.tp_limits(space.prepare(low))[k0] * 3.0 == pytest.approx(0.7, abs=0.08)
    # in front of the mast, it blocks the straight path where the mast front reaches it
    mast = sort_into_bands(np.array([[1.0, 0.0, 0.7]]), [BASE, MAST], max_xy_m=3.3)
    assert space.tp_limits(space.prepare(mast))[k0] * 3.0 == pytest.approx(0.95, abs=0.08)


def _long_table() -> np.ndarray:
    """A 10 m long table 0.8 m deep: top at 1.1 m (above the 1.0 m robot), legs every 1.5 m."""
    xs, ys = np.meshgrid(np.arange(1.5, 2.31, 0.05), np.arange(-5.0, 5.01, 0.05))
    top = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 1.1)])
    legs = [wall(x, y, x, y + 0.04, z=z) for x in (1.55, 2.25) for y in np.arange(-4.5, 4.6, 1.5)
            for z in (0.2, 0.6, 1.0)]
    return np.concatenate([top, *legs])


def test_the_navigator_maps_a_point_off_every_path_as_the_ptg_does(cache_dir) -> None:
    # behind the robot a forward-only CS path never passes: not exact, and the distance of turning towards it (the
    # table's nearest path sample, the start of every path, would say "distance 0": a target already reached)
    space = PTGSpace("CS", [BASE, MAST], V_MAX, W_MAX, 61, 3.0, 0.05, cache_dir)
    rng = np.random.default_rng(5)
    pts = np.vstack([[[-0.5, -0.2], [-0.2, 0.0], [-1.0, 0.3]], rng.uniform(-2.0, 2.0, (200, 2))])  # in the horizon
    k, d, exact = space.inverse_map_many(pts)
    k_ptg, d_ptg, exact_ptg, _ = space.ptg.inverse_map_ws2tp_many(pts)
    assert not exact[:3].any() and np.all(d[:3] > 0.3 / 3.0)
    off = ~exact & ~exact_ptg  # off every path by both (the table decides at 5 cm cell centres)
    assert off.sum() > 50
    np.testing.assert_allclose(d[off], d_ptg[off], atol=0.05 / 3.0)


@pytest.mark.parametrize("scene", ["open", "wall ahead", "wall ahead and left", "wall ahead and right", "corridor"])
@pytest.mark.parametrize("target", [(-0.6, 0.1), (-1.0, 0.0), (-0.8, -0.3)])
def test_a_target_just_behind_the_robot_is_reached_by_turning_towards_it(cache_dir, scene, target) -> None:
    # a dead end or a corridor with the target 0.6-1 m behind (a doorway's waypoint overshot): no forward path
    # gets there, so the robot turns (in place where a wall is close) instead of creeping or waiting
    walls = {"open": [], "wall ahead": [wall(0.5, -3, 0.5, 3)],
             "wall ahead and left": [wall(0.5, -3, 0.5, 3), wall(-3, 0.5, 0.5, 0.5)],
             "wall ahead and right": [wall(0.5, -3, 0.5, 3), wall(-3, -0.6, 0.5, -0.6)],
             "corridor": [wall(-3, 0.55, 3, 0.55), wall(-3, -0.55, 3, -0.55)]}[scene]
    obstacles = np.vstack(walls) if walls else np.zeros((0, 3))
    if scene in ("wall ahead and right", "corridor") and target == (-0.8, -0.3):
        target = (-0.8, 0.0)  # the robot could not stand on the other one
    poses, commands = drive(make_nav(cache_dir), obstacles, target, 15.0)
    assert commands[-1].state == "reached"
    if len(obstacles):
        assert footprint_distance(poses, obstacles[:, :2], BASE.polygon) > 0.02


def test_a_one_path_slot_to_the_target_is_taken_where_nd_sees_no_gap(cache_dir) -> None:
    # a doorway seen at an angle: only the target's own path gets through; ND's filters want wider gaps
    from simnav.navigation.holonomic import HolonomicInput, HolonomicND

    nav = make_nav(cache_dir, num_paths=121)
    target_base = np.array([1.2, -0.5])
    limits = []
    for space in nav._spaces:
        k_t, d_t, exact = space.inverse_map(*target_base)
        assert exact
        lim = np.full(space.num_paths, 0.1)
        lim[k_t] = min(1.0, d_t + 0.2)
        limits.append(lim)
        nd = HolonomicND().navigate(HolonomicInput.toward_path(lim, k_t, d_t, ref_distance_m=3.0))
        assert nd.direction_k != k_t or nd.speed == 0.0  # ND alone would not take it
    best, direct = nav._best_candidate(target_base, limits, final=False)
    assert direct and best is not None and best.speed > 0.0
    assert best.k == nav._spaces[best.ptg].inverse_map(*target_base)[0]


def test_turning_around_keeps_its_direction_across_the_seam_of_tp_space(cache_dir) -> None:
    # alpha paths k and N-1-k near +-pi both turn the robot around, one to the left, one to the right
    nav = make_nav(cache_dir, num_paths=121)
    alpha = nav._spaces[[s.name for s in nav._spaces].index("alpha")]
    free = np.ones(alpha.num_paths)
    left, right = 117, 3
    assert alpha.command(left)[1] > 0 > alpha.command(right)[1]
    # nothing decided yet: towards the target's side
    assert nav._keep_seam_side(alpha, left, free, np.array([-1.0, -0.2])) == right
    assert nav._keep_seam_side(alpha, left, free, np.array([-1.0, 0.2])) == left
    # already turning right: keep turning right, even with the target now a little to the left ...
    nav._seam_side = -1
    assert nav._keep_seam_side(alpha, left, free, np.array([-1.0, 0.2])) == right
    # ... unless the mirror path is much less free; paths off the seam are left alone
    blocked = free.copy()
    blocked[right] = 0.5
    assert nav._keep_seam_side(alpha, left, blocked, np.array([-1.0, 0.2])) == left
    assert nav._keep_seam_side(alpha, 80, free, np.array([-1.0, -0.2])) == 80


def test_a_table_the_robot_fits_under_is_passable_in_3d_and_blocked_in_2d(cache_dir) -> None:
    from simnav.navigation.bands import planar_bands
    from simnav.robot.spec import Prism, RobotSpec

    table = _long_table()
    nav3d = make_nav(cache_dir)
    poses, commands = drive(nav3d, table, (4.0, 0.0), 30.0)
    assert commands[-1].state == "reached"
    spec = RobotSpec(prisms=[Prism(name=b.name, z_min_m=b.z_min_m, z_max_m=b.z_max_m, polygon=b.polygon.tolist())
                             for b in (BASE, MAST)])
    nav2d = make_nav(cache_dir, bands=planar_bands(spec))
    poses, commands = drive(nav2d, table, (4.0, 0.0), 30.0)
    assert commands[-1].state != "reached"
    assert np.max(poses[:, 0, 2]) < 1.5


def test_waypoints_are_passed_without_stopping(cache_dir) -> None:
    nav = make_nav(cache_dir)
    nav.set_waypoints(np.array([[2.0, 0.0], [2.0, 2.0], [4.0, 2.0]]))
    T, speeds = np.eye(3), []
    for k in range(600):
        cmd = nav.step(0.05 * k, T, np.zeros((0, 3)))
        if cmd.state == "reached":
            break
        speeds.append(cmd.v_m_s)
        T = T @ se2.exp([cmd.v_m_s * 0.05, 0.0, cmd.w_rad_s * 0.05])
    assert cmd.state == "reached"
    assert min(speeds[20:-20]) > 0.2 * V_MAX   # never stops at the intermediate waypoints


def test_a_waypoint_with_a_heading_is_passed_facing_it_then_the_doorway_behind_it(cache_dir) -> None:
    # a wall at y = 1.1 with a 1 m doorway at x = 2; the approach waypoint lies 0.6 m before it, heading +y
    obstacles = np.vstack([wall(-3.0, 1.1, 1.5, 1.1), wall(2.5, 1.1, 6.0, 1.1)])
    nav = make_nav(cache_dir)
    nav.set_waypoints(np.array([[2.0, 0.5], [2.0, 1.1], [2.0, 2.5]]), allow_skip=np.array([False, False, True]),
                      allowed_distance_m=np.array([0.15, 0.3, 0.3]), headings_rad=np.array([np.pi / 2, np.nan, np.nan]))
    T, dt, passed_at, states = np.eye(3), 0.05, None, []
    for k in range(1200):
        pts = np.column_stack([se2.transform_points(se2.inverse(T), obstacles[:, :2]), obstacles[:, 2]])
        cmd = nav.step(k * dt, T, pts)
        states.append(cmd.state)
        if passed_at is None and cmd.target_index >= 1:
            passed_at = T.copy()
        if cmd.state == "reached":
            break
        T = T @ se2.exp([cmd.v_m_s * dt, 0.0, cmd.w_rad_s * dt])
    assert cmd.state == "reached"
    assert "turning" in states
    assert np.linalg.norm(passed_at[:2, 2] - [2.0, 0.5]) <= 0.15
    yaw = math.atan2(passed_at[1, 0], passed_at[0, 0])
    assert abs(se2.wrap_angle(yaw - np.pi / 2)) <= nav.config.waypoint_heading_tolerance_rad + 1e-9


def _run_waypoints(nav: ReactiveNavigator3D, obstacles, steps: int, dt: float = 0.05, states: list | None = None):
    """Closed loop over the waypoints already set, among the (N, 3) ``obstacles`` (or a function of the time and
    the robot's pose giving them); returns the last command and the pose where waypoint 0 was passed (None if
    never)."""
    T, passed_at, cmd = np.eye(3), None, None
    at = obstacles if callable(obstacles) else (lambda t_s, T: obstacles)
    for k in range(steps):
        world = at(k * dt, T)
        pts = np.column_stack([se2.transform_points(se2.inverse(T), world[:, :2]), world[:, 2]])
        cmd = nav.step(k * dt, T, pts)
        if states is not None:
            states.append(cmd.state)
        if passed_at is None and cmd.target_index >= 1:
            passed_at = T.copy()
        if cmd.state == "reached":
            break
        T = T @ se2.exp([cmd.v_m_s * dt, 0.0, cmd.w_rad_s * dt])
    return cmd, passed_at


@pytest.mark.parametrize("pass_m", [0.6, 0.0])
def test_a_waypoint_to_line_up_at_whose_spot_is_taken_is_lined_up_at_from_close_by(cache_dir, pass_m) -> None:
    # a post 0.1 m beside the approach waypoint (2, 0.5), heading +y: no pose within its 0.15 m leaves room for the
    # robot (half-width 0.3 m); the way on to (2, 1.5) and the goal passes 0.6 m from the post
    post = np.array([[2.1, 0.5, 0.2], [2.12, 0.5, 0.2], [2.1, 0.52, 0.2], [2.1, 0.48, 0.2]])
    nav = make_nav(cache_dir, taken_waypoint_pass_m=pass_m)
    nav.set_waypoints(np.array([[2.0, 0.5], [2.0, 1.5], [2.0, 2.5]]), allow_skip=np.array([False, False, True]),
                      allowed_distance_m=np.array([0.15, 0.3, 0.3]), headings_rad=np.array([np.pi / 2, np.nan, np.nan]))
    cmd, passed_at = _run_waypoints(nav, post, 1200)
    if pass_m == 0.0:  # never reached within its tolerance: the robot stays before it
        assert passed_at is None and cmd.state != "reached"
        return
    assert cmd.state == "reached"
    assert 0.15 < np.linalg.norm(passed_at[:2, 2] - [2.0, 0.5]) <= pass_m
    yaw = math.atan2(passed_at[1, 0], passed_at[0, 0])
    assert abs(se2.wrap_angle(yaw - np.pi / 2)) <= nav.config.waypoint_heading_tolerance_rad + 1e-9


@pytest.mark.parametrize("wait_s", [0.0, 4.0])
def test_a_lineup_spot_someone_walks_past_is_waited_for_with_the_taken_waypoint_wait(cache_dir, wait_s) -> None:
    # the approach waypoint (2, 0.5) of the test above, heading +y; someone stands 0.15 m beside it and walks off
    # 2 s after the robot has come within taken_waypoint_pass_m (0.6 m) of it
    came: list[float] = []

    def people(t_s: float, T: np.ndarray) -> np.ndarray:
        if not came and np.linalg.norm(T[:2, 2] - [2.0, 0.5]) <= 0.6:
            came.append(t_s)
        return _person(2.15, 0.5) if not came or t_s < came[0] + 2.0 else np.zeros((0, 3))

    nav = make_nav(cache_dir, taken_waypoint_wait_s=wait_s)
    nav.set_waypoints(np.array([[2.0, 0.5], [2.0, 1.5], [2.0, 2.5]]), allow_skip=np.array([False, False, True]),
                      allowed_distance_m=np.array([0.15, 0.3, 0.3]), headings_rad=np.array([np.pi / 2, np.nan, np.nan]))
    states: list[str] = []
    cmd, passed_at = _run_waypoints(nav, people, 1200, states=states)
    assert cmd.state == "reached"
    if wait_s == 0.0:  # as before: lined up where the robot stood when it found the spot taken
        assert "waiting" not in states and np.linalg.norm(passed_at[:2, 2] - [2.0, 0.5]) > 0.15
    else:  # stopped, waited for the spot to free up, then lined up on it
        assert 0 < states.count("waiting") * 0.05 <= 2.0
        assert np.linalg.norm(passed_at[:2, 2] - [2.0, 0.5]) <= 0.15


def _person(x: float, y: float, radius: float = 0.2) -> np.ndarray:
    """Points on the outline of someone standing at (x, y), at the base band's height."""
    a = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
    return np.column_stack([x + radius * np.cos(a), y + radius * np.sin(a), np.full(24, 0.3)])


def _through_a_doorway(nav: ReactiveNavigator3D, start_y: float, leaves_s: float, seconds: float = 40.0,
                       steps_in_m: float = math.inf, doorway_allowed_m: float = 0.3):
    """The robot at (2, start_y) facing +y drives through a 1 m doorway at (2, 1.1) (in a wall along y = 1.1) to
    (2, 2.5), the doorway flagged to yield at; someone stands in it, at (2, 1.3), from when the robot is within
    ``steps_in_m`` of the doorway (at once by default) until ``leaves_s``; the doorway's waypoint is passed within
    ``doorway_allowed_m``. Returns the distances to the doorway and
    the states while they stand there, and the last command."""
    walls = np.vstack([wall(-3.0, 1.1, 1.5, 1.1), wall(2.5, 1.1, 6.0, 1.1)])
    nav.set_waypoints(np.array([[2.0, 0.5], [2.0, 1.1], [2.0, 2.5]]), allow_skip=np.array([False, False, True]),
                      allowed_distance_m=np.array([0.15, doorway_allowed_m, 0.3]),
                      headings_rad=np.array([np.pi / 2, np.nan, np.nan]), give_way=np.array([False, True, False]))
    T, dt, distances, states, stepped_in = se2.from_xy_yaw(2.0, start_y, np.pi / 2), 0.05, [], [], False
    for k in range(int(seconds / dt)):
        stepped_in = stepped_in or float(np.linalg.norm(T[:2, 2] - [2.0, 1.1])) <= steps_in_m
        there = stepped_in and k * dt < leaves_s
        world = np.vstack([walls, _person(2.0, 1.3)]) if there else walls
        pts = np.column_stack([se2.transform_points(se2.inverse(T), world[:, :2]), world[:, 2]])
        cmd = nav.step(k * dt, T, pts)
        if there:
            distances.append(float(np.linalg.norm(T[:2, 2] - [2.0, 1.1])))
            states.append(cmd.state)
        if cmd.state == "reached":
            break
        T = T @ se2.exp([cmd.v_m_s * dt, 0.0, cmd.w_rad_s * dt])
    return np.array(distances), states, cmd


def test_before_a_doorway_someone_stands_in_the_robot_makes_room_then_goes_through(cache_dir) -> None:
    # someone steps into the doorway when the robot, driving up, is 0.5 m before it: it backs away along the way
    # it came to give_way_distance_m and waits
    nav = make_nav(cache_dir)
    distances, states, cmd = _through_a_doorway(nav, -0.7, leaves_s=25.0, steps_in_m=0.5)
    assert cmd.state == "reached"
    assert "yielding" in states and "turning" not in states
    assert distances.min() <= 0.55 and distances[-1] >= nav.config.give_way_distance_m - 0.02  # measured: 1.50 m
    # without yielding, placed there, it stays at the doorway, pressing towards the person
    nav = make_nav(cache_dir, give_way=False)
    distances, states, cmd = _through_a_doorway(nav, 0.6, leaves_s=15.0)
    assert cmd.state == "reached" and "yielding" not in states
    assert distances.max() < 0.6  # measured: 0.50 m throughout


def test_a_doorway_passed_but_not_crossed_can_still_be_yielded_at(cache_dir) -> None:
    # the doorway's waypoint passed 0.6 m before it (its allowed distance), someone steps in 0.55 m before it: by
    # default the robot, aiming beyond the doorway, does not yield
    distances, states, cmd = _through_a_doorway(make_nav(cache_dir), -0.7, leaves_s=25.0, steps_in_m=0.55,
                                                doorway_allowed_m=0.6)
    assert cmd.state == "reached" and "yielding" not in states
    assert distances.max() < 0.6  # measured: 0.47-0.57 m, pressing towards the person
    # with give_way_until_crossed it still has the doorway ahead and makes room
    nav = make_nav(cache_dir, give_way_until_crossed=True)
    distances, states, cmd = _through_a_doorway(nav, -0.7, leaves_s=25.0, steps_in_m=0.55, doorway_allowed_m=0.6)
    assert cmd.state == "reached" and "yielding" in states
    # to give_way_distance_m, or as far as its trail of the last recovery_trail_s goes: measured 1.46 m
    assert distances[-1] >= nav.config.give_way_distance_m - 0.05


def _boxed_in_facing_the_target(nav: ReactiveNavigator3D, seconds: float = 60.0):
    """The robot at the origin facing +x, in a box open behind (walls 0.7 m ahead and 0.8 m to each side), three
    people standing behind it, the target 3 m ahead beyond the wall. Returns the states and yaw rates (rad/s) per
    step and the last pose."""
    world = np.vstack([wall(0.7, -0.8, 0.7, 0.8), wall(-0.4, 0.8, 0.7, 0.8), wall(-0.4, -0.8, 0.7, -0.8),
                       _person(-0.9, 0.0), _person(-0.9, 0.5), _person(-0.9, -0.5)])
    nav.set_waypoints(np.array([[3.0, 0.0]]))
    T, dt, states, w = se2.from_xy_yaw(0.0, 0.0, 0.0), 0.05, [], []
    for k in range(int(seconds / dt)):
        pts = np.column_stack([se2.transform_points(se2.inverse(T), world[:, :2]), world[:, 2]])
        cmd = nav.step(k * dt, T, pts)
        states.append(cmd.state)
        w.append(cmd.w_rad_s)
        T = T @ se2.exp([cmd.v_m_s * dt, 0.0, cmd.w_rad_s * dt])
    return states, np.array(w), T


def test_spun_out_on_the_spot_the_robot_faces_the_target_and_waits(cache_dir) -> None:
    # boxed in, the way behind taken: ND's valley lies behind the robot and stays there as it turns
    dt = 0.05
    states, w, T = _boxed_in_facing_the_target(make_nav(cache_dir))
    assert np.abs(w[-400:]).sum() * dt > math.radians(180)  # still spinning in the last 20 s
    states, w, T = _boxed_in_facing_the_target(make_nav(cache_dir, spin_limit_rad=2 * math.pi))
    assert np.abs(w).sum() * dt < 2 * math.pi + math.pi  # one turn, then back to face the target
    assert set(states[-400:]) == {"waiting"} and np.all(w[-400:] == 0.0)
    assert abs(se2.to_xy_yaw(T)[2]) <= NavigatorConfig().turn_in_place_stop_rad + 0.05
    assert float(np.hypot(*T[:2, 2])) < 0.3
    with pytest.raises(ValueError, match="spin_limit_rad"):
        NavigatorConfig(spin_limit_rad=0.0)


def test_yielding_backs_only_where_the_robot_drove(cache_dir) -> None:
    # placed 0.5 m before the taken doorway with no trail behind it (a mission's start, or after an intervention),
    # the robot yields standing: its lidar does not see behind it, and no point sensed there does not make it free
    nav = make_nav(cache_dir)
    distances, states, cmd = _through_a_doorway(nav, 0.6, leaves_s=15.0)
    assert cmd.state == "reached" and "yielding" in states
    assert np.ptp(distances) < 0.05  # measured: 0.50 m throughout
    # backing wherever no point is sensed (give_way_on_trail off) backs it blind
    nav = make_nav(cache_dir, give_way_on_trail=False)
    distances, states, cmd = _through_a_doorway(nav, 0.6, leaves_s=15.0)
    assert cmd.state == "reached"
    assert distances[-1] >= nav.config.give_way_distance_m - 0.02


def _lined_up_at_a_doorway(nav: ReactiveNavigator3D, lidar: bool = False):
    """The robot drives north-east (45 degrees) from (0.8, -0.7) to the approach waypoint (2, 0.5) of a doorway at
    (2, 1.1), turns in place there to face it, and then someone steps into the doorway, at (2, 1.3), for 25 s.
    With ``lidar``, walls also close the corridor 2.7 m south of the doorway's wall and 2.5 m east of it, and the
    points within 120 degrees of the heading come as a level lidar's scan points (rays from the base origin).
    Returns the distances to the doorway, the yaws (rad) and the states while they stand there, and the last
    command."""
    walls = np.vstack([wall(-3.0, 1.1, 1.5, 1.1), wall(2.5, 1.1, 6.0, 1.1)])
    if lidar:
        walls = np.vstack([walls, wall(-3.0, -1.6, 4.5, -1.6), wall(4.5, -1.6, 4.5, 1.1)])
    nav.set_waypoints(np.array([[2.0, 0.5], [2.0, 1.1], [2.0, 2.5]]), allow_skip=np.array([False, False, True]),
                      allowed_distance_m=np.array([0.15, 0.3, 0.3]), headings_rad=np.array([np.pi / 2, np.nan, np.nan]),
                      give_way=np.array([False, True, False]))
    T, dt, since, distances, yaws, states = se2.from_xy_yaw(0.8, -0.7, np.pi / 4), 0.05, None, [], [], []
    for k in range(int(60.0 / dt)):
        x, y, yaw = se2.to_xy_yaw(T)
        if since is None and abs(se2.wrap_angle(yaw - np.pi / 2)) < math.radians(10) and abs(x - 2.0) < 0.15:
            since = k * dt  # lined up on the doorway's axis
        there = since is not None and k * dt < since + 25.0
        world = np.vstack([walls, _person(2.0, 1.3)]) if there else walls
        pts = np.column_stack([se2.transform_points(se2.inverse(T), world[:, :2]), world[:, 2]])
        if lidar:
            ahead = np.abs(np.arctan2(pts[:, 1], pts[:, 0])) <= math.radians(120)
            cmd = nav.step(k * dt, T, np.zeros((0, 3)), pts[ahead])
        else:
            cmd = nav.step(k * dt, T, pts)
        if there:
            distances.append(float(np.hypot(x - 2.0, y - 1.1)))
            yaws.append(yaw)
            states.append(cmd.state)
        if cmd.state == "reached":
            break
        T = T @ se2.exp([cmd.v_m_s * dt, 0.0, cmd.w_rad_s * dt])
    return np.array(distances), np.array(yaws), states, cmd


def test_yielding_after_turning_to_face_the_doorway_can_turn_back_onto_the_trail(cache_dir) -> None:
    # lined up facing the doorway, the robot's trail comes in at 45 degrees: backing straight would leave it, so
    # without a lidar's scans of the space behind it yields where it stands
    distances, yaws, states, cmd = _lined_up_at_a_doorway(make_nav(cache_dir))
    assert cmd.state == "reached" and "yielding" in states
    assert np.ptp(distances) < 0.05 and distances[-1] < 0.7  # measured: 0.66-0.67 m
    # with give_way_turn_back it turns back to the heading it came with (the doorway still ahead) and backs along
    # its trail to give_way_distance_m
    nav = make_nav(cache_dir, give_way_turn_back=True)
    distances, yaws, states, cmd = _lined_up_at_a_doorway(nav)
    assert cmd.state == "reached" and "yielding" in states
    assert distances[-1] >= nav.config.give_way_distance_m - 0.02  # measured: 1.51 m
    assert abs(yaws[-1] - np.pi / 4) < math.radians(25)  # facing about north-east again
    assert "turning" not in states and distances.min() > 0.6  # never on towards the person; measured: 0.66 m


def test_yielding_after_turning_to_face_the_doorway_backs_where_the_lidar_saw_free_space(cache_dir) -> None:
    # the corridor behind the lined-up robot was in the lidar's view as it came: it backs straight, facing the
    # doorway, to give_way_distance_m (give_way_seen_free_s, 20 s by default)
    nav = make_nav(cache_dir)
    distances, yaws, states, cmd = _lined_up_at_a_doorway(nav, lidar=True)
    assert cmd.state == "reached" and "yielding" in states and "turning" not in states
    assert distances[-1] >= nav.config.give_way_distance_m - 0.02  # measured: 1.50 m
    assert abs(se2.wrap_angle(yaws[-1] - np.pi / 2)) < math.radians(10)  # still facing the doorway
    # only onto its trail (give_way_seen_free_s=None): it stands where it turned
    distances, yaws, states, cmd = _lined_up_at_a_doorway(make_nav(cache_dir, give_way_seen_free_s=None), lidar=True)
    assert cmd.state == "reached" and "yielding" in states
    assert np.ptp(distances) < 0.05 and distances[-1] < 0.7  # measured: 0.66-0.67 m
    with pytest.raises(ValueError, match="give_way_seen_free_s"):
        NavigatorConfig(give_way_seen_free_s=0.0)


def test_a_doorway_someone_stands_in_is_waited_for_from_where_the_robot_sees_it(cache_dir) -> None:
    # from 2 m away the robot drives up to give_way_check_m and waits there: no closer while it is taken
    nav = make_nav(cache_dir)
    distances, states, cmd = _through_a_doorway(nav, -0.9, leaves_s=10.0)
    assert cmd.state == "reached"
    assert states[-1] == "yielding"
    assert distances.min() >= nav.config.give_way_distance_m  # measured: 1.66 m (it stops from 1.9 m)


def test_before_a_doorway_of_two_narrow_nodes_the_robot_makes_room_from_the_first(cache_dir) -> None:
    # narrow nodes at (2, 1.1) (the wall's doorway) and (2, 1.85) just inside; someone stands on the second: the
    # robot backs away until give_way_distance_m from the first, out of the way of whoever comes out
    walls = np.vstack([wall(-3.0, 1.1, 1.5, 1.1), wall(2.5, 1.1, 6.0, 1.1)])
    world = np.vstack([walls, _person(2.0, 2.0)])
    nav = make_nav(cache_dir)
    nav.set_waypoints(np.array([[2.0, 0.5], [2.0, 1.1], [2.0, 1.48], [2.0, 1.85], [2.0, 3.0]]),
                      allow_skip=np.array([False, False, True, False, True]),
                      allowed_distance_m=np.array([0.15, 0.3, 0.3, 0.3, 0.3]),
                      headings_rad=np.array([np.pi / 2, np.nan, np.nan, np.nan, np.nan]),
                      give_way=np.array([False, True, False, True, False]))
    T, dt, stepped_in = se2.from_xy_yaw(2.0, -0.7, np.pi / 2), 0.05, False
    for k in range(500):  # they step in when the robot, driving up, is 0.5 m before the first
        stepped_in = stepped_in or float(np.linalg.norm(T[:2, 2] - [2.0, 1.1])) <= 0.5
        seen = world if stepped_in else walls
        cmd = nav.step(k * dt, T, np.column_stack([se2.transform_points(se2.inverse(T), seen[:, :2]), seen[:, 2]]))
        T = T @ se2.exp([cmd.v_m_s * dt, 0.0, cmd.w_rad_s * dt])
    assert stepped_in and cmd.state == "yielding"
    distance = nav.config.give_way_distance_m
    assert distance - 0.02 <= 1.1 - T[1, 2] < distance + 0.1  # measured: 1.50 m from the first


def test_a_skipped_waypoint_is_aimed_at_again_when_the_later_one_is_no_longer_reachable(cache_dir) -> None:
    # the goal (2.5, 1.5) is reachable from the start, so the waypoint (1.5, 0) is skipped; then a wall across
    # x = 2.1 closes the way to the goal, not to the waypoint: the robot aims at the waypoint again
    nav = make_nav(cache_dir)
    nav.set_waypoints(np.array([[1.5, 0.0], [2.5, 1.5]]))
    assert nav.step(0.0, np.eye(3), np.zeros((0, 3))).target_index == 1
    closed = wall(2.1, -3.0, 2.1, 3.0)
    assert nav.step(0.05, np.eye(3), closed).target_index == 0
    # behind the robot it is not: turned to face -x, the goal stays the target
    nav.set_waypoints(np.array([[1.5, 0.0], [2.5, 1.5]]))
    nav.step(0.1, np.eye(3), np.zeros((0, 3)))
    T = se2.from_xy_yaw(1.8, 0.0, np.pi)
    assert nav.step(0.15, T, np.column_stack([se2.transform_points(se2.inverse(T), closed[:, :2]),
                                              closed[:, 2]])).target_index == 1


def test_short_of_a_doorway_passed_the_robot_aims_straight_through_it(cache_dir) -> None:
    # the doorway (2, 1.1) in the gap of a wall along y = 1.1 (passed within 0.3 m), its exit waypoint (2, 1.6)
    # straight on, a waypoint (3.5, 1.8) beyond: with through_doorway_first, 0.2 m short of the doorway the robot
    # aims at the exit waypoint, past the wall's line it may cut to the one beyond
    walls = np.vstack([wall(-3.0, 1.1, 1.5, 1.1), wall(2.5, 1.1, 6.0, 1.1)])

    def target_at(y_m: float, **overrides) -> int:
        nav = make_nav(cache_dir, **overrides)
        nav.set_waypoints(np.array([[2.0, 0.0], [2.0, 1.1], [2.0, 1.6], [3.5, 1.8]]),
                          allow_skip=np.array([True, False, True, True]),
                          allowed_distance_m=np.array([1.5, 0.3, 0.3, 0.3]),
                          give_way=np.array([False, True, False, False]))
        T = se2.from_xy_yaw(2.0, y_m, np.pi / 2)
        return nav.step(0.0, T, np.column_stack([se2.transform_points(se2.inverse(T), walls[:, :2]),
                                                 walls[:, 2]])).target_index

    assert target_at(0.9, through_doorway_first=True) == 2
    assert target_at(1.15, through_doorway_first=True) == 3
    assert target_at(0.9) == 3  # by default the doorway counts as passed from 0.2 m short


def test_a_waypoint_heading_is_given_up_without_room_to_turn(cache_dir) -> None:
    nav = make_nav(cache_dir)
    nav.set_waypoints(np.array([[0.0, 0.0], [3.0, 0.0]]), headings_rad=np.array([np.pi, np.nan]))
    beside = np.array([[0.0, 0.45, 0.2]])  # inside the turning circle, clear of the path ahead
    cmd = nav.step(0.0, np.eye(3), beside)
    assert cmd.state == "navigating" and cmd.target_index == 1
    nav.set_waypoints(np.array([[0.0, 0.0], [3.0, 0.0]]), headings_rad=np.array([np.pi, np.nan]))
    cmd = nav.step(0.0, np.eye(3), np.zeros((0, 3)))
    assert cmd.state == "turning" and cmd.target_index == 0 and cmd.v_m_s == 0.0


def test_with_every_path_blocked_the_robot_turns_in_place_if_it_just_fits(cache_dir) -> None:
    # a cup of points around the front half, just outside the base's circumcircle (0.42 m) but inside it plus the
    # 5 cm margin: no path moves, nothing to back along; the target lies behind to the right
    angles = np.radians(np.linspace(-100.0, 100.0, 81))
    reach = math.hypot(0.3, 0.3)

    def first_state(radius_m: float) -> str:
        nav = make_nav(cache_dir)
        nav.set_target((-0.5, -2.0))
        cup = np.column_stack([radius_m * np.cos(angles), radius_m * np.sin(angles), np.full(len(angles), 0.2)])
        return nav.step(0.0, np.eye(3), cup).state

    assert first_state(reach + 0.035) == "turning"   # within the margin, but the robot fits
    assert first_state(reach + 0.01) == "waiting"    # too tight even to turn


def test_stuck_is_reported_after_the_timeout(cache_dir) -> None:
    nav = make_nav(cache_dir, stuck_timeout_s=2.0)
    obstacles = wall(0.6, -30.0, 0.6, 30.0)
    _, commands = drive(nav, obstacles, (5.0, 0.0), 4.0)
    assert not commands[10].stuck
    assert commands[-1].stuck


def test_bad_configuration_and_waypoints_are_rejected(cache_dir) -> None:
    with pytest.raises(ValueError, match="secure_distance"):
        NavigatorConfig(secure_distance_m=5.0)
    with pytest.raises(ValueError, match="give_way_distance_m must be >= 0, got -1"):
        NavigatorConfig(give_way_distance_m=-1.0)
    nav = make_nav(cache_dir)
    with pytest.raises(ValueError, match="waypoints"):
        nav.set_waypoints(np.array([[np.nan, 0.0]]))
    with pytest.raises(ValueError, match="headings_rad"):
        nav.set_waypoints(np.array([[1.0, 0.0]]), headings_rad=np.zeros(2))
    with pytest.raises(ValueError, match="give_way"):
        nav.set_waypoints(np.array([[1.0, 0.0]]), give_way=np.zeros(3, dtype=bool))



def test_near_obstacles_the_fastest_point_of_the_robot_is_slowed_not_each_speed(cache_dir) -> None:
    nav = make_nav(cache_dir)
    radius_m = math.hypot(0.3, 0.3)
    assert nav._point_speed_scale(V_MAX, 0.0, 1.0) == 1.0  # nothing near: full speed
    assert nav._point_speed_scale(V_MAX, 0.0, 0.4) == pytest.approx(0.4)  # driving straight: 0.4 of top speed
    # a slow turn on the spot moves no point faster than the cap: untouched
    assert nav._point_speed_scale(0.0, 0.5, 0.4) == 1.0
    # a fast one is held to the cap at the corners
    scale = nav._point_speed_scale(0.0, W_MAX, 0.4)
    assert scale * W_MAX * radius_m == pytest.approx(0.4 * V_MAX)
    # an arc shares the cap between driving and turning
    scale = nav._point_speed_scale(0.3, 0.5, 0.4)
    assert scale * (0.3 + 0.5 * radius_m) == pytest.approx(0.4 * V_MAX)


def test_the_secure_distance_ramp_lets_the_robot_stop_short_of_the_first_obstacle_on_its_path(cache_dir) -> None:
    nav = make_nav(cache_dir)
    cfg, space = nav.config, nav._spaces[0]
    straight = space.num_paths // 2
    a, tau = cfg.braking_m_s2, cfg.reaction_time_s
    v_full = space.command(straight)[0]
    assert nav._stopping_speed(space, straight, cfg.secure_distance_m / cfg.ref_distance_m) == 0.0
    assert nav._stopping_speed(space, straight, 1.0) == 1.0  # free to the horizon: full speed
    for room_m in (0.05, 0.2, 0.5):
        v = v_full * nav._stopping_speed(space, straight, (room_m + cfg.secure_distance_m) / cfg.ref_distance_m)
        assert v < v_full
        assert v * tau + v * v / (2 * a) == pytest.approx(room_m)  # reacts, brakes, stops right there
    # the ramp is in metres: the same speed with twice the horizon and half the normalised distance
    far = make_nav(cache_dir, ref_distance_m=2 * CONFIG.ref_distance_m)
    free_m = 0.3
    assert far._stopping_speed(far._spaces[0], straight, free_m / far.config.ref_distance_m) == pytest.approx(
        nav._stopping_speed(space, straight, free_m / cfg.ref_distance_m))
    # a turning path moves along its pseudo-distance (turning counts turning_radius_ref_m per radian)
    k = straight + 10
    v, w = space.command(k)
    s = nav._stopping_speed(space, k, (0.1 + cfg.secure_distance_m) / cfg.ref_distance_m)
    u = s * math.hypot(v, w * space.ptg.config.turning_radius_ref_m)
    assert u * tau + u * u / (2 * a) == pytest.approx(0.1)


def test_close_to_a_wall_with_the_target_beside_it_the_robot_turns_in_place_then_goes(cache_dir) -> None:
    # stopped 0.2 m before a wall (its front at 0.3 m), a wall to the left too; the target lies 2 m to the right:
    # every path moves forward while it turns, and the secure distance stops them all
    obstacles = np.vstack([wall(0.5, -4.0, 0.5, 1.0), wall(-2.0, 1.0, 0.5, 1.0)])
    nav = make_nav(cache_dir)
    poses, commands = drive(nav, obstacles, (0.0, -2.0), 20.0)
    assert commands[-1].state == "reached"
    assert all(c.state == "turning" and c.v_m_s == 0.0 and c.w_rad_s < 0.0 for c in commands[:20])  # to the right
    assert all(c.w_rad_s <= 0.0 for c in commands if c.state == "turning")                          # no dithering
    assert footprint_distance(poses, obstacles[:, :2], BASE.polygon) > 0.02
    # without the rule it waits there
    _, commands_without = drive(make_nav(cache_dir, turn_in_place=False), obstacles, (0.0, -2.0), 20.0)
    assert commands_without[-1].state == "waiting"
    assert not any(c.state == "turning" for c in commands_without)


def test_askew_before_a_tight_doorway_with_no_path_a_small_stalled_turn_squares_the_robot_up(cache_dir) -> None:
    # jambs 0.8 m apart beside the robot's front (0.1 m of room each side of the 0.6 m base), the robot 10 degrees
    # off the doorway's axis: no path gets through, and the target lies within turn_in_place_stop_rad
    jambs = np.vstack([wall(0.2, 0.4, 0.35, 0.4, step=0.02), wall(0.2, -0.4, 0.35, -0.4, step=0.02)])
    start = (0.0, 0.0, math.radians(10.0))
    # by default a robot with no path turns in place only from turn_in_place_stop_rad: it waits there for good
    _, commands = drive(make_nav(cache_dir), jambs, (3.0, 0.0), 20.0, start=start)
    assert {c.state for c in commands} == {"waiting"}
    # from 3 degrees it squares up and goes through
    poses, commands = drive(make_nav(cache_dir, turn_in_place_stalled_rad=math.radians(3.0)), jambs, (3.0, 0.0),
                            20.0, start=start)
    assert commands[0].state == "turning" and commands[0].w_rad_s < 0.0
    assert commands[-1].state == "reached"
    assert footprint_distance(poses, jambs[:, :2], BASE.polygon) > 0.04
    with pytest.raises(ValueError, match="turn_in_place_stalled_rad"):
        NavigatorConfig(turn_in_place_stalled_rad=math.radians(20.0))


def test_a_doorway_the_grids_close_is_squeezed_through_when_the_exact_sweep_is_free(cache_dir) -> None:
    # 0.1 m deep jambs 0.76 m apart just ahead, the 0.6 m base 4 cm off their centre line: 3 cm between its side and
    # the nearer jamb, less than the grids' 5 cm margin (plus up to half a cell), more than the squeeze's 2 cm
    jambs = np.vstack([wall(0.3, 0.38, 0.4, 0.38, step=0.01), wall(0.3, -0.38, 0.4, -0.38, step=0.01)])
    start, goal = (0.0, 0.04, 0.0), (2.0, 0.0)

    def drive_through(nav, obstacles, seconds):
        """The doorway's waypoint (flagged give_way, as missions flag narrow nodes), then the goal beyond it."""
        nav.set_target = lambda xy: nav.set_waypoints(np.array([[0.35, 0.0], xy]), allow_skip=np.array([False, True]),
                                                      allowed_distance_m=np.array([0.3, 0.3]),
                                                      give_way=np.array([True, False]))
        return drive(nav, obstacles, goal, seconds, start=start)

    _, commands = drive_through(make_nav(cache_dir, squeeze=False), jambs, 10.0)
    assert commands[-1].state in ("waiting", "recovering") and commands[-1].v_m_s <= 0.0
    _, commands = drive(make_nav(cache_dir), jambs, goal, 10.0, start=start)  # no doorway flagged: no squeezing
    assert commands[-1].state in ("waiting", "recovering") and commands[-1].v_m_s <= 0.0
    poses, commands = drive_through(make_nav(cache_dir), jambs, 40.0)
    assert commands[-1].state == "reached"
    gap = footprint_distance(poses, jambs[:, :2], BASE.polygon)
    assert 0.02 - 1e-3 < gap < 0.05
    first_move = next(c for c in commands if c.v_m_s > 0.0)  # slowly, until the grids see it fit
    assert first_move.state == "squeezing" and first_move.v_m_s <= make_nav(cache_dir).config.squeeze_speed_m_s + 1e-9
    with pytest.raises(ValueError, match="squeeze_speed_m_s"):
        NavigatorConfig(squeeze_speed_m_s=0.0)
    # someone standing in the doorway: no squeezing into them
    person = np.vstack([jambs, wall(0.7, -0.1, 0.7, 0.1, step=0.02)])
    poses, commands = drive_through(make_nav(cache_dir), person, 10.0)
    assert commands[-1].state != "reached" and np.max(poses[:, 0, 2]) < 0.2


def test_squeezing_is_not_tried_again_where_it_ended_with_every_path_blocked(cache_dir) -> None:
    nav = make_nav(cache_dir)
    nav.set_waypoints(np.array([[0.5, 0.0], [3.0, 0.0]]), give_way=np.array([True, False]))
    assert nav._may_squeeze(np.eye(3))  # a doorway 0.5 m ahead
    nav._squeeze_stuck_xy = np.array([0.1, 0.0])  # where a squeeze ended blocked
    assert not nav._may_squeeze(np.eye(3))
    assert nav._may_squeeze(se2.from_xy_yaw(-0.25, 0.0, 0.0))  # backed away 0.35 m from it
    nav.set_waypoints(np.array([[0.5, 0.0], [3.0, 0.0]]), give_way=np.array([True, False]))
    assert nav._may_squeeze(np.eye(3))  # a new route forgets it
    nav.set_waypoints(np.array([[0.5, 0.0], [3.0, 0.0]]))
    assert not nav._may_squeeze(np.eye(3))  # no doorway on the route


def test_a_target_beside_the_robot_in_open_space_is_reached_on_a_path_not_by_turning_in_place(cache_dir) -> None:
    nav = make_nav(cache_dir)
    _, commands = drive(nav, np.zeros((0, 3)), (0.0, 2.0), 20.0)
    assert commands[-1].state == "reached"
    assert not any(c.state == "turning" for c in commands)


def test_no_turning_in_place_with_an_obstacle_inside_the_turning_circle(cache_dir) -> None:
    # the same wall, and a post beside the robot's rear corner: turning would sweep within 6 mm of it
    obstacles = np.vstack([wall(0.5, -4.0, 0.5, 1.0), wall(-2.0, 1.0, 0.5, 1.0), [[-0.25, -0.35, 0.2]]])
    nav = make_nav(cache_dir)
    poses, commands = drive(nav, obstacles, (0.0, -2.0), 5.0)
    assert not any(c.state == "turning" for c in commands)
    assert footprint_distance(poses, obstacles[:, :2], BASE.polygon) > 0.02


def test_paths_into_space_no_sensor_sees_are_not_free(cache_dir) -> None:
    """A wall of people 0.75 m ahead across a corridor, a target beyond it, a 240-degree lidar: limited to its
    view the robot waits; without, the paths that turn it around into the unseen space behind look free and it
    turns. (MRPT's ND alone: its fallback finds the paths turning sideways within the view, free for 0.75 m.)"""
    from simnav.navigation.sensing import ViewSector

    lidar = ViewSector(0.2, 0.0, 0.0, math.radians(120.0), 5.0)
    people = np.vstack([wall(0.75, -1.0, 0.75, 1.0, z) for z in (0.2, 0.7)])
    seen_sides = np.vstack([wall(0.0, s, 3.0, s, z) for s in (-1.0, 1.0) for z in (0.2, 0.7)])
    points = np.vstack([people, seen_sides])
    chosen = {}
    for name, limit in (("blind", False), ("view", True)):
        nav = ReactiveNavigator3D([BASE, MAST], V_MAX, W_MAX, max_acc_m_s2=1.0, max_ang_acc_rad_s2=3.0,
                                  config=replace(CONFIG, limit_to_view=limit, nd_fallback_floor_ratio=None),
                                  cache_dir=cache_dir, view=[lidar])
        nav.set_target([4.0, 0.0])
        chosen[name] = [nav.step(0.05 * k, np.eye(3), points) for k in range(10)][-1]
    assert chosen["blind"].state == "navigating" and abs(chosen["blind"].w_rad_s) > 0.3
    assert chosen["view"].state in ("waiting", "recovering") and chosen["view"].w_rad_s == 0.0


def test_nd_crowded_floor_ratio_reaches_the_holonomic_method(cache_dir) -> None:
    crowded = ReactiveNavigator3D([BASE, MAST], V_MAX, W_MAX, cache_dir=cache_dir,
                                  config=replace(CONFIG, nd_crowded_floor_ratio=0.5))
    assert all(method.config.crowded_floor_ratio == 0.5 for method in crowded._holonomic)
    plain = ReactiveNavigator3D([BASE, MAST], V_MAX, W_MAX, cache_dir=cache_dir, config=CONFIG)
    assert all(method.config.crowded_floor_ratio is None for method in plain._holonomic)


def test_a_low_wall_the_camera_no_longer_sees_is_remembered_and_stops_the_giraff(cache_dir) -> None:
    from simnav.navigation.bands import robot_bands
    from simnav.navigation.memory import MemoryConfig
    from simnav.navigation.sensing import camera_free_space
    from simnav.robot import load_robot

    # a wall 5 cm high across the way: only the Giraff's depth camera sees it, and only from 0.86 m ahead on (its
    # view's lower edge, 52.8 deg down from 1.12 m, 0.05 m ahead of the base origin) within its 57 deg
    robot = load_robot("giraff")
    bands, drive_spec = robot_bands(robot), robot.drive
    near_m = 0.05 + (1.12 - 0.05) / math.tan(math.radians(30.0 + 45.6 / 2))
    wall_xy = np.column_stack([np.full(301, 2.0), np.linspace(-3.0, 3.0, 301)])

    def closest_gap_m(whole_band_view: bool) -> float:
        config = NavigatorConfig(memory_config=MemoryConfig(whole_band_view=whole_band_view))
        nav = ReactiveNavigator3D(bands, drive_spec.max_v_m_s, drive_spec.max_w_rad_s,
                                  max_acc_m_s2=drive_spec.max_acc_m_s2,
                                  max_ang_acc_rad_s2=drive_spec.max_ang_acc_rad_s2, cache_dir=cache_dir,
                                  config=config, free_space_x_m=camera_free_space(robot, bands))
        nav.set_target((4.0, 0.0))
        T, poses = np.eye(3), []
        for k in range(80):  # 4 s
            p = se2.transform_points(se2.inverse(T), wall_xy)
            seen = (p[:, 0] >= near_m) & (np.abs(np.arctan2(p[:, 1], p[:, 0] - 0.05)) <= math.radians(28.5))
            cmd = nav.step(0.05 * k, T, np.column_stack([p[seen], np.full(seen.sum(), 0.05)]))
            T = T @ se2.exp([cmd.v_m_s * 0.05, 0.0, cmd.w_rad_s * 0.05])
            poses.append(T)
        return min(2.0 - float(np.max(se2.transform_points(P, bands[0].polygon)[:, 0])) for P in poses)

    # the cone counted as seen free where the camera sees nothing of the floor: the wall is forgotten, and crossed
    assert closest_gap_m(False) < 0.0
    # the base band counted as seen free only where the camera sees it whole: the robot stops in front
    assert closest_gap_m(True) > 0.05
    with pytest.raises(ValueError, match="whole_band_view needs"):
        ReactiveNavigator3D(bands, 0.7, 1.0, cache_dir=cache_dir,
                            config=NavigatorConfig(memory_config=MemoryConfig(whole_band_view=True)))


# TP-NavLimits of the alpha-A PTG (121 paths) of an office mission: the Giraff inside a doorway beside the open
# leaf, heading 14 degrees right of its next waypoint; the paths turning right (20-41) free for 0.2-0.67 of the horizon
_BESIDE_LEAF_ALPHA = np.array([0.02] * 19 + [0.03, 0.2, 0.2, 0.2, 0.21, 0.22, 0.22, 0.23, 0.24, 0.25, 0.26, 0.28, 0.3,
                                             0.33, 0.35, 0.37, 0.4, 0.43, 0.47, 0.51, 0.56, 0.62, 0.67]
                              + [0.05] * 3 + [0.04] * 28 + [0.03] * 2 + [0.02] * 24 + [0.03] * 2 + [0.04] * 13
                              + [0.05, 0.05, 0.04] + [0.05] * 4)


@pytest.mark.parametrize("fallback", [None, 0.5])
def test_where_nd_finds_no_gap_its_fallback_takes_the_free_paths(cache_dir, fallback) -> None:
    # MRPT's sweep stops at 0.6: above it only paths 40-41, a gap too narrow for ND's filters: no way found
    nav = make_nav(cache_dir, num_paths=121, ref_distance_m=4.0, ptgs=("C", "alpha", "CS"),
                   nd_fallback_floor_ratio=fallback)
    blocked = np.full(121, 0.03)
    best, direct = nav._best_candidate(np.array([2.37, 0.61]), [blocked, _BESIDE_LEAF_ALPHA, blocked], final=False)
    assert not direct
    if fallback is None:
        assert best is None  # the robot would back away or wait
    else:
        assert best.ptg == 1 and 20 <= best.k <= 41 and best.speed > 0  # measured: path 40, free 0.62, speed 1


@pytest.mark.parametrize(("turned_deg", "backs"), [(0.0, True), (2.0, True), (12.0, False), (-18.0, False)])
def test_yielding_backs_onto_the_trail_only_with_the_footprint_where_it_was(cache_dir, turned_deg: float,
                                                                           backs: bool) -> None:
    # the robot drove 1.5 m straight along +x, then turned in place (askew in a doorway, say): backing straight
    # to yield lands on the trail only if its every corner stays within the footprint margin of where it was
    # (turned 12 degrees, the corners of the 0.6 m base lie 9 cm off where they were: a door jamb beside one is
    # hit); recovery still backs within 0.1 m and 20 degrees of a trail pose
    nav = make_nav(cache_dir)
    for k in range(76):
        nav._remember_pose(0.1 * k, se2.from_xy_yaw(0.02 * k, 0.0, 0.0))
    T = se2.from_xy_yaw(1.5, 0.0, math.radians(turned_deg))
    nav._remember_pose(8.0, T)
    assert nav._behind_is_trail(T, footprint=True) is backs
    assert nav._behind_is_trail(T) is (abs(turned_deg) <= 20.0)


@pytest.mark.parametrize("keep", [True, False])
def test_a_new_route_to_the_same_goal_can_keep_the_time_without_progress(cache_dir, keep: bool) -> None:
    # the robot does not move (held in place): stuck after stuck_timeout_s; a new route 6 s in keeps the clock
    # running with keep_stuck_timer, else it starts it again
    nav = make_nav(cache_dir, stuck_timeout_s=10.0)
    T, route = se2.from_xy_yaw(0.0, 0.0, 0.0), np.array([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    nav.set_waypoints(route)
    stuck = [nav.step(0.05 * k, T, np.zeros((0, 3))).stuck for k in range(120)]
    nav.set_waypoints(route[1:], keep_stuck_timer=keep)
    stuck += [nav.step(0.05 * k, T, np.zeros((0, 3))).stuck for k in range(120, 240)]
    assert not any(stuck[:200])
    assert any(stuck[200:]) is keep  # 10-12 s after the start


@pytest.mark.parametrize(("reapproach_after_s", "person_stays", "back_at_s"),
                         [(8.0, False, 8.0), (None, False, None), (8.0, True, None)])
def test_lined_up_off_its_spot_and_stalled_the_robot_aims_at_the_approach_waypoint_again(
        cache_dir, reapproach_after_s, person_stays, back_at_s) -> None:
    # the approach waypoint (2, 0.5), heading +y, of a 0.8 m doorway (2, 1.1) in a wall along y = 1.1: someone
    # stands beside its spot, so the robot 0.45 m west of it lines up where it is; held there (it finds no way
    # through from there), it aims at the approach waypoint again after reapproach_after_s without progress, once
    # the spot is free, and not while someone still stands on it
    walls = np.vstack([wall(-3.0, 1.1, 1.6, 1.1), wall(2.4, 1.1, 6.0, 1.1)])
    nav = make_nav(cache_dir, reapproach_after_s=reapproach_after_s)
    nav.set_waypoints(np.array([[2.0, 0.5], [2.0, 1.1], [2.0, 2.0]]), allow_skip=np.array([False, False, True]),
                      allowed_distance_m=np.array([0.15, 0.3, 0.3]), headings_rad=np.array([np.pi / 2, np.nan, np.nan]),
                      give_way=np.array([False, True, False]))
    T = se2.from_xy_yaw(1.55, 0.5, np.pi / 2)
    targets = []
    for k in range(240):  # 12 s
        t_s = 0.05 * k
        world = np.vstack([walls, _person(2.2, 0.5)]) if person_stays or t_s < 1.0 else walls
        targets.append(nav.step(t_s, T, np.column_stack([se2.transform_points(se2.inverse(T), world[:, :2]),
                                                         world[:, 2]])).target_index)
    targets = np.array(targets)
    assert targets[:20].max() == 1  # lined up off the spot within the first second
    if back_at_s is None:
        assert np.all(targets[20:] == 1)
    else:
        first = int(np.argmax(targets[20:] == 0)) + 20
        assert targets[first] == 0 and back_at_s <= 0.05 * first <= back_at_s + 1.0
        assert np.all(targets[first:] == 0)  # once: held off it, the robot does not pass it again


@pytest.mark.parametrize("within_view", [True, False])
def test_a_waypoint_is_skipped_to_only_along_paths_a_sensor_sees(cache_dir, within_view) -> None:
    # a 240-degree lidar facing +x, nothing sensed; the route goes 1.5 m ahead, then to waypoints behind the robot
    # on its left: along paths that turn it around into space no sensor sees (where a wall may stand, as in a room
    # the route leaves through a doorway) they are not skipped to
    from simnav.navigation.sensing import ViewSector

    lidar = ViewSector(0.2, 0.0, 0.0, math.radians(120.0), 5.0)
    nav = ReactiveNavigator3D([BASE, MAST], V_MAX, W_MAX, max_acc_m_s2=1.0, max_ang_acc_rad_s2=3.0,
                              config=replace(CONFIG, skip_within_view=within_view), cache_dir=cache_dir, view=[lidar])
    nav.set_waypoints(np.array([[1.5, 0.0], [-1.0, 0.8], [-2.0, 0.8]]), allowed_distance_m=np.array([0.3, 0.3, 0.3]))
    target = nav.step(0.0, np.eye(3), np.zeros((0, 3))).target_index
    assert target == 0 if within_view else target > 0
    nav.set_waypoints(np.array([[1.5, 0.0], [2.5, 0.3], [3.5, 0.3]]), allowed_distance_m=np.array([0.3, 0.3, 0.3]))
    assert nav.step(0.05, np.eye(3), np.zeros((0, 3))).target_index == 1  # ahead, in view: skipped to either way


def test_stalled_the_robot_goes_back_along_its_route_through_the_waypoints_it_lined_up_at(cache_dir) -> None:
    # two waypoints to line up at, 0.4 and 0.55 m ahead (heading +x), both lined up at off their spots while someone
    # stood there, then a doorway; held where it stands, 8 s without progress later the robot aims at the second
    # again and, short of it, at the first right after; without the rule it keeps aiming at the doorway
    def targets(reapproach_after_s):
        nav = make_nav(cache_dir, reapproach_after_s=reapproach_after_s)
        nav.set_waypoints(np.array([[0.4, 0.0], [0.55, 0.0], [1.2, 0.0], [2.5, 0.0]]),
                          allow_skip=np.array([False, False, False, True]), allowed_distance_m=np.array([0.15] * 4),
                          headings_rad=np.array([0.0, 0.0, np.nan, np.nan]),
                          give_way=np.array([False, False, True, False]))
        out = []
        for k in range(300):  # 15 s
            t_s = 0.05 * k
            world = _person(0.6, 0.45) if t_s < 1.0 else np.zeros((0, 3))
            out.append(nav.step(t_s, np.eye(3), world).target_index)
        return np.array(out)

    back = targets(8.0)
    assert back[19] == 2  # both lined up at off their spots within the first second
    first = 20 + int(np.argmax(back[20:] != 2))
    assert back[first] == 1 and 8.0 <= 0.05 * first <= 9.0
    assert np.all(back[first + 1:] == 0)
    assert np.all(targets(None)[19:] == 2)
