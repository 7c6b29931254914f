"""A compact recording of what the viewer shows, written next to a run's report for ``simnav view``.

``viz_recording.npz`` (numpy, compressed) holds the world, the robot and the navigator's PTG settings as JSON, and
per frame (``VizConfig.rate_hz`` per simulated second): the true and estimated robot poses, the people, the other
robots, the door leaves and the chosen PTG path; per point frame (``points_rate_hz``): lidar, depth and obstacle
points thinned to the configured caps, as float16 in the robot's frame; and the routes with the time each started.
A 20 s mission in the office with ten people takes about 100 kB.
"""

from __future__ import annotations

import json
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import simnav
from simnav.errors import SimnavError
from simnav.robot.spec import RobotSpec
from simnav.viz.config import VizConfig
from simnav.viz.frame import PathFamilies, SceneInfo, VizFrame, thin
from simnav.world.schema import WorldSpec

RECORDING_FILE = "viz_recording.npz"
FORMAT = "simnav-viz-recording"
FORMAT_VERSION = 1
POINT_CHANNELS = ("scan", "depth", "obstacles")
_EPS_S = 1e-9


@dataclass
class Ragged:
    """Variable-length point sets: set j is ``xyz[ptr[j]:ptr[j + 1]]`` (m, float16)."""

    ptr: np.ndarray
    xyz: np.ndarray

    def __len__(self) -> int:
        return len(self.ptr) - 1

    def __getitem__(self, j: int) -> np.ndarray:
        return self.xyz[self.ptr[j]:self.ptr[j + 1]].astype(np.float32)

    @staticmethod
    def of(sets: list[np.ndarray], dims: int = 3, dtype=np.float16) -> Ragged:
        ptr = np.zeros(len(sets) + 1, dtype=np.int64)
        np.cumsum([len(s) for s in sets], out=ptr[1:])
        xyz = np.concatenate(sets).astype(dtype) if sets else np.zeros((0, dims), dtype)
        return Ragged(ptr, xyz.reshape(-1, dims))


@dataclass
class Recording:
    """A run as drawn (see the module docstring).

    Attributes:
        scene: world, robot, agent counts, PTG settings.
        rate_hz: frames per simulated second the recording was made at.
        times_s: (T,) frame times, s.
        base_xyyaw: (T, 3) ground-truth robot pose (x m, y m, yaw rad).
        est_xyyaw: (T, 3) the navigator's estimate (NaN rows without a navigator).
        people: (T, P, 3) pedestrians (x, y, yaw).     robots: (T, W, 3) other robots.
        door_yaws_rad: (T, D) door leaf headings, rad.
        ptg: (T,) index of the chosen path's PTG in ``scene.paths.names`` (-1: none).
        path_index: (T,) chosen path (-1: none).     free_distance: (T,) its normalised free distance.
        point_frames: (K,) indices of the frames that carry points.
        points: per channel (scan, depth in the ``base`` frame of the true pose; obstacles in that of the
            estimate), one point set per point frame, m.
        route_times_s: (Q,) when each route started, s.     routes: the routes' waypoints (x, y), m.
    """

    scene: SceneInfo
    rate_hz: float
    times_s: np.ndarray
    base_xyyaw: np.ndarray
    est_xyyaw: np.ndarray
    people: np.ndarray
    robots: np.ndarray
    door_yaws_rad: np.ndarray
    ptg: np.ndarray
    path_index: np.ndarray
    free_distance: np.ndarray
    point_frames: np.ndarray
    points: dict[str, Ragged]
    route_times_s: np.ndarray
    routes: Ragged
    meta: dict = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return float(self.times_s[-1] - self.times_s[0]) if len(self.times_s) else 0.0

    # ------------------------------------------------------------------------------------------------ files
    def save(self, path: Path) -> Path:
        """Write the recording (``path``: a folder, then ``viz_recording.npz`` in it, or a file name)."""
        path = Path(path)
        path = path / RECORDING_FILE if path.is_dir() else path
        path.parent.mkdir(parents=True, exist_ok=True)
        header = {"format": FORMAT, "version": FORMAT_VERSION, "simnav_version": simnav.__version__,
                  "rate_hz": self.rate_hz, "paths": _paths_json(self.scene.paths), **self.meta}
        arrays = dict(
            header=np.array(json.dumps(header)),
            world=np.array(self.scene.world.model_dump_json()), robot=np.array(self.scene.robot.model_dump_json()),
            times_s=self.times_s, base_xyyaw=self.base_xyyaw, est_xyyaw=self.est_xyyaw, people=self.people,
            robots=self.robots, door_yaws_rad=self.door_yaws_rad, ptg=self.ptg, path_index=self.path_index,
            free_distance=self.free_distance, point_frames=self.point_frames, route_times_s=self.route_times_s,
            routes_ptr=self.routes.ptr, routes_xy=self.routes.xyz)
        for name, ragged in self.points.items():
            arrays[f"{name}_ptr"], arrays[f"{name}_xyz"] = ragged.ptr, ragged.xyz
        with path.open("wb") as f:
            np.savez_compressed(f, **arrays)
        return path

    @staticmethod
    def load(path: Path) -> Recording:
        """Read a recording from a run folder (``viz_recording.npz`` in it) or from the file itself.

        Raises:
            SimnavError: no recording there, or not a readable simnav recording (the message names the path).
        """
        path = Path(path)
        file = path / RECORDING_FILE if path.is_dir() else path
        if not file.is_file():
            raise SimnavError(f"{path}: no viz recording; expected {file} (written by `simnav mission` into its "
                              "output folder)")
        if not zipfile.is_zipfile(file):
            raise SimnavError(f"{file}: not a simnav viz recording (expected the numpy .npz archive that "
                              "`simnav mission` writes)")
        try:
            with np.load(file, allow_pickle=False) as data:
                return _from_arrays(dict(data))
        except (OSError, ValueError, KeyError, zipfile.BadZipFile, json.JSONDecodeError) as err:
            raise SimnavError(f"{file}: not a readable simnav viz recording ({err})") from None


