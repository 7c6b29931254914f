"""``simnav odometry`` and ``simnav eval``: run an odometry over a recorded dataset, score a trajectory.

``simnav odometry METHOD INPUT`` writes the estimated trajectory as a TUM file (``est.txt``, with each increment's
covariance in the ``est.cov.txt`` sidecar). The planar odometries (srf, rf2o, wheels) read a CARMEN log or a
``simnav record`` folder and write base poses ``T_odom_base`` (3x3 covariances); the depth / RGB-D odometries
(difodo, vosf) read a TUM RGB-D folder and write the poses ``T_odom_camera`` of the camera's optical frame, the
frame of the dataset's ``groundtruth.txt`` (6x6 covariances; vosf also writes its scene flow with ``--flow-out``).
``simnav eval EST GT`` compares such a trajectory with a ground truth: RPE per second, SE(3)-aligned ATE and drift
per segment length. Both end every user error as one red line and exit code 2.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
import typer
from rich.table import Table

from simnav.cli.app import SetOption, _run_dir, _update_latest, app, console, err_console, user_errors
from simnav.errors import ConfigError, SimnavError, UnknownNameError

if TYPE_CHECKING:
    from simnav.io import RGBDDataset, Trajectory
    from simnav.metrics import ATEResult, DriftResult, RPEResult
    from simnav.odometry import FrameOdometry, OdometryEstimate, ScanOdometry
    from simnav.sensors.readings import LaserScan

WHEELS = "wheels"
VOSF = "vosf"
RGBD_INDEX = "depth.txt"
FORMATS = ("carmen", "simnav")
CARMEN_SUFFIXES = (".clf", ".log")
DRIVE_FIELDS = ("wheel_radius_m", "wheel_separation_m", "ticks_per_rev")
UNOBSERVABLE_VARIANCE = 1e12  # written for non-finite variances (directions an odometry could not observe)


# ----------------------------------------------------------------------------------------------------------
# simnav odometry


@app.command("odometry")
@user_errors
def odometry_command(
    method: Annotated[str, typer.Argument(
        metavar="METHOD", help="Planar: srf, rf2o, wheels. Depth / RGB-D: difodo, vosf.", show_default=False)],
    input_path: Annotated[Path, typer.Argument(
        metavar="INPUT", help="srf, rf2o, wheels: a CARMEN log (.clf/.log) or a `simnav record` folder. difodo, "
        "vosf: a TUM RGB-D folder (or a `simnav record` folder holding one).", show_default=False)],
    format_: Annotated[str | None, typer.Option(
        "--format", help="carmen or simnav (default: a folder is simnav, a file carmen); planar methods only.")] = None,
    laser: Annotated[str | None, typer.Option(
        help="Laser: <laser>.clf of a simnav folder, or a CARMEN log's scan stream (default: the first).")] = None,
    camera: Annotated[str | None, typer.Option(
        help="difodo, vosf on a `simnav record` folder: the camera subfolder (default: the only one).")] = None,
    out: Annotated[Path | None, typer.Option(
        help="Trajectory file (default: runs/<timestamp>-odometry-<method>/est.txt).")] = None,
    flow_out: Annotated[Path | None, typer.Option(
        "--flow-out", help="vosf: write each frame's scene flow, cluster labels and moving mask into this folder "
        "(see above).")] = None,
    base: Annotated[bool, typer.Option(
        "--base", help="difodo, vosf: write the base poses T_odom_base (through camera.yaml's mount) instead of "
        "the camera's.")] = False,
    settings: SetOption = None,
) -> None:
    """Run an odometry over a dataset and write its trajectory as a TUM file (est.txt, covariances in est.cov.txt).

    Planar odometries write the base poses T_odom_base. Scan odometries (srf, rf2o) take their settings with --set,
    e.g. --set max_iterations=10. The wheel odometry uses the ODOM poses of a CARMEN log, or integrates wheels.txt of
    a simnav folder with robot.yaml's drive (--set wheel_radius_m=0.076 overrides it).

    Depth / RGB-D odometries read a TUM RGB-D folder (depth.txt, depth/, optional rgb.txt, rgb/, camera.yaml; the
    layout `simnav record` writes for each camera): difodo (DIFODO, depth only) and vosf (Joint-VO-SF, RGB-D,
    odometry and scene flow). They write the poses of the camera's optical frame (z forward, x right, y down),
    T_odom_camera with odom = the optical frame of the first frame: the frame of the dataset's groundtruth.txt, so
    `simnav eval est.txt DATASET` compares like with like (--base writes base poses instead). Settings with --set,
    e.g. --set max_rows=120 runs DIFODO at QQVGA. With --flow-out DIR, vosf writes per frame
    DIR/scene_flow/<stamp>.npy (float32 3xHxW: displacement in m of each pixel's point since the previous frame,
    current optical frame, NaN = unknown), DIR/labels/<stamp>.npy (int32 HxW cluster, -1 = no depth),
    DIR/moving/<stamp>.npy (bool HxW), the index DIR/flow.txt and the clusters' background probabilities in
    DIR/clusters.txt.
    """
    from simnav.odometry import FRAME_ODOMETRIES, SCAN_ODOMETRIES

    planar = sorted([*SCAN_ODOMETRIES, WHEELS])
    frame_methods = sorted(FRAME_ODOMETRIES)
    if method not in planar and method not in frame_methods:
        available = ", ".join([*planar, *frame_methods])
        raise UnknownNameError(f"unknown odometry method '{method}'; available: {available}")
    if method in frame_methods:
        _reject_options(method, {"--format": format_ is not None, "--laser": laser is not None})
    else:
        _reject_options(method, {"--camera": camera is not None, "--flow-out": flow_out is not None, "--base": base})
    if flow_out is not None and method != VOSF:
        raise ConfigError(f"--flow-out: only {VOSF} computes scene flow, not {method}")
    if method in frame_methods:
        folder = _rgbd_folder(input_path, camera)
        out_path = out or _run_dir(f"odometry-{method}") / "est.txt"
        rows = _run_frames(method, folder, settings, out_path, flow_out, base)
    else:
        fmt = _input_format(input_path, format_)
        out_path = out or _run_dir(f"odometry-{method}") / "est.txt"
        if method == WHEELS:
            rows = _run_wheels(input_path, fmt, settings, out_path)
        else:
            rows = _run_scans(method, input_path, fmt, laser, settings, out_path)
    _update_latest(out_path.parent)
    table = Table(title=f"odometry {method}: {out_path}", show_header=False)
    for name, value in rows:
        table.add_row(name, value)
    console.print(table)


def _reject_options(method: str, given: dict[str, bool]) -> None:
    """One clear error for an option that does not apply to ``method``."""
    for option, is_given in given.items():
        if is_given:
            raise ConfigError(f"{option} does not apply to odometry method '{method}'")


def _input_format(path: Path, format_: str | None) -> str:
    if not path.exists():
        raise _missing(f"{path}: input not found (expected a CARMEN log or a `simnav record` folder)")
    if format_ is None:
        return "simnav" if path.is_dir() else "carmen"
    if format_ not in FORMATS:
        raise ConfigError(f"--format: expected one of {', '.join(FORMATS)}, got {format_!r}")
    if (format_ == "simnav") != path.is_dir():
        kind = "a `simnav record` folder" if format_ == "simnav" else "a CARMEN log file"
        raise ConfigError(f"--format {format_}: {path} is not {kind}")
    return format_


def _missing(message: str) -> SimnavError:
    from simnav.io import MissingDataError

    return MissingDataError(message)


def _run_scans(method: str, input_path: Path, fmt: str, laser: str | None, settings: list[str] | None,
               out_path: Path) -> list[tuple[str, str]]:
    """Runs a scan odometry over the scans of one laser; returns the summary rows."""
    from simnav.config import apply_overrides

    config = apply_overrides({}, settings, "--set")
    odometry = _make_scan_odometry(method, config)
    source, scans = _read_scans(input_path, fmt, laser)
    if not scans:
        raise _format_error(source, "no laser scans in this log")
    estimates, runtimes_s = _process_scans(odometry, scans, method, out_path)
    positions = np.array([e.T_odom_base[:2, 2] for e in estimates])
    runtime_ms = np.asarray(runtimes_s) * 1e3
    return [
        ("input", str(source)),
        ("scans", str(len(estimates))),
        ("valid scans", str(sum(e.valid_points > 0 for e in estimates))),
        ("degenerate scans", str(sum(bool(e.degenerate) for e in estimates))),
        ("runtime per scan (median / p95)",
         f"{np.median(runtime_ms):.2f} / {np.percentile(runtime_ms, 95):.2f} ms"),
        ("distance travelled", f"{_path_length_m(positions):.2f} m"),
    ]


def _make_scan_odometry(method: str, config: dict[str, Any]) -> ScanOdometry:
    """The scan odometry by name; a missing module or an invalid setting becomes one clear error."""
    from pydantic import ValidationError

    from simnav.config import format_validation_error
    from simnav.odometry import SCAN_ODOMETRIES, make_scan_odometry

    try:
        return make_scan_odometry(method, **config)
    except SimnavError:
        raise
    except (ImportError, AttributeError) as err:
        where = SCAN_ODOMETRIES[method].replace(":", ".")
        raise SimnavError(f"odometry '{method}' is not available in this installation ({where}: {err})") from None
    except ValidationError as err:
        raise ConfigError(format_validation_error(err, f"--set ({method})")) from None
    except (TypeError, ValueError) as err:
        raise ConfigError(f"--set ({method}): {err}") from None


def _read_scans(input_path: Path, fmt: str, laser: str | None) -> tuple[Path, list[LaserScan]]:
    """The CARMEN log used and its scans of one laser, in file order."""
    from simnav.io import read_carmen

    if fmt == "simnav":
        log_path = _simnav_laser_log(input_path, laser)
        return log_path, read_carmen(log_path).scans
    scans = read_carmen(input_path).scans
    streams = list(dict.fromkeys(s.sensor for s in scans))
    if laser is None:
        return input_path, [s for s in scans if s.sensor == streams[0]] if streams else []
    if laser not in streams:
        raise UnknownNameError(f"{input_path}: no scans of laser '{laser}'; available: {', '.join(streams)}")
    return input_path, [s for s in scans if s.sensor == laser]


def _simnav_laser_log(folder: Path, laser: str | None) -> Path:
    logs = sorted(folder.glob("*.clf"))
    if not logs:
        raise _missing(f"{folder}: no <laser>.clf CARMEN log in this folder (recorded without a 2D lidar?)")
    if laser is None:
        return logs[0]
    path = folder / f"{laser}.clf"
    if not path.is_file():
        raise UnknownNameError(f"{folder}: no laser '{laser}'; available: {', '.join(p.stem for p in logs)}")
    return path


def _process_scans(odometry: ScanOdometry, scans: list[LaserScan], method: str,
                   out_path: Path) -> tuple[list[OdometryEstimate], list[float]]:
    """Feeds the scans one by one (progress bar on stderr), streaming the poses into the TUM file."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from simnav.io import TumWriter

    estimates, runtimes_s = [], []
    with TumWriter(out_path) as writer, Progress(
        TextColumn(f"[bold]odometry[/] {method}"), BarColumn(), MofNCompleteColumn(), TextColumn("scans"),
        TimeRemainingColumn(), console=err_console, transient=True,
    ) as bar:
        task = bar.add_task(method, total=len(scans))
        for scan in scans:
            started = time.perf_counter()
            estimate = odometry.process(scan)
            runtimes_s.append(time.perf_counter() - started)
            writer.write(estimate.stamp_s, estimate.T_odom_base_3d, _finite_covariance(estimate.covariance))
            estimates.append(estimate)
            bar.advance(task)
    return estimates, runtimes_s


