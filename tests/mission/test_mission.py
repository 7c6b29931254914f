"""`simnav mission`: a headless navigation mission writes a valid report, and the same seed gives the same mission."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from simnav.io import read_tum
from simnav.mission.mission import (
    NAV_LOG_COLUMNS,
    MissionSettings,
    mission_robot,
    navigator_config,
    resume_route,
    run_mission,
)
from simnav.navigation.memory import MemoryConfig
from simnav.navigation.navigator import STATES, NavigatorConfig
from simnav.robot import load_robot
from simnav.world import load_world

QUIET = ["--world", "polygonal", "--agents", "0", "--robots", "0", "--targets", "2", "--seed", "3"]
REPORT_KEYS = {"simnav_version", "world", "robot", "seed", "nav", "pose_source", "people", "targets_requested",
               "targets_reached", "success_rate", "distance_m", "duration_s", "avg_speed_m_s", "max_speed_m_s",
               "minor_incidents", "interventions", "replans", "min_clearance_m", "path_length_ratio",
               "navigator_step_ms", "real_time_factor", "wall_time_s", "odometry", "targets", "incidents",
               "intervention_log", "state_time_s"}


def simnav(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "simnav.cli", *args], capture_output=True, text=True, timeout=600)


def test_a_short_mission_writes_a_valid_report_trajectories_and_plot(tmp_path):
    out = tmp_path / "run"
    result = simnav("mission", *QUIET, "--out", str(out))
    assert result.returncode == 0, result.stderr
    report = json.loads((out / "report.json").read_text())
    assert REPORT_KEYS <= set(report)
    assert report["targets_requested"] == 2 and report["targets_reached"] == 2
    assert report["interventions"] == 0 and report["minor_incidents"]["total"] == 0
    assert report["distance_m"] > 2.0 and 0 < report["avg_speed_m_s"] <= report["max_speed_m_s"] <= 0.75
    assert report["min_clearance_m"] > 0.05
    assert report["navigator_step_ms"]["median"] > 0
    assert [set(row) >= {"reached", "time_s", "distance_m", "shortest_m", "path_length_ratio"}
            for row in report["targets"]] == [True, True]
    gt = read_tum(out / "trajectory_gt.txt")
    assert len(gt) > 10 and gt.stamps_s[-1] == pytest.approx(report["duration_s"], abs=0.06)
    assert len(read_tum(out / "trajectory_est.txt")) == len(gt)
    assert (out / "mission.png").stat().st_size > 10_000
    assert "targets reached" in result.stdout
    # the navigator's log: a row per control step, and the time per state adds up to the mission's
    log = np.genfromtxt(out / "navigation.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
    assert set(NAV_LOG_COLUMNS) == set(log.dtype.names) and len(log) == len(gt) - 1
    assert {"navigating", "reached"} <= set(log["state"]) <= set(STATES)
    assert np.allclose(np.column_stack([log["x_m"], log["y_m"]])[0], gt.T[0][:2, 3], atol=1e-4)
    assert sum(report["state_time_s"].values()) == pytest.approx(report["duration_s"], abs=0.06)
    assert report["state_time_s"]["navigating"] > 0.5 * report["duration_s"]


def test_the_same_seed_gives_the_same_mission():
    world, robot = load_world("polygonal"), load_robot("giraff")
    settings = MissionSettings(targets=1, seed=5, sim={"pedestrians": 2, "wanderers": 0})
    runs = [run_mission(world, mission_robot(robot, settings), settings) for _ in range(2)]
    a, b = (r.targets[0] for r in runs)
    assert (a.node, a.reached, a.time_s) == (b.node, b.reached, b.time_s)
    assert runs[0].distance_m == runs[1].distance_m
    assert runs[0].minor_incidents == runs[1].minor_incidents


def test_an_odometry_pose_source_reports_its_drift(tmp_path):
    world, robot = load_world("polygonal"), load_robot("giraff")
    settings = MissionSettings(targets=1, seed=2, pose_source="wheels", sim={"pedestrians": 0, "wanderers": 0})
    report = run_mission(world, mission_robot(robot, settings), settings)
    assert report.odometry is not None and report.odometry["source"] == "wheels"
    assert np.isfinite(report.odometry["rpe"]["trans_rmse_cm_s"])
    assert 0 <= report.odometry["final_error_m"] < 0.5


@pytest.mark.parametrize(("args", "message"), [
    (["--pose-source", "sonar"], "unknown pose source 'sonar'"),
    (["--nav", "4d"], "--nav must be 3d or 2d"),
    (["--keep-right", "3"], "--keep-right"),
    (["--world", "atlantis"], "unknown world 'atlantis'"),
    (["--nav-set", "limit_to_sight=true"], "unknown field(s) limit_to_sight"),
    (["--nav-set", "secure_distance_m=9"], "secure_distance_m must be in [0, ref_distance_m)"),
    (["--nav-set", "memory_config.half_life_s=3"], "memory_config: unknown field(s) half_life_s"),
    (["--nav-set", "memory_config.decay_s=0"], "decay_s must be > 0"),
    (["--nav-set", "memory_config=3"], "memory_config takes fields"),
    (["--nav-set", "num_paths=121.5"], "num_paths takes a whole number, got 121.5"),
    (["--nav-set", "limit_to_view=1"], "limit_to_view takes true or false, got 1"),
    (["--nav-set", "nd_crowded_floor_ratio=abc"], "nd_crowded_floor_ratio takes a number or null, got 'abc'"),
    (["--nav-set", "nd_crowded_floor_ratio=-1"], "nd_crowded_floor_ratio must be None or in (0, 1], got -1"),
    (["--nav-set", "holonomic=bogus"], "holonomic must be one of nd, vff, got 'bogus'"),
    (["--nav-set", "memory_config.decay_s=[1, 2]"], "memory_config.decay_s: expected one value"),
])
def test_bad_options_are_one_clear_error(args, message):
    result = simnav("mission", "--targets", "1", *args)
    assert result.returncode == 2
    assert message in result.stderr
    assert result.stderr.count("simnav mission:") <= 1  # one error, not one per type the value could have had
    assert "Traceback" not in result.stderr + result.stdout


class _Watcher:
    """Records what a mission shows its observers."""

    def __init__(self) -> None:
        self.calls: list[str] = []
        self.frames = []

    def start(self, world, robot, sim, navigator) -> None:
        self.calls.append("start")
        self.sim = sim

    def step(self, frame) -> None:
        self.frames.append(frame)

    def finish(self, report) -> None:
        self.calls.append("finish")
        self.report = report


class _CountingRobot:
    """The simulated robot, counting the commands it gets (a robot factory's product)."""

    def __init__(self, sim) -> None:
        from simnav.sim.robot import SimRobot

        self.inner, self.sent, self.closed = SimRobot(sim), 0, False
        self.control_period_s = self.inner.control_period_s

    def now_s(self):
        return self.inner.now_s()

    def send_velocity(self, v_m_s, w_rad_s):
        self.sent += 1
        self.inner.send_velocity(v_m_s, w_rad_s)

    def poll_readings(self):
        return self.inner.poll_readings()

    def wait_next_period(self):
        self.inner.wait_next_period()

    def stop(self):
        self.inner.stop()

    def close(self):
        self.closed = True


def test_observers_see_every_step_and_the_robot_factory_drives_the_mission():
    world, robot = load_world("polygonal"), load_robot("giraff")
    settings = MissionSettings(targets=1, seed=3, sim={"pedestrians": 0, "wanderers": 0})
    watcher, robots = _Watcher(), []

    def factory(sim):
        robots.append(_CountingRobot(sim))
        return robots[0]

    report = run_mission(world, mission_robot(robot, settings), settings, observers=[watcher], robot_factory=factory)
    assert report.targets_reached == 1
    assert watcher.calls == ["start", "finish"] and watcher.report is report
    frames = watcher.frames
    assert len(frames) == robots[0].sent > 10 and robots[0].closed
    assert np.all(np.diff([f.time_s for f in frames]) > 0)
    assert frames[-1].time_s == pytest.approx(report.duration_s)
    last = frames[-1]
    assert last.T_world_base.shape == (3, 3) and last.T_world_est.shape == (3, 3)
    assert np.allclose(last.waypoints_world[-1], [report.targets[0].x_m, report.targets[0].y_m])
    assert last.points_base.ndim == 2 and last.points_base.shape[1] == 3
    assert sum(len(f.readings) for f in frames) > len(frames)  # lidar, wheels, ...
    assert any(f.command.state == "navigating" for f in frames)


def test_a_doorway_on_the_route_is_lined_up_before_and_passed_through():
    from simnav.mission.mission import (
        DOOR_APPROACH_M,
        DOOR_APPROACH_TOLERANCE_M,
        NARROW_NODE_TOLERANCE_M,
        route_waypoints,
    )

    nodes = np.array([[0.0, 0.0], [3.0, -2.0], [3.0, 0.0], [3.0, 2.0], [3.0, 2.5]])  # node 2: a doorway
    narrow = np.array([False, False, True, False, False])
    xy, skip, near, heading, doorway = route_waypoints(nodes, [0, 1, 2, 3, 4], narrow, 1.0)
    np.testing.assert_allclose(xy, [[0, 0], [3, -2], [3, -DOOR_APPROACH_M], [3, 0], [3, DOOR_APPROACH_M], [3, 2],
                                    [3, 2.5]])
    assert skip.tolist() == [True, True, False, False, True, True, True]
    # the nodes before and after the doorway are passed close by (or cut once a later waypoint is reachable)
    assert near.tolist() == [1.0, NARROW_NODE_TOLERANCE_M, DOOR_APPROACH_TOLERANCE_M] + [NARROW_NODE_TOLERANCE_M] * 3 \
        + [1.0]
    # the approach waypoint is passed facing the doorway (+y); the others at any heading
    np.testing.assert_allclose(heading[2], np.pi / 2)
    assert np.isnan(np.delete(heading, 2)).all()
    assert doorway.tolist() == [False, False, False, True, False, False, False]  # the navigator yields there
    # at most half way to a close neighbour; a route starting in the doorway has no approach before it
    xy, skip, _, heading, _ = route_waypoints(nodes, [2, 3, 4], narrow, 1.0)
    np.testing.assert_allclose(xy, [[3, 0], [3, DOOR_APPROACH_M], [3, 2], [3, 2.5]])
    assert np.isnan(heading).all()
    xy, _, _, heading, _ = route_waypoints(nodes, [4, 3, 2], np.array([False, False, False, True, False]), 1.0)
    np.testing.assert_allclose(xy, [[3, 2.5], [3, 2.25], [3, 2], [3, 2 - DOOR_APPROACH_M], [3, 0]])
    np.testing.assert_allclose(heading[1], -np.pi / 2)


def test_a_doorway_of_two_narrow_nodes_is_approached_along_its_axis():
    from simnav.mission.mission import DOOR_APPROACH_M, doorway_axis_approaches, route_waypoints

    # the office's north-east doorway: narrow nodes (0, 0) in the wall and (0, 0.75) inside the room, the room's
    # node diagonally beyond; the open leaf's tip at (0.5, 1.0)
    nodes = np.array([[0.0, -1.0], [0.0, 0.0], [0.0, 0.75], [1.5, 2.5]])
    narrow = np.array([False, True, True, False])
    edges = [(0, 1), (1, 2), (2, 3)]
    tip = np.array([0.5, 1.0])
    approaches = doorway_axis_approaches(nodes, edges, narrow, lambda xy: np.linalg.norm(xy - tip, axis=1) - 0.42)
    np.testing.assert_allclose(approaches[(2, 1)], [0.0, 0.75 + DOOR_APPROACH_M])
    np.testing.assert_allclose(approaches[(1, 2)], [0.0, -DOOR_APPROACH_M])
    xy, _, _, heading, _ = route_waypoints(nodes, [3, 2, 1, 0], narrow, 1.0, axis_approach=approaches)
    np.testing.assert_allclose(xy[1], [0.0, 0.75 + DOOR_APPROACH_M])  # on the axis, 0.6 m from the tip
    np.testing.assert_allclose(heading[1], -np.pi / 2)  # facing straight through
    # without it, towards the room's node: 0.2 m from the leaf's tip, where the robot found no path past it
    xy, _, _, heading, _ = route_waypoints(nodes, [3, 2, 1, 0], narrow, 1.0)
    assert np.linalg.norm(xy[1] - tip) < 0.25 and abs(heading[1] + np.pi / 2) > 0.5
    # an axis point without room to turn (here: the tip closer) is left out, and the old approach taken
    cramped = doorway_axis_approaches(nodes, edges, narrow, lambda xy: np.linalg.norm(xy - tip, axis=1) - 1.0)
    assert (2, 1) not in cramped
    # nor is one beyond half way to the previous node
    close = nodes.copy()
    close[3] = [0.3, 1.5]
    xy, _, _, _, _ = route_waypoints(close, [3, 2, 1, 0], narrow, 1.0, axis_approach=approaches)
    assert np.linalg.norm(xy[1] - close[2]) < DOOR_APPROACH_M


def test_the_hallway_outside_a_doorway_is_reached_close_by_where_the_route_turns():
    from simnav.mission.mission import DOOR_APPROACH_TOLERANCE_M, NARROW_NODE_TOLERANCE_M, route_waypoints

    # a room (node 0), its doorway (1), the 1 m hallway below it (2), along the hallway (3, 4)
    nodes = np.array([[0.0, 2.0], [0.0, 0.55], [0.0, 0.0], [2.0, 0.0], [4.0, 0.0]])
    narrow = np.array([False, True, True, True, False])
    turnable = np.array([True, False, True, True, True])  # no room to turn in place in the doorway

    def tolerance_at(route, xy_m, turnable=turnable):
        xy, _, near, _, _ = route_waypoints(nodes, route, narrow, 1.0, turnable)
        (i,) = np.flatnonzero(np.all(np.isclose(xy, xy_m), axis=1))
        return near[i]

    # out of the doorway, then turning along the hallway: the hallway's middle is reached close by
    assert tolerance_at([0, 1, 2, 3, 4], [0.0, 0.0]) == DOOR_APPROACH_TOLERANCE_M
    assert tolerance_at([0, 1, 2, 3, 4], [2.0, 0.0]) == NARROW_NODE_TOLERANCE_M  # further along: as before
    # along the hallway and turning into the doorway: lined up there too (see the next test); nothing known about
    # where the robot can turn: as before
    assert tolerance_at([4, 3, 2, 1, 0], [0.0, 0.0]) == DOOR_APPROACH_TOLERANCE_M
    assert tolerance_at([0, 1, 2, 3, 4], [0.0, 0.0], None) == NARROW_NODE_TOLERANCE_M


def test_a_doorway_close_beside_a_narrow_hallway_is_lined_up_where_the_robot_can_turn():
    from simnav.mission.mission import DOOR_APPROACH_TOLERANCE_M, route_waypoints

    # along a 1 m hallway (nodes 0, 1), turning at node 1 into the doorway 0.55 m beside it (2), into the room (3)
    nodes = np.array([[-2.0, 0.0], [0.0, 0.0], [0.0, 0.55], [0.0, 2.0]])
    narrow = np.array([True, True, True, False])
    turnable = np.array([True, True, False, True])
    xy, skip, near, heading, _ = route_waypoints(nodes, [0, 1, 2, 3], narrow, 1.0, turnable)
    # the robot lines up at the hallway node, facing the doorway, not half way to it (no room to turn there)
    (i,) = np.flatnonzero(np.all(np.isclose(xy, [0.0, 0.0]), axis=1))
    assert near[i] == DOOR_APPROACH_TOLERANCE_M and not skip[i]
    np.testing.assert_allclose(heading[i], np.pi / 2)
    assert not np.any(skip[i:i + 2])  # then straight on through the approach waypoint, nothing left to cut
    np.testing.assert_allclose(xy[i + 1], [0.0, 0.275])
    # a doorway far enough from the hallway node, one where the robot can turn, or going on straight: as before
    far = nodes * [1.0, 3.0]
    xy, _, _, heading, _ = route_waypoints(far, [0, 1, 2, 3], narrow, 1.0, turnable)
    assert np.isnan(heading[np.flatnonzero(np.all(np.isclose(xy, [0.0, 0.0]), axis=1))[0]])
    for fit, route in ((np.ones(4, dtype=bool), [0, 1, 2, 3]), (turnable, [3, 2, 1, 0])):
        xy, _, _, heading, _ = route_waypoints(nodes, route, narrow, 1.0, fit)
        assert np.isnan(heading[np.flatnonzero(np.all(np.isclose(xy, nodes[1]), axis=1))[0]])


def test_the_route_keeps_to_the_right_where_it_goes_on_straight_between_wide_nodes():
    from simnav.mission.mission import route_waypoints

    # a corridor along +x (nodes 0-3), a room off it at node 2 (node 4, through the doorway 5)
    nodes = np.array([[0.0, 0.0], [2.0, 0.0], [4.0, 0.0], [6.0, 0.0], [4.0, 3.0], [4.0, 1.0]])
    narrow = np.array([False, False, False, False, False, True])
    room = np.array([0.4, 0.4, 0.4, 0.25, 0.4, 0.0])  # node 3 is near a pillar
    xy, *_ = route_waypoints(nodes, [0, 1, 2, 3], narrow, 1.0, None, room)
    np.testing.assert_allclose(xy, [[0, 0], [2, -0.4], [4, -0.4], [6, 0]])  # ends where they are; right of +x
    xy, *_ = route_waypoints(nodes, [3, 2, 1, 0], narrow, 1.0, None, room)
    np.testing.assert_allclose(xy, [[6, 0], [4, 0.4], [2, 0.4], [0, 0]])  # heading -x: right is +y
    # turning at node 2 into the doorway: node 2 stays where it is (the doorway is lined up from there)
    xy, *_ = route_waypoints(nodes, [0, 1, 2, 5, 4], narrow, 1.0, None, room)
    np.testing.assert_allclose(xy[:3], [[0, 0], [2, -0.4], [4, 0]])
    xy, *_ = route_waypoints(nodes, [0, 1, 2, 3], narrow, 1.0)  # not asked for: on the roadmap
    np.testing.assert_allclose(xy, nodes[:4])


def test_an_intervention_sets_the_robot_down_past_doorways():
    narrow = np.zeros(10, dtype=bool)
    narrow[[5, 6]] = True  # a doorway and the node inside it
    route = [1, 2, 5, 6, 7, 8]
    assert resume_route(route, 0, narrow) == [2, 5, 6, 7, 8]
    assert resume_route(route, 1, narrow) == [7, 8]   # not into the doorway
    assert resume_route(route, 5, narrow) == [8]      # at the goal: stays there
    assert resume_route([1, 5, 6], 0, narrow) == [6]  # nothing but doorways left: the goal
    taken = np.zeros(10, dtype=bool)
    taken[7] = True  # someone stands there
    assert resume_route(route, 1, narrow, taken) == [8]
    assert resume_route(route, 0, narrow, taken) == [2, 5, 6, 7, 8]


def test_an_intervention_does_not_set_the_robot_down_on_people():
    from simnav.mission.mission import SET_DOWN_CLEARANCE_M, _MissionRunner

    settings = MissionSettings(targets=1, seed=3)
    runner = _MissionRunner(load_world("office"), mission_robot(load_robot("giraff"), settings), settings, None)
    route = runner._new_target()
    nodes = runner.sim.roadmap.nodes_xy
    # people stand on every node of the route after the first, the goal included
    crowd = runner.sim.crowd
    for i, node in enumerate(route[1:crowd.count + 1]):
        crowd._pos[i] = nodes[node]
    remaining = runner._intervene(runner.report.targets[-1], route)
    xy = runner._true_pose()[:2, 2]
    gap = np.linalg.norm(crowd.positions_xy - xy, axis=1).min()
    assert gap >= runner._circumradius_m + crowd.radius_m + SET_DOWN_CLEARANCE_M - 1e-9
    assert remaining[-1] == route[-1]  # still on its way to the same goal
    assert runner.report.interventions == 1


def test_targets_are_never_drawn_in_a_doors_swing():
    # the office's room nodes 0.9 m from a hinge lie in the area the leaf sweeps: a robot waiting there keeps the
    # door open, and the open leaf keeps the spot taken
    from simnav.mission.mission import _MissionRunner
    from simnav.world.footprint import door_swing_distance_m

    settings = MissionSettings(targets=1, seed=5)
    world = load_world("office")
    runner = _MissionRunner(world, mission_robot(load_robot("giraff"), settings), settings, None)
    try:
        nodes = runner.sim.roadmap.nodes_xy
        in_swing = door_swing_distance_m(world, nodes) < runner._circumradius_m
        assert 0 < in_swing.sum() < len(nodes)
        drawn = {runner._random_target(0) for _ in range(300)}
        assert not any(in_swing[list(drawn)])
        assert len(drawn) >= (~(runner._narrow | in_swing)).sum() - 2  # every other node can be drawn
    finally:
        runner.close()


def test_navigator_options_reach_the_missions_navigator():
    settings = MissionSettings(targets=1, memory=False, navigator={"limit_to_view": True, "secure_distance_m": 0.2,
                                                                   "memory_config": {"decay_s": 10}})
    config = navigator_config(settings)
    assert (config.limit_to_view, config.secure_distance_m, config.memory) == (True, 0.2, False)
    assert config.memory_config == MemoryConfig(decay_s=10.0)
    assert navigator_config(MissionSettings(targets=1)) == NavigatorConfig()


def test_navigator_options_take_words_numbers_and_null():
    settings = MissionSettings(targets=1, navigator={"holonomic": "vff", "num_paths": 61, "ref_distance_m": 4,
                                                     "nd_crowded_floor_ratio": None})
    config = navigator_config(settings)
    assert (config.holonomic, config.num_paths, config.ref_distance_m, config.nd_crowded_floor_ratio) == \
        ("vff", 61, 4, None)


def test_settings_errors_name_the_field_once_without_pydantic_prefixes():
    from simnav.config import validate
    from simnav.errors import ConfigError

    with pytest.raises(ConfigError) as root:
        validate(MissionSettings, {"targets": None}, "mission.yaml")
    assert str(root.value) == "mission.yaml: give targets or duration_s"  # a whole-model check names no field
    with pytest.raises(ConfigError) as bad:
        validate(MissionSettings, {"targets": 1, "navigator": {"num_paths": [1]}}, "mission.yaml")
    assert str(bad.value) == ("mission.yaml: field 'navigator': num_paths: expected one value (true/false, a number, "
                              "a word or null), got [1]")


def _lost_in_a_room(replan_after_s: float | None, seconds: float = 120.0):
    """The office without people; the robot stands in the south room west of x = 10 m, at (8, -2) facing east, and
    is handed a route along the corridor beyond the room's wall (from the corridor node nearest (7, 0) to the one
    nearest (12, 0)). Returns the runner, the route's goal node and the last command."""
    from simnav.mission.mission import _MissionRunner

    settings = MissionSettings(targets=1, seed=3, replan_after_s=replan_after_s, sim={"pedestrians": 0, "wanderers": 0})
    runner = _MissionRunner(load_world("office"), mission_robot(load_robot("giraff"), settings), settings, None)
    graph = runner.sim.roadmap
    route = graph.shortest_path(graph.nearest_node(np.array([7.0, 0.0])), graph.nearest_node(np.array([12.0, 0.0])))
    runner.sim.teleport(8.0, -2.0, 0.0)
    runner.pose.anchor(runner.sim.time_s, runner._true_pose())
    runner._follow(route)
    while runner.sim.time_s < seconds:
        cmd = runner._control_step()
        if cmd.state == "reached" or cmd.stuck:
            break
        route = runner._replan_if_off_route(cmd, route)
    return runner, route[-1], cmd


def test_a_robot_off_its_route_behind_a_wall_is_given_a_new_route():
    # the route's waypoints lie in the corridor beyond the room's wall: the navigator alone follows the wall
    # inside the room and is stuck
    runner, goal, cmd = _lost_in_a_room(None)
    assert cmd.stuck and runner.report.replans == 0
    # re-planned from the nearest roadmap node in sight, it leaves the room through its doorway and gets there
    runner, goal, cmd = _lost_in_a_room(3.0)
    assert cmd.state == "reached" and runner.report.replans >= 1
    assert np.linalg.norm(runner._true_pose()[:2, 2] - runner.sim.roadmap.nodes_xy[goal]) < 0.5


def test_the_line_of_sight_test_crosses_segments_and_their_ends():
    from simnav.mission.mission import in_sight, wall_segments

    wall = np.array([[[0.0, -1.0], [0.0, 1.0]]])
    points = np.array([[1.0, 0.0], [-0.5, 3.0], [1.0, 1.5], [1.0, 2.0], [1.0, 3.0]])
    np.testing.assert_array_equal(in_sight(np.array([-1.0, 0.0]), points, wall), [False, True, False, False, True])
    segments = wall_segments(load_world("office"))
    assert segments.shape[1:] == (2, 2) and len(segments) > 10
    # the corridor's south wall between the rooms hides the corridor from the room below it
    assert not in_sight(np.array([8.0, -2.0]), np.array([[8.0, 0.0]]), segments)[0]
    assert in_sight(np.array([8.0, -0.5]), np.array([[12.0, 0.0]]), segments)[0]