def _paths_json(paths: PathFamilies | None) -> dict | None:
    if paths is None:
        return None
    return {"names": list(paths.names), "num_paths": paths.num_paths, "ref_distance_m": paths.ref_distance_m,
            "max_v_m_s": paths.max_v_m_s, "max_w_rad_s": paths.max_w_rad_s}


def _from_arrays(data: dict[str, np.ndarray]) -> Recording:
    header = json.loads(str(data["header"]))
    if header.get("format") != FORMAT or header.get("version") != FORMAT_VERSION:
        raise ValueError(f"format {header.get('format')!r} version {header.get('version')!r}, expected {FORMAT!r} "
                         f"version {FORMAT_VERSION}")
    paths = header.get("paths")
    people, robots = data["people"], data["robots"]
    scene = SceneInfo(WorldSpec.model_validate_json(str(data["world"])),
                      RobotSpec.model_validate_json(str(data["robot"])), people.shape[1], robots.shape[1],
                      PathFamilies(tuple(paths["names"]), paths["num_paths"], paths["ref_distance_m"],
                                   paths["max_v_m_s"], paths["max_w_rad_s"]) if paths else None)
    points = {name: Ragged(data[f"{name}_ptr"], data[f"{name}_xyz"]) for name in POINT_CHANNELS}
    meta = {k: v for k, v in header.items() if k not in ("format", "version", "rate_hz", "paths")}
    return Recording(scene, float(header["rate_hz"]), data["times_s"], data["base_xyyaw"], data["est_xyyaw"], people,
                     robots, data["door_yaws_rad"], data["ptg"], data["path_index"], data["free_distance"],
                     data["point_frames"], points, data["route_times_s"], Ragged(data["routes_ptr"],
                                                                                  data["routes_xy"]), meta)


def _xyyaw(T: np.ndarray | None) -> list[float]:
    if T is None:
        return [math.nan] * 3
    return [float(T[0, 2]), float(T[1, 2]), math.atan2(T[1, 0], T[0, 0])]