def _finite_covariance(covariance: np.ndarray) -> np.ndarray:
    """The (3, 3) or (6, 6) covariance with non-finite variances as UNOBSERVABLE_VARIANCE and their correlations 0."""
    cov = np.array(covariance, dtype=np.float64)
    n = 6 if cov.size == 36 else 3
    cov = cov.reshape(n, n)
    bad = ~np.isfinite(np.diag(cov))
    cov[bad, :] = 0.0
    cov[:, bad] = 0.0
    cov[bad, bad] = UNOBSERVABLE_VARIANCE
    cov[~np.isfinite(cov)] = 0.0
    return cov


def _run_wheels(input_path: Path, fmt: str, settings: list[str] | None, out_path: Path) -> list[tuple[str, str]]:
    """Writes the wheel odometry trajectory; returns the summary rows."""
    from simnav.io import write_tum

    if fmt == "carmen":
        if settings:
            raise ConfigError("--set: the wheel odometry of a CARMEN log is its logged ODOM poses; nothing to set")
        trajectory, source = _carmen_odom(input_path), input_path
    else:
        trajectory, source = _integrate_wheels(input_path, settings), input_path / "wheels.txt"
    write_tum(out_path, trajectory.stamps_s, trajectory.T)
    duration_s = trajectory.stamps_s[-1] - trajectory.stamps_s[0] if len(trajectory) else 0.0
    return [
        ("input", str(source)),
        ("poses", str(len(trajectory))),
        ("duration", f"{duration_s:.2f} s"),
        ("distance travelled", f"{_path_length_m(trajectory.T[:, :2, 3]):.2f} m"),
    ]


