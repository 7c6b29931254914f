"""Replays of a recording: a meshcat animation, served live or saved as one self-contained HTML page.

The scene is the live view's (:func:`simnav.viz.draw.scene_commands`); the motion is a meshcat animation with
play / pause / time controls: keyframed poses of the robot, the estimate, the people, the other robots, the doors
and of the whole scene (so that the camera follows the robot); point clouds, chosen paths and routes are objects of
their own that the animation shows and hides in turn. Trails are drawn whole. The HTML page comes from a private
meshcat server (meshcat's static HTML: the viewer's JavaScript and every command inline), so it opens offline and
can be mailed.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from simnav.viz import style
from simnav.viz.commands import (
    Command,
    Track,
    line_object,
    mesh_object,
    points_object,
    pose_xy_yaw,
    set_animation,
    set_object,
    set_transform,
    transform_tracks,
    visibility_track,
)
from simnav.viz.config import VizConfig
from simnav.viz.draw import (
    NAV,
    PATH_HEIGHT_M,
    ROBOT,
    ROOT,
    TRAIL_HEIGHT_M,
    band_colors,
    chosen_path_object,
    door_path,
    person_path,
    scene_commands,
    wanderer_path,
)
from simnav.viz.frame import PathFan
from simnav.viz.meshes import target_mesh
from simnav.viz.recording import Recording
from simnav.viz.server import meshcat_connection

log = logging.getLogger(__name__)
REPLAY = f"{ROOT}/replay"


def replay_commands(recording: Recording, config: VizConfig | None = None) -> list[Command]:
    """The scene of a recording and its animation (times in seconds from the first frame)."""
    config = config or VizConfig()
    fans = recording.scene.paths.fans() if recording.scene.paths is not None else []
    commands = scene_commands(recording.scene, config, fans)
    if len(recording.times_s) == 0:
        return commands
    keys = _thin_indices(len(recording.times_s), config.replay_max_frames)
    times = recording.times_s - recording.times_s[0]
    end_s = float(times[-1])
    tracks: dict[str, list[Track]] = {}
    _pose_tracks(recording, keys, times, config, tracks)
    commands += _trail_commands(recording)
    commands += _point_commands(recording, times, end_s, config, tracks)
    commands += _chosen_commands(recording, fans, keys, times, end_s, config, tracks)
    commands += _route_commands(recording, float(recording.times_s[0]), end_s, tracks)
    commands.append(set_animation(tracks, play=True, repetitions=1))
    return commands


def _thin_indices(n: int, cap: int) -> np.ndarray:
    return np.unique(np.linspace(0, n - 1, min(n, cap)).round().astype(np.int64))


def _poses(xyyaw: np.ndarray) -> np.ndarray:
    return np.array([pose_xy_yaw(x, y, yaw) for x, y, yaw in xyyaw.tolist()]).reshape(-1, 4, 4)


def _pose_tracks(rec: Recording, keys: np.ndarray, times: np.ndarray, config: VizConfig,
                 tracks: dict[str, list[Track]]) -> None:
    """Keyframed poses of the robot, the estimate, people, other robots, doors and the scene shift."""
    t = times[keys]
    tracks[ROBOT] = transform_tracks(t, _poses(rec.base_xyyaw[keys]))
    if np.isfinite(rec.est_xyyaw).all():
        tracks[NAV] = transform_tracks(t, _poses(rec.est_xyyaw[keys]))
    for i in range(rec.people.shape[1]):
        tracks[person_path(i)] = transform_tracks(t, _poses(rec.people[keys, i].astype(np.float64)))
    for i in range(rec.robots.shape[1]):
        tracks[wanderer_path(i)] = transform_tracks(t, _poses(rec.robots[keys, i].astype(np.float64)))
    for i, door in enumerate(rec.scene.world.doors):
        yaws = rec.door_yaws_rad[keys, i].astype(np.float64)
        xyyaw = np.column_stack([np.full(len(yaws), door.hinge[0]), np.full(len(yaws), door.hinge[1]), yaws])
        tracks[door_path(i)] = transform_tracks(t, _poses(xyyaw))
    if config.follow_robot:
        shift = -rec.base_xyyaw[keys].astype(np.float64)
        shift[:, 2] = 0.0
        tracks[ROOT] = transform_tracks(t, _poses(shift))


def _trail_commands(rec: Recording) -> list[Command]:
    """The whole ground-truth and estimated trajectories."""
    out = []
    for name, xyyaw, color in (("gt", rec.base_xyyaw, style.GT_TRAIL_COLOR),
                               ("est", rec.est_xyyaw, style.EST_TRAIL_COLOR)):
        xy = xyyaw[np.isfinite(xyyaw).all(axis=1), :2]
        if len(xy) >= 2:
            line = np.column_stack([xy, np.full(len(xy), TRAIL_HEIGHT_M)])
            out.append(set_object(f"{ROOT}/trails/{name}/c0", line_object(line, color)))
    return out


def _shown_during(tracks: dict[str, list[Track]], path: str, start_s: float, stop_s: float, end_s: float) -> None:
    """Animate a node visible from ``start_s`` until ``stop_s`` (every clip lasts until ``end_s``).

    The node's own ``visible`` is left alone: three.js writes an animated property only when its value changes,
    so a node hidden by a command and animated as visible from the start would never appear."""
    times, visible = [0.0, start_s, stop_s, end_s], [start_s <= 0.0, True, stop_s >= end_s, stop_s >= end_s]
    keep = [0] + [i for i in range(1, 4) if times[i] > times[i - 1]]
    tracks[path] = [visibility_track([times[i] for i in keep], [visible[i] for i in keep])]


def _point_commands(rec: Recording, times: np.ndarray, end_s: float, config: VizConfig,
                    tracks: dict[str, list[Track]]) -> list[Command]:
    """One point-cloud node per point frame, placed at that frame's pose and shown until the next one."""
    out = []
    frames = rec.point_frames
    chosen = _thin_indices(len(frames), config.replay_max_point_frames) if len(frames) else frames
    for n, j in enumerate(chosen):
        f = int(frames[j])
        node = f"{REPLAY}/points/k{n}"
        start = float(times[f])
        stop = float(times[frames[chosen[n + 1]]]) if n + 1 < len(chosen) else end_s
        base, est = rec.base_xyyaw[f], rec.est_xyyaw[f]
        for name, pose, color in (("scan", base, style.SCAN_COLOR), ("depth", base, style.DEPTH_COLOR),
                                  ("obstacles", est, None)):
            pts = rec.points[name][j]
            if len(pts) == 0 or not np.isfinite(pose).all():
                continue
            rgb = band_colors(pts, rec.scene.robot) if color is None else color
            out += [set_object(f"{node}/{name}", points_object(pts, rgb, config.point_size_m)),
                    set_transform(f"{node}/{name}", pose_xy_yaw(*pose.tolist()))]
        _shown_during(tracks, node, start, stop, end_s)
    return out