class Recorder:
    """A frame sink that keeps a :class:`Recording` and writes it into ``out_dir`` when the run finishes.

    Frames arrive at the observer's rate; point sets are kept at ``config.points_rate_hz``.

    Args:
        out_dir: where ``viz_recording.npz`` goes (None: keep it in memory only).
        config: rates and caps.
    """

    web_url: str | None = None

    def __init__(self, out_dir: Path | None, config: VizConfig | None = None) -> None:
        self.out_dir, self.config = (Path(out_dir) if out_dir is not None else None), config or VizConfig()
        self.path: Path | None = None
        self._scene: SceneInfo | None = None
        self._clear()

    def _clear(self) -> None:
        self._rows: list[tuple] = []
        self._point_frames: list[int] = []
        self._points: dict[str, list[np.ndarray]] = {name: [] for name in POINT_CHANNELS}
        self._routes: list[tuple[float, np.ndarray]] = []
        self._last_route: np.ndarray | None = None
        self._next_points_s = -math.inf

    def show(self, scene: SceneInfo) -> None:
        """Start a recording of ``scene`` (what was recorded before is dropped: one recording per episode)."""
        self._scene = scene
        self._clear()

    def wants_points(self, time_s: float) -> bool:
        return time_s + _EPS_S >= self._next_points_s

    def draw(self, frame: VizFrame) -> None:
        names = self._scene.paths.names if self._scene is not None and self._scene.paths is not None else ()
        ptg = names.index(frame.ptg) if frame.ptg in names else -1
        self._rows.append((frame.time_s, _xyyaw(frame.T_world_base), _xyyaw(frame.T_world_est), frame.people,
                           frame.robots, frame.door_yaws_rad, ptg, frame.path_index, frame.free_distance))
        if self.wants_points(frame.time_s):
            last = frame.time_s if math.isinf(self._next_points_s) else self._next_points_s
            self._next_points_s = max(last + 1.0 / self.config.points_rate_hz, frame.time_s)
            self._point_frames.append(len(self._rows) - 1)
            for name, pts in (("scan", frame.scan_base), ("depth", frame.depth_base),
                              ("obstacles", frame.obstacles_base)):
                pts = np.asarray(pts, dtype=np.float32).reshape(-1, 3)
                self._points[name].append(thin(pts, self.config.record_max_points))
        if frame.T_world_est is not None and (self._last_route is None
                                              or not np.array_equal(self._last_route, frame.route_world)):
            self._last_route = np.array(frame.route_world, dtype=np.float64)
            self._routes.append((frame.time_s, self._last_route.astype(np.float32).reshape(-1, 2)))

    def recording(self) -> Recording:
        """What was recorded so far.

        Raises:
            SimnavError: nothing was shown yet.
        """
        if self._scene is None:
            raise SimnavError("viz recorder: no scene was shown (attach it to a simulator or a mission first)")
        scene, rows = self._scene, self._rows
        col = list(zip(*rows)) if rows else [[] for _ in range(9)]

        def stack(values, shape):
            return np.array(values, dtype=np.float32).reshape(len(rows), *shape)

        return Recording(
            scene, self.config.rate_hz, np.array(col[0], dtype=np.float64), np.array(col[1]).reshape(-1, 3),
            np.array(col[2]).reshape(-1, 3), stack(col[3], (scene.people, 3)), stack(col[4], (scene.robots, 3)),
            stack(col[5], (len(scene.world.doors),)), np.array(col[6], dtype=np.int8),
            np.array(col[7], dtype=np.int16), np.array(col[8], dtype=np.float32),
            np.array(self._point_frames, dtype=np.int32),
            {name: Ragged.of(sets) for name, sets in self._points.items()},
            np.array([t for t, _ in self._routes], dtype=np.float64),
            Ragged.of([xy for _, xy in self._routes], dims=2, dtype=np.float32))

    def finish(self) -> None:
        """Write ``viz_recording.npz`` into ``out_dir`` (nothing when no frame was recorded)."""
        if self.out_dir is not None and self._rows:
            self.path = self.recording().save(self.out_dir / RECORDING_FILE)