def _carmen_odom(path: Path) -> Trajectory:
    from simnav.io import read_carmen
    from simnav.metrics import planar_trajectory

    odom = read_carmen(path).odom
    if len(odom.stamps_s) == 0:
        raise _format_error(path, "no ODOM messages (wheel odometry) in this CARMEN log")
    return planar_trajectory(odom.stamps_s, odom.poses_xyt)


def _integrate_wheels(folder: Path, settings: list[str] | None) -> Trajectory:
    """Dead reckoning of wheels.txt with the drive of robot.yaml (fields overridable with --set)."""
    from simnav.metrics import planar_trajectory
    from simnav.odometry import WheelOdometry
    from simnav.sensors.readings import WheelTicks

    drive = _drive_parameters(folder / "robot.yaml", settings)
    stamps, ticks = _read_wheels(folder / "wheels.txt")
    odometry = WheelOdometry()
    poses = [odometry.update(WheelTicks("wheels", float(t), int(left), int(right), **drive))
             for t, (left, right) in zip(stamps, ticks)]
    return planar_trajectory(stamps, np.reshape(poses, (-1, 3)))


def _drive_parameters(path: Path, settings: list[str] | None) -> dict[str, Any]:
    from simnav.config import apply_overrides, read_yaml

    if not path.is_file():
        raise _missing(f"{path}: robot.yaml not found (needed for the wheel radius, separation and resolution)")
    drive = read_yaml(path).get("drive")
    if not isinstance(drive, dict):
        raise ConfigError(f"{path}: field 'drive': expected a mapping with {', '.join(DRIVE_FIELDS)}")
    drive = apply_overrides({k: drive.get(k) for k in DRIVE_FIELDS}, settings, "--set")
    for key, value in drive.items():
        source = "--set" if any(s.split("=", 1)[0].strip() == key for s in settings or []) else str(path)
        if key not in DRIVE_FIELDS:
            raise ConfigError(f"--set: unknown wheel odometry field '{key}'; available: {', '.join(DRIVE_FIELDS)}")
        is_number = isinstance(value, int | float) and not isinstance(value, bool)
        if not is_number or not np.isfinite(value) or value <= 0 or (key == "ticks_per_rev" and value % 1):
            kind = "a positive integer" if key == "ticks_per_rev" else "a positive number"
            raise ConfigError(f"{source}: field 'drive.{key}': expected {kind}, got {value!r}")
    drive["ticks_per_rev"] = int(drive["ticks_per_rev"])
    return drive