def _chosen_commands(rec: Recording, fans: list[PathFan], keys: np.ndarray, times: np.ndarray, end_s: float,
                     config: VizConfig, tracks: dict[str, list[Track]]) -> list[Command]:
    """One line per (PTG, path) the navigator chose, under the estimate's node, shown while it was chosen."""
    if not fans:
        return []
    labels = np.where(rec.ptg[keys] >= 0, rec.ptg[keys].astype(np.int64) * 100000 + rec.path_index[keys], -1)
    out = []
    for label in np.unique(labels[labels >= 0]):
        ptg, k = divmod(int(label), 100000)
        node = f"{NAV}/chosen/{fans[ptg].name}_{k}"
        out.append(set_object(node, chosen_path_object(fans[ptg], k, 1.0, config.path_step_m)))
        on = labels == label
        change = np.flatnonzero(np.diff(on.astype(np.int8), prepend=np.int8(not on[0])))
        t = [0.0] + [float(times[keys[i]]) for i in change if times[keys[i]] > 0] + [end_s]
        v = [bool(on[0])] + [bool(on[i]) for i in change if times[keys[i]] > 0] + [bool(on[-1])]
        tracks[node] = [visibility_track(t, v)]
    return out


def _route_commands(rec: Recording, t0_s: float, end_s: float, tracks: dict[str, list[Track]]) -> list[Command]:
    """Each route (polyline and target) as a node of its own, shown until the next route starts."""
    out = []
    starts = [float(t - t0_s) for t in rec.route_times_s]
    target = mesh_object(target_mesh())
    for q in range(len(rec.routes)):
        xy = rec.routes[q].astype(np.float64)
        if len(xy) == 0:
            continue
        node = f"{REPLAY}/routes/r{q}"
        line = np.column_stack([xy, np.full(len(xy), TRAIL_HEIGHT_M)])
        out += [set_object(f"{node}/line", line_object(np.vstack([line, line[-1:]]), style.ROUTE_COLOR)),
                set_object(f"{node}/target", target),
                set_transform(f"{node}/target", pose_xy_yaw(float(xy[-1, 0]), float(xy[-1, 1]), 0.0, PATH_HEIGHT_M))]
        stop = starts[q + 1] if q + 1 < len(starts) else end_s
        _shown_during(tracks, node, max(starts[q], 0.0), stop, end_s)
    return out


def replay_html(recording: Recording, config: VizConfig | None = None) -> str:
    """The replay as one self-contained HTML page (built by a private meshcat server)."""
    config = config or VizConfig()
    commands = replay_commands(recording, config)
    with meshcat_connection(None, config.timeout_s) as connection:
        connection.send(commands)
        return connection.scene_html()


def write_replay_html(recording: Recording, path: Path, config: VizConfig | None = None) -> Path:
    """Write :func:`replay_html` to ``path`` (parent folders are created)."""
    path = Path(path)
    html = replay_html(recording, config)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(html)
    log.info("replay: %s (%.1f MB, %.1f s)", path, len(html) / 1e6, recording.duration_s)
    return path


class HtmlReplay:
    """A frame sink that writes the HTML replay of a :class:`~simnav.viz.recording.Recorder`'s recording when the
    run finishes (put it after the recorder in the observer's sinks).

    Args:
        recorder: the recorder of the same run.
        path: the HTML file to write.
        config: replay options.
    """

    web_url: str | None = None

    def __init__(self, recorder, path: Path, config: VizConfig | None = None) -> None:
        self.recorder, self.path, self.config = recorder, Path(path), config or VizConfig()

    def show(self, scene) -> None:
        pass

    def wants_points(self, time_s: float) -> bool:
        return False

    def draw(self, frame) -> None:
        pass

    def finish(self) -> None:
        write_replay_html(self.recorder.recording(), self.path, self.config)
