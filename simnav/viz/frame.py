"""What the viewer shows: the static scene (:class:`SceneInfo`) and one moment of a run (:class:`VizFrame`).

A frame is taken from a :class:`~simnav.sim.simulator.Simulator` alone (:func:`sim_frame`: robot, people, other
robots, doors, the latest lidar and depth readings), and a mission adds what its navigator decided
(:func:`mission_frame`: estimated pose, obstacle points, chosen PTG path, route). Frames are plain numpy, so the
live viewer, the recorder and the replay all draw from the same data. The PTG path shapes come from the
navigator's settings (:class:`PathFamilies`), so a recording can rebuild them without a navigator.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from simnav.geometry import se2
from simnav.navigation.sensing import SensingConfig, reading_points_base
from simnav.sensors.readings import LaserScan, PointCloud, Reading, RGBDFrame
from simnav.viz.config import VizConfig

if TYPE_CHECKING:
    from simnav.mission.observer import MissionFrame
    from simnav.navigation.navigator import ReactiveNavigator3D
    from simnav.robot.spec import RobotSpec
    from simnav.sim.simulator import Simulator
    from simnav.world.schema import WorldSpec


@dataclass(frozen=True)
class PathFamilies:
    """The navigator's PTGs, by the settings that shape their paths (a navigator or a recording gives them).

    Attributes:
        names: PTG names in the navigator's order (keys of :data:`simnav.navigation.ptgspace.FAMILIES`).
        num_paths: paths per PTG.
        ref_distance_m: horizon, m.
        max_v_m_s, max_w_rad_s: the robot's speed limits the paths are built for.
    """

    names: tuple[str, ...]
    num_paths: int
    ref_distance_m: float
    max_v_m_s: float
    max_w_rad_s: float

    @staticmethod
    def of(navigator: ReactiveNavigator3D) -> PathFamilies:
        cfg = navigator.config
        return PathFamilies(tuple(cfg.ptgs), cfg.num_paths, cfg.ref_distance_m, navigator.max_v_m_s,
                            navigator.max_w_rad_s)

    def fans(self) -> list[PathFan]:
        """The sampled paths of every PTG (integrated once per process and settings)."""
        return list(_fans(self))


@dataclass(frozen=True)
class PathFan:
    """The sampled paths of one PTG in the ``base`` frame at the start of the paths.

    Attributes:
        name: PTG name.
        xy: (N, S, 2) path samples, m (rows padded with their last sample).
        dist_m: (N, S) distance along each path, pseudo-metres (the navigator's metric).
        num_samples: (N,) samples stored per path.
        ref_distance_m: horizon, m.
    """

    name: str
    xy: np.ndarray
    dist_m: np.ndarray
    num_samples: np.ndarray
    ref_distance_m: float

    def path(self, k: int, d_norm: float = 1.0) -> np.ndarray:
        """(M, 2) samples of path ``k`` up to normalised distance ``d_norm`` (at least two), m."""
        return self.xy[k, :self.end(k, d_norm)]

    def end(self, k: int, d_norm: float) -> int:
        """How many samples of path ``k`` lie within normalised distance ``d_norm`` (at least two)."""
        n = int(self.num_samples[k])
        end = int(np.searchsorted(self.dist_m[k, :n], max(d_norm, 0.0) * self.ref_distance_m, side="right"))
        return max(end, 2)


@functools.lru_cache(maxsize=4)
def _fans(families: PathFamilies) -> tuple[PathFan, ...]:
    from simnav.navigation.ptg import PTG, PTGConfig
    from simnav.navigation.ptgspace import FAMILIES

    fans = []
    for name in families.names:
        family, backward = FAMILIES[name]
        ptg = PTG(PTGConfig(family=family, backward=backward, num_paths=families.num_paths,
                            ref_distance_m=families.ref_distance_m, v_max_mps=families.max_v_m_s,
                            w_max_radps=families.max_w_rad_s))
        fans.append(PathFan(name, ptg.poses[..., :2].astype(np.float32), ptg.dist_m, ptg.num_samples.copy(),
                            families.ref_distance_m))
    return tuple(fans)


@dataclass(frozen=True)
class SceneInfo:
    """What does not move, and how many things do.

    Attributes:
        world: the explicit world.
        robot: the robot.
        people: number of pedestrians.
        robots: number of other (wandering) robots.
        paths: the navigator's PTGs (None without a navigator).
    """

    world: WorldSpec
    robot: RobotSpec
    people: int
    robots: int
    paths: PathFamilies | None = None

    @staticmethod
    def of(sim: Simulator, navigator: ReactiveNavigator3D | None = None) -> SceneInfo:
        paths = PathFamilies.of(navigator) if navigator is not None else None
        return SceneInfo(sim.world, sim.robot, sim.crowd.count, sim.wanderers.count, paths)


def _empty() -> np.ndarray:
    return np.zeros((0, 3))


@dataclass(frozen=True)
class VizFrame:
    """One moment of a run, as drawn.

    Attributes:
        time_s: simulation time, s.
        T_world_base: (3, 3) ground-truth SE(2) pose of the robot.
        people: (P, 3) pedestrians as (x m, y m, yaw rad) in the world frame.
        robots: (W, 3) other robots, same layout.
        door_yaws_rad: (D,) heading of each door leaf (hinge to tip) in the world frame, rad.
        scan_base: (N, 3) lidar returns (2D and 3D lidars) in the ``base`` frame of ``T_world_base``, m.
        depth_base: (M, 3) depth-camera points in the same frame, m.
        T_world_est: (3, 3) the pose the navigator used (None without a navigator).
        obstacles_base: (K, 3) the navigator's obstacle points in the ``base`` frame of ``T_world_est``, m.
        ptg: the PTG of the chosen path ('' when none).
        path_index: the chosen path of that PTG (-1 when none).
        free_distance: normalised collision-free distance of the chosen path.
        route_world: (R, 2) the route being followed (last row: the target), m; (0, 2) when none.
    """

    time_s: float
    T_world_base: np.ndarray
    people: np.ndarray
    robots: np.ndarray
    door_yaws_rad: np.ndarray
    scan_base: np.ndarray = field(default_factory=_empty)
    depth_base: np.ndarray = field(default_factory=_empty)
    T_world_est: np.ndarray | None = None
    obstacles_base: np.ndarray = field(default_factory=_empty)
    ptg: str = ""
    path_index: int = -1
    free_distance: float = 0.0
    route_world: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


def decimate(xy: np.ndarray, step_m: float) -> np.ndarray:
    """The rows of a (M, D) polyline about ``step_m`` of arc length apart (the first and last kept), m."""
    return xy[decimated(xy, step_m)]


def decimated(xy: np.ndarray, step_m: float) -> np.ndarray:
    """Indices of the rows :func:`decimate` keeps."""
    if len(xy) <= 2:
        return np.arange(len(xy))
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    keep = np.flatnonzero(np.diff(np.floor(arc / step_m), prepend=-1.0) > 0)
    return keep if keep[-1] == len(xy) - 1 else np.append(keep, len(xy) - 1)


def thin(points: np.ndarray, cap: int) -> np.ndarray:
    """At most ``cap`` rows of ``points``: every n-th, n as small as it can be."""
    if len(points) <= cap:
        return points
    if cap <= 0:
        return points[:0]
    return points[::-(-len(points) // cap)]


class LatestReadings:
    """The most recent range reading of every sensor (what a viewer draws at its next update)."""

    def __init__(self) -> None:
        self._latest: dict[str, Reading] = {}

    def add(self, readings: Iterable[Reading]) -> None:
        for reading in readings:
            if isinstance(reading, LaserScan | PointCloud | RGBDFrame):
                self._latest[reading.sensor] = reading

    def clear(self) -> None:
        self._latest.clear()

    def points_base(self, config: VizConfig) -> tuple[np.ndarray, np.ndarray]:
        """(lidar (N, 3), depth (M, 3)) points in the ``base`` frame at each reading's stamp, thinned, m."""
        sensing = SensingConfig(depth_stride=config.depth_stride, max_age_s=float("inf"))
        scans, depth = [], []
        for reading in self._latest.values():
            pts = reading_points_base(reading, sensing)
            if pts is not None and len(pts):
                (depth if isinstance(reading, RGBDFrame) else scans).append(pts)
        return (thin(np.concatenate(scans), config.max_scan_points) if scans else _empty(),
                thin(np.concatenate(depth), config.max_depth_points) if depth else _empty())


def sim_frame(sim: Simulator, readings: LatestReadings | None = None, config: VizConfig | None = None) -> VizFrame:
    """The simulator's state now: robot, people, other robots, doors and (optionally) the latest readings."""
    config = config or VizConfig()
    scan, depth = readings.points_base(config) if readings is not None else (_empty(), _empty())
    crowd, wanderers = sim.crowd, sim.wanderers
    return VizFrame(
        time_s=sim.time_s,
        T_world_base=se2.from_se3(sim.T_world_base),
        people=np.column_stack([crowd.positions_xy, crowd.yaws_rad]),
        robots=np.column_stack([wanderers.positions_xy, wanderers.yaws_rad]),
        door_yaws_rad=np.array([door.yaw_rad for door in sim.doors]),
        scan_base=scan,
        depth_base=depth,
    )


def mission_frame(sim: Simulator, frame: MissionFrame, readings: LatestReadings | None = None,
                  config: VizConfig | None = None) -> VizFrame:
    """:func:`sim_frame` plus what the mission's navigator saw and decided in ``frame``."""
    config = config or VizConfig()
    base = sim_frame(sim, readings, config)
    cmd = frame.command
    return VizFrame(
        time_s=frame.time_s,
        T_world_base=np.asarray(frame.T_world_base, dtype=np.float64),
        people=base.people,
        robots=base.robots,
        door_yaws_rad=base.door_yaws_rad,
        scan_base=base.scan_base,
        depth_base=base.depth_base,
        T_world_est=np.asarray(frame.T_world_est, dtype=np.float64),
        obstacles_base=thin(np.asarray(frame.points_base, dtype=np.float64).reshape(-1, 3),
                            config.max_obstacle_points),
        ptg=cmd.ptg,
        path_index=cmd.path_index,
        free_distance=cmd.free_distance,
        route_world=np.asarray(frame.waypoints_world, dtype=np.float64).reshape(-1, 2),
    )