def _read_wheels(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(N,) stamps (s) and (N, 2) cumulative left/right ticks of a ``t left_ticks right_ticks`` file."""
    from simnav.io import format_error

    if not path.is_file():
        raise _missing(f"{path}: wheel encoder file not found")
    stamps, ticks = [], []
    for line_no, raw in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), start=1):
        tokens = raw.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        row = _wheel_row(tokens)
        if row is None:
            raise format_error(path, line_no, f"expected 'timestamp left_ticks right_ticks', got {raw.strip()!r}")
        stamps.append(row[0])
        ticks.append(row[1:])
    if not stamps:
        raise format_error(path, None, "no encoder readings")
    return np.asarray(stamps), np.asarray(ticks, dtype=np.int64)


def _wheel_row(tokens: list[str]) -> tuple[float, int, int] | None:
    if len(tokens) != 3:
        return None
    try:
        stamp, left, right = float(tokens[0]), int(tokens[1]), int(tokens[2])
    except ValueError:
        return None
    return (stamp, left, right) if np.isfinite(stamp) else None


def _path_length_m(positions: np.ndarray) -> float:
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    return float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum()) if len(positions) > 1 else 0.0


def _format_error(path: Path, message: str) -> SimnavError:
    from simnav.io import format_error

    return format_error(path, None, message)


# ----------------------------------------------------------------------------------------------------------
# simnav odometry difodo / vosf: depth and RGB-D odometries over a TUM RGB-D folder


def _rgbd_folder(path: Path, camera: str | None) -> Path:
    """The TUM RGB-D folder of INPUT: the folder itself, or a camera subfolder of a `simnav record` folder."""
    if not path.exists():
        raise _missing(f"{path}: input not found (expected a TUM RGB-D folder with {RGBD_INDEX}, or a `simnav record` "
                       "folder)")
    if not path.is_dir():
        raise ConfigError(f"{path}: expected a TUM RGB-D folder ({RGBD_INDEX}, depth/, rgb.txt, rgb/), got a file")
    cameras = sorted(p.name for p in path.iterdir() if p.is_dir() and (p / RGBD_INDEX).is_file())
    if camera is not None:
        if camera not in cameras:
            available = ", ".join(cameras) or "none"
            raise UnknownNameError(f"{path}: no camera '{camera}' (a subfolder holding {RGBD_INDEX}); "
                                   f"available: {available}")
        return path / camera
    if (path / RGBD_INDEX).is_file():
        return path
    if len(cameras) == 1:
        return path / cameras[0]
    if cameras:
        raise ConfigError(f"{path}: holds several cameras ({', '.join(cameras)}); choose one with --camera")
    raise _missing(f"{path}: no {RGBD_INDEX} here or in a camera subfolder (expected a TUM RGB-D folder, or a "
                   "`simnav record` folder recorded with cameras)")


def _run_frames(method: str, folder: Path, settings: list[str] | None, out_path: Path, flow_out: Path | None,
                base: bool) -> list[tuple[str, str]]:
    """Runs a depth / RGB-D odometry over a TUM RGB-D folder; returns the summary rows."""
    from simnav.config import apply_overrides
    from simnav.io import RGBDDataset

    config = apply_overrides({}, settings, "--set")
    odometry = _make_frame_odometry(method, config)
    dataset = RGBDDataset(folder)
    if len(dataset) == 0:
        raise _format_error(folder / RGBD_INDEX, "no depth images in this dataset")
    flows = _FlowWriter(flow_out) if flow_out is not None else None
    try:
        run = _process_frames(odometry, dataset, method, out_path, flows, base)
    finally:
        if flows is not None:
            flows.close()
    runtime_ms = np.asarray(run.runtimes_s) * 1e3
    h, w = run.image_size
    rows = [
        ("input", str(folder)),
        ("frames", f"{len(runtime_ms)} ({w} x {h})"),
        ("frames aligned", str(run.measured)),
        ("degenerate frames", str(run.degenerate)),
        ("runtime per frame (median / p95)", f"{np.median(runtime_ms):.2f} / {np.percentile(runtime_ms, 95):.2f} ms"),
        ("poses of", "the base (T_odom_base)" if base else "the camera optical frame (T_odom_camera)"),
        ("distance travelled", f"{_path_length_3d_m(np.asarray(run.positions)):.2f} m"),
    ]
    if run.moving_fractions:
        rows.append(("moving pixels (mean over frames)", f"{100 * np.mean(run.moving_fractions):.1f} %"))
    if flows is not None:
        rows.append(("scene flow", str(flows.root)))
    return rows


def _make_frame_odometry(method: str, config: dict[str, Any]) -> FrameOdometry:
    """The frame odometry by name; a missing module or an invalid setting becomes one clear error."""
    from simnav.odometry import FRAME_ODOMETRIES, make_frame_odometry

    try:
        return make_frame_odometry(method, **config)
    except SimnavError as err:
        raise ConfigError(f"--set ({method}): {err}") from None
    except ImportError as err:
        where = FRAME_ODOMETRIES[method].replace(":", ".")
        raise SimnavError(f"odometry '{method}' is not available in this installation ({where}: {err})") from None
    except (TypeError, ValueError) as err:
        raise ConfigError(f"--set ({method}): {err}") from None


@dataclass
class _FrameRun:
    """What the summary needs of a run over the frames (the estimates themselves are not kept)."""

    image_size: tuple[int, int] = (0, 0)
    runtimes_s: list[float] = field(default_factory=list)
    positions: list[np.ndarray] = field(default_factory=list)
    measured: int = 0
    degenerate: int = 0
    moving_fractions: list[float] = field(default_factory=list)


def _process_frames(odometry: FrameOdometry, dataset: RGBDDataset, method: str, out_path: Path,
                    flows: _FlowWriter | None, base: bool) -> _FrameRun:
    """Feeds the frames one by one (progress bar on stderr), streaming the poses into the TUM file."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from simnav.io import DataFormatError, TumWriter

    run = _FrameRun()
    with TumWriter(out_path) as writer, Progress(
        TextColumn(f"[bold]odometry[/] {method}"), BarColumn(), MofNCompleteColumn(), TextColumn("frames"),
        TimeRemainingColumn(), console=err_console, transient=True,
    ) as bar:
        task = bar.add_task(method, total=len(dataset))
        for frame in dataset:
            run.image_size = tuple(np.shape(frame.depth_m)[:2])
            started = time.perf_counter()
            try:
                estimate = odometry.process(frame)
            except ValueError as err:  # e.g. an image size the pyramid cannot use
                raise DataFormatError(f"{dataset.root}: {method} cannot use frame {frame.stamp_s:.6f}: {err}") from None
            run.runtimes_s.append(time.perf_counter() - started)
            T = estimate.T_odom_base if base else estimate.T_odom_camera
            writer.write(estimate.stamp_s, T, _finite_covariance(estimate.covariance))
            run.positions.append(np.asarray(T)[:3, 3].copy())
            run.measured += bool(estimate.extra.get("measured", True))
            run.degenerate += bool(estimate.degenerate)
            moving = estimate.extra.get("moving_mask")
            if moving is not None:
                valid = np.count_nonzero(np.isfinite(frame.depth_m) & (frame.depth_m > 0))
                run.moving_fractions.append(np.count_nonzero(moving) / max(valid, 1))
            if flows is not None:
                flows.write(estimate.stamp_s, estimate.extra)
            bar.advance(task)
    return run


class _FlowWriter:
    """Writes vosf's per-frame outputs: scene_flow/, labels/, moving/ (.npy), flow.txt and clusters.txt."""

    KINDS = ("scene_flow", "labels", "moving")

    def __init__(self, root: Path) -> None:
        if root.exists() and not root.is_dir():
            raise ConfigError(f"--flow-out: {root} is a file, expected a folder")
        self.root = root
        for kind in self.KINDS:
            (root / kind).mkdir(parents=True, exist_ok=True)
        self._index = open(root / "flow.txt", "w", encoding="ascii", newline="\n")  # noqa: SIM115
        self._index.write("# scene flow of Joint-VO-SF: float32 (3, H, W) m, displacement since the previous frame "
                          "in the current optical frame, NaN = unknown; labels int32 (H, W), -1 = no depth; moving "
                          "bool (H, W)\n# timestamp scene_flow labels moving\n")
        self._clusters = open(root / "clusters.txt", "w", encoding="ascii", newline="\n")  # noqa: SIM115
        self._clusters.write("# background probability of each cluster (1 - b: below 1/3 moving, 1/3-2/3 uncertain; "
                             "moving/ also marks the uncertain clusters whose own motion is at least "
                             "uncertain_moving_speed_m_s)\n"
                             "# timestamp p_0 p_1 ... p_K-1\n")

    def write(self, stamp_s: float, extra: dict) -> None:
        from simnav.io.rgbd_dataset import stamp_text

        stamp = stamp_text(stamp_s)
        arrays = {"scene_flow": np.asarray(extra["scene_flow_m"], dtype=np.float32),
                  "labels": np.asarray(extra["labels"], dtype=np.int32),
                  "moving": np.asarray(extra["moving_mask"], dtype=bool)}
        for kind, array in arrays.items():
            np.save(self.root / kind / f"{stamp}.npy", array, allow_pickle=False)
        self._index.write(f"{stamp} " + " ".join(f"{kind}/{stamp}.npy" for kind in self.KINDS) + "\n")
        probabilities = np.asarray(extra.get("background_probability", []), dtype=np.float64).ravel()
        self._clusters.write(" ".join([stamp, *(f"{p:.4f}" for p in probabilities)]) + "\n")

    def close(self) -> None:
        self._index.close()
        self._clusters.close()


def _path_length_3d_m(positions: np.ndarray) -> float:
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    return float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum()) if len(positions) > 1 else 0.0


