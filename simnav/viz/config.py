"""Options of the viewer, the recorder and the replay; the defaults are the product."""

from __future__ import annotations

import math
from dataclasses import dataclass

from simnav.errors import ConfigError


@dataclass(frozen=True)
class VizConfig:
    """What is drawn, how often, and how much of it.

    Attributes:
        rate_hz: visual updates (live view, recording, replay keyframes) per simulated second.
        points_rate_hz: point clouds (lidar, depth, obstacles) per simulated second in recordings and replays
            (the live view sends them with every update).
        record_max_points: points kept per cloud (lidar, depth, obstacles) in a recording and its replay.
        max_scan_points: lidar returns drawn per update, evenly thinned.
        max_depth_points: depth-camera points drawn per update, evenly thinned.
        max_obstacle_points: the navigator's obstacle points drawn per update, evenly thinned.
        depth_stride: every n-th row and column of a depth image is back-projected before thinning.
        point_size_m: size of a drawn point, m.
        path_stride: every n-th path of each PTG is drawn in the candidate fan.
        path_step_m: drawn paths keep one sample per this much arc length, m.
        trail_step_m: the live view extends a trajectory trail once the pose has moved this far, m.
        trail_chunk: trajectory trail points per line object in the live view (a full chunk is never re-sent).
        follow_robot: the camera's orbit centre follows the robot (live and replay); else it is the building's centre.
        camera_offset_m: the camera's position relative to its orbit centre, world axes (x, y, z), m.
        camera_fov_deg: the camera's vertical field of view (a narrow one keeps people upright at the edges), deg.
        max_pending: live commands the server may still owe a reply for before updates are skipped: a slow or
            stopped viewer drops frames, it never slows the simulation.
        timeout_s: how long to wait for a meshcat server to start, answer or finish a scene, s.
        replay_max_frames: keyframes of a replay at most (a longer recording is thinned evenly).
        replay_max_point_frames: point-cloud keyframes of a replay at most.
    """

    rate_hz: float = 10.0
    points_rate_hz: float = 1.0
    record_max_points: int = 200
    max_scan_points: int = 360
    max_depth_points: int = 600
    max_obstacle_points: int = 600
    depth_stride: int = 8
    point_size_m: float = 0.04
    path_stride: int = 10
    path_step_m: float = 0.08
    trail_step_m: float = 0.15
    trail_chunk: int = 100
    follow_robot: bool = True
    camera_offset_m: tuple[float, float, float] = (-1.0, -2.8, 17.0)
    camera_fov_deg: float = 40.0
    max_pending: int = 400
    timeout_s: float = 20.0
    replay_max_frames: int = 3000
    replay_max_point_frames: int = 200

    def __post_init__(self) -> None:
        checks = [
            (math.isfinite(self.rate_hz) and 0 < self.rate_hz <= 1000, "rate_hz must be in (0, 1000]"),
            (math.isfinite(self.points_rate_hz) and 0 < self.points_rate_hz <= self.rate_hz,
             "points_rate_hz must be in (0, rate_hz]"),
            (min(self.max_scan_points, self.max_depth_points, self.max_obstacle_points, self.record_max_points) >= 0,
             "max_*_points must be >= 0"),
            (self.depth_stride >= 1 and self.path_stride >= 1, "depth_stride and path_stride must be >= 1"),
            (0 < self.camera_fov_deg < 180, "camera_fov_deg must be in (0, 180)"),
            (min(self.point_size_m, self.path_step_m, self.trail_step_m) > 0,
             "point_size_m, path_step_m and trail_step_m must be > 0"),
            (self.trail_chunk >= 2, "trail_chunk must be >= 2"),
            (self.max_pending >= 1 and self.timeout_s > 0, "max_pending must be >= 1 and timeout_s > 0"),
            (self.replay_max_frames >= 2 and self.replay_max_point_frames >= 1,
             "replay_max_frames must be >= 2 and replay_max_point_frames >= 1"),
        ]
        for ok, message in checks:
            if not ok:
                raise ConfigError(f"VizConfig: {message}")