# ----------------------------------------------------------------------------------------------------------
# simnav eval


@app.command("eval")
@user_errors
def eval_command(
    est_path: Annotated[Path, typer.Argument(
        metavar="EST", help="Estimated trajectory (TUM), or a run folder holding est.txt.", show_default=False)],
    gt_path: Annotated[Path, typer.Argument(
        metavar="GT", help="Ground truth: a TUM file, a CARMEN log with TRUEPOS lines or a `simnav record` folder.",
        show_default=False)],
    delta: Annotated[float, typer.Option(help="Time between the poses of an RPE pair, s.")] = 1.0,
    plot: Annotated[Path | None, typer.Option(help="Save an x-y and error-over-time plot (PNG).")] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Save the metrics as JSON.")] = None,
) -> None:
    """Score a trajectory against ground truth: RPE per second, SE(3)-aligned ATE, drift per segment length."""
    from simnav.io import DataFormatError
    from simnav.metrics import ate, drift_per_segment, plot_trajectories, rpe_per_second

    if not (np.isfinite(delta) and delta > 0):
        raise ConfigError(f"--delta: expected a time > 0 s, got {delta}")
    est_file = est_path / "est.txt" if est_path.is_dir() else est_path
    est = _read_estimate(est_file)
    gt, gt_file = _read_ground_truth(gt_path)
    try:
        rpe = rpe_per_second(est, gt, delta_s=delta)
        ate_result = ate(est, gt, "se3")
        drift = drift_per_segment(est, gt)
    except DataFormatError as err:
        raise DataFormatError(f"{est_file} vs {gt_file}: {err}") from None
    _print_eval(est_file, gt_file, rpe, ate_result, drift)
    if plot is not None:
        plot_trajectories(est, gt, plot, aligned=ate_result)
        err_console.print(f"plot: {plot}")
    if json_out is not None:
        report = {"estimate": str(est_file), "ground_truth": str(gt_file), "rpe": rpe.as_dict(),
                  "ate": ate_result.as_dict(), "drift": {f"{L:g}": d.as_dict() for L, d in drift.items()}}
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(report, indent=2) + "\n")
        err_console.print(f"metrics: {json_out}")


def _read_estimate(path: Path) -> Trajectory:
    from simnav.io import read_tum

    if not path.is_file():
        raise _missing(f"{path}: estimated trajectory not found")
    return read_tum(path)


def _read_ground_truth(path: Path) -> tuple[Trajectory, Path]:
    """The ground truth and the file it came from: TUM file, CARMEN TRUEPOS, or a record folder."""
    from simnav.io import read_carmen, read_tum
    from simnav.metrics import planar_trajectory

    if path.is_dir():
        path = path / "groundtruth.txt"
        if not path.is_file():
            raise _missing(f"{path}: ground truth not found (is {path.parent} a `simnav record` folder?)")
        return read_tum(path), path
    if not path.is_file():
        raise _missing(f"{path}: ground truth not found")
    if not _is_carmen(path):
        return read_tum(path), path
    truepos = read_carmen(path).truepos
    if len(truepos.stamps_s) == 0:
        raise _format_error(path, "no TRUEPOS messages (ground truth) in this CARMEN log")
    return planar_trajectory(truepos.stamps_s, truepos.poses_xyt), path


def _is_carmen(path: Path) -> bool:
    """A CARMEN log by suffix, or by its first message starting with a name (TUM lines start with a number)."""
    if path.suffix.lower() in CARMEN_SUFFIXES:
        return True
    with open(path, encoding="utf-8", errors="replace") as f:
        for raw in f:
            text = raw.strip()
            if text and not text.startswith("#"):
                return text[0].isalpha()
    return False


def _print_eval(est_file: Path, gt_file: Path, rpe: RPEResult, ate_result: ATEResult,
                drift: dict[float, DriftResult]) -> None:
    from simnav.metrics import DEFAULT_SEGMENTS_M

    table = Table("metric", "RMSE", "mean", "median", "max", title=f"{est_file} vs {gt_file}")
    table.add_row(f"RPE translation per {rpe.delta_s:g} s (cm/s)",
                  *_cells(rpe.trans_rmse_cm_s, rpe.trans_mean_cm_s, rpe.trans_median_cm_s, rpe.trans_max_cm_s))
    table.add_row(f"RPE rotation per {rpe.delta_s:g} s (deg/s)",
                  *_cells(rpe.rot_rmse_deg_s, rpe.rot_mean_deg_s, rpe.rot_median_deg_s, rpe.rot_max_deg_s))
    table.add_row(f"ATE, {ate_result.alignment} aligned (m)",
                  *_cells(ate_result.rmse_m, ate_result.mean_m, ate_result.median_m, ate_result.max_m))
    table.caption = f"{rpe.pairs} RPE pairs, {ate_result.pairs} associated poses"
    console.print(table)
    if not drift:
        shortest = min(DEFAULT_SEGMENTS_M)
        console.print(f"drift: the ground-truth path is shorter than the shortest segment ({shortest:g} m)")
        return
    drift_table = Table("segment (m)", "segments", "translation (%)", "rotation (deg/m)", title="drift per segment")
    for length, d in drift.items():
        drift_table.add_row(f"{length:g}", str(d.segments), f"{d.translation_pct:.3f}", f"{d.rotation_deg_per_m:.4f}")
    console.print(drift_table)


def _cells(*values: float) -> list[str]:
    return [f"{v:.4f}" for v in values]
