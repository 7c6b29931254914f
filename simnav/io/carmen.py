"""CARMEN log files: planar laser scans, odometry and ground truth, one message per line.

The format of the classic CARMEN robot logs and of the public scan-matching / SLAM benchmark logs. Every
message line ends with ``ipc_timestamp ipc_hostname logger_timestamp``; lines starting with ``#`` are
comments::

    PARAM param_name param_value
    ODOM x y theta tv rv accel
    TRUEPOS true_x true_y true_theta odom_x odom_y odom_theta
    FLASER num_readings [range_readings] x y theta odom_x odom_y odom_theta        (RLASER: rear laser)
    RAWLASER1 laser_type start_angle field_of_view angular_resolution maximum_range accuracy remission_mode
        num_readings [range_readings] num_remissions [remission values]               (also RAWLASER2..4)
    ROBOTLASER1 <RAWLASER fields> laser_pose_x laser_pose_y laser_pose_theta robot_pose_x robot_pose_y
        robot_pose_theta laser_tv laser_rv forward_safety_dist side_safety_dist turn_axis  (also ROBOTLASER2)

Units are m, rad, m/s, rad/s and s; poses ``(x, y, theta)`` are in the odometry frame; ``x y theta`` of FLASER
and ``laser_pose_*`` of ROBOTLASER are the pose of the *laser*, the other pose that of the robot base.

Conventions of this module:

* **No-return beams.** simnav marks an invalid beam with range 0. The writer stores it as exactly
  ``maximum_range`` (ROBOTLASER1, written with the same 3 decimals as the ranges) or as ``no_return_m``
  (FLASER, default 81.83 m, the no-return reading of the SICK LMS 2xx scanners the classic logs come from),
  which is what public CARMEN readers treat as "no hit". Beams at or beyond the maximum range are no-returns
  too. Valid beams are clamped to ``[0.001, maximum_range - 0.001]`` m so that rounding to millimetres never
  turns them into no-returns. The reader maps readings that are 0, negative, NaN/inf or ``>= maximum_range``
  (``>= flaser_max_range_m`` for FLASER/RLASER) to 0, so a round trip keeps ``LaserScan.valid``.
* **Angles.** ROBOTLASER/RAWLASER beam k is at ``start_angle + k * angular_resolution`` (the writer stores the
  first beam angle and the mean signed increment, ``field_of_view = resolution * (n - 1)``). FLASER/RLASER
  carry no angles: n beams spread evenly from -90 deg to +90 deg inclusive.
* **Mount.** The laser's ``T_base_sensor`` is the laser pose expressed in the robot frame, computed per
  message from the two poses it logs (unless ``T_base_laser`` is given to :func:`read_carmen`). RAWLASER
  messages log no pose: identity (or ``T_base_laser``). An upside-down scanner is written as the equivalent
  upright one with mirrored beam angles (CARMEN stores planar, z-up scanners only).
* **Sensor names.** ROBOTLASER1/FLASER -> ``"laser1"``, ROBOTLASER2/RLASER -> ``"laser2"``, RAWLASERk ->
  ``"laser<k>"``; ``min_range_m`` is 0 (the format does not store it).
* **Determinism.** The writer uses fixed formats (ranges 3 decimals, metres 6, radians 9, time 6) and writes
  ``logger_timestamp = ipc_timestamp``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, NamedTuple

import numpy as np

from simnav.io import MissingDataError, format_error
from simnav.io.tum import fmt_float
from simnav.sensors.readings import LaserScan

logger = logging.getLogger(__name__)

FLASER_NO_RETURN_M = 81.83
"""Default no-return reading of FLASER/RLASER beams (SICK LMS 2xx in cm mode), m."""
_MAX_TILT_COS = math.cos(math.radians(10.0))
_MOUNT_TOL = 1e-3
_NUMBERED_LASER = {"ROBOTLASER1": 1, "ROBOTLASER2": 2, "FLASER": 1, "RLASER": 2}
_RAW_LAYOUT = (
    "laser_type start_angle field_of_view angular_resolution maximum_range accuracy remission_mode "
    "num_readings [range_readings] num_remissions [remission values]"
)
_ROBOT_LAYOUT = (
    _RAW_LAYOUT + " laser_pose_x laser_pose_y laser_pose_theta robot_pose_x robot_pose_y robot_pose_theta "
    "laser_tv laser_rv forward_safety_dist side_safety_dist turn_axis"
)
_FOOTER = "ipc_timestamp ipc_hostname logger_timestamp"
HEADER_LINES = (
    "# CARMEN Logfile",
    "# file format is one message per line",
    "# message_name [message contents] ipc_timestamp ipc_hostname logger_timestamp",
    "# message formats defined: PARAM ODOM TRUEPOS FLASER ROBOTLASER1",
    "# PARAM param_name param_value",
    "# ODOM x y theta tv rv accel",
    "# TRUEPOS true_x true_y true_theta odom_x odom_y odom_theta",
    "# FLASER num_readings [range_readings] x y theta odom_x odom_y odom_theta",
    "# ROBOTLASER1 " + _ROBOT_LAYOUT,
    "# units: m, rad, m/s, rad/s, s; no-return beams are written as maximum_range (FLASER: no_return_m)",
)


# ----------------------------------------------------------------------------------------------------------
# Planar pose helpers


def wrap_angle(a: float) -> float:
    """Angle wrapped to [-pi, pi), rad."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def relative_xyt(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3,) pose ``b`` expressed in the frame of pose ``a`` (both (x, y, theta) in a common frame)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[2] - a[2])])


def compose_xyt(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3,) composed pose ``a (+) b``: ``b`` (given in frame ``a``) expressed in ``a``'s parent frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap_angle(a[2] + b[2])])


def xyt_to_T(xyt: np.ndarray) -> np.ndarray:
    """(4, 4) homogeneous transform of a planar pose (x, y, theta): rotation about z, z translation 0."""
    c, s = math.cos(xyt[2]), math.sin(xyt[2])
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:2, 3] = xyt[:2]
    return T


def _planar_mount(T_base_sensor: np.ndarray) -> tuple[np.ndarray, bool]:
    """Planar mount (x, y, yaw) of a scanner and whether it is upside down (beam angles mirrored)."""
    T = np.asarray(T_base_sensor, dtype=np.float64)
    if abs(T[2, 2]) < _MAX_TILT_COS:
        raise ValueError(f"scanner z axis is tilted by more than 10 deg (R_zz={T[2, 2]:.3f})")
    return np.array([T[0, 3], T[1, 3], math.atan2(T[1, 0], T[0, 0])]), bool(T[2, 2] < 0)


# ----------------------------------------------------------------------------------------------------------
# Writer


class CarmenWriter:
    """Writes a CARMEN log, message by message (context manager).

    The header (comment lines) is written on construction. See the module docstring for the conventions.

    Args:
        path: the log file (created or truncated; parent folders are created).
        hostname: ``ipc_hostname`` written on every message (no whitespace).
    """

    def __init__(self, path: str | Path, hostname: str = "simnav") -> None:
        self.path = Path(path)
        if not hostname or any(ch.isspace() for ch in hostname):
            raise format_error(self.path, None, f"hostname must be one non-empty word, got {hostname!r}")
        self.hostname = hostname
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: IO[str] | None = open(self.path, "w", encoding="ascii", newline="\n")  # noqa: SIM115
        self._warned_nonuniform = False
        for line in HEADER_LINES:
            self._file.write(line + "\n")

    def write_param(self, name: str, value: object) -> None:
        """Writes ``PARAM name value`` (``value`` as ``str(value)``; neither may contain whitespace)."""
        text = str(value)
        for what, word in (("name", name), ("value", text)):
            if not word or any(ch.isspace() for ch in word):
                raise format_error(self.path, None, f"PARAM {what} must be one non-empty word, got {word!r}")
        self._emit(f"PARAM {name} {text}")

    def write_odom(
        self, stamp_s: float, pose_xyt: np.ndarray, tv_m_s: float, rv_rad_s: float, accel: float = 0.0
    ) -> None:
        """Writes ``ODOM x y theta tv rv accel``.

        Args:
            stamp_s: time stamp, s.
            pose_xyt: (3,) odometry pose of the robot base (m, m, rad).
            tv_m_s: translational velocity, m/s.
            rv_rad_s: rotational velocity, rad/s.
            accel: translational acceleration, m/s^2.
        """
        fields = [*_pose_fields(pose_xyt), _m(tv_m_s), _m(rv_rad_s), _m(accel)]
        self._emit("ODOM " + " ".join(fields), stamp_s)

    def write_truepos(self, stamp_s: float, true_pose_xyt: np.ndarray, odom_pose_xyt: np.ndarray) -> None:
        """Writes ``TRUEPOS true_x true_y true_theta odom_x odom_y odom_theta`` (ground-truth reference).

        Args:
            stamp_s: time stamp, s.
            true_pose_xyt: (3,) true pose of the robot base in the world frame.
            odom_pose_xyt: (3,) odometry pose at the same time.
        """
        fields = [*_pose_fields(true_pose_xyt), *_pose_fields(odom_pose_xyt)]
        self._emit("TRUEPOS " + " ".join(fields), stamp_s)

    def write_flaser(
        self,
        stamp_s: float,
        ranges_m: np.ndarray,
        laser_pose_xyt: np.ndarray,
        odom_pose_xyt: np.ndarray,
        *,
        no_return_m: float = FLASER_NO_RETURN_M,
    ) -> None:
        """Writes ``FLASER n r1..rn x y theta odom_x odom_y odom_theta`` for a 180 deg front scanner.

        Args:
            stamp_s: time stamp, s.
            ranges_m: (n,) ranges, m, beams evenly spread from -90 deg to +90 deg inclusive; 0, negative or
                non-finite = no return.
            laser_pose_xyt: (3,) pose of the laser in the odometry frame.
            odom_pose_xyt: (3,) odometry pose of the robot base.
            no_return_m: value written for beams without a return, m.
        """
        ranges = _ranges_text(np.asarray(ranges_m, dtype=np.float64).reshape(-1), no_return_m)
        poses = [*_pose_fields(laser_pose_xyt), *_pose_fields(odom_pose_xyt)]
        self._emit(" ".join(["FLASER", str(len(ranges)), *ranges, *poses]), stamp_s)

    def write_robotlaser(
        self,
        scan: LaserScan,
        laser_pose_xyt: np.ndarray | None,
        robot_pose_xyt: np.ndarray,
        tv_m_s: float,
        rv_rad_s: float,
        laser_type: int = 0,
        *,
        accuracy_m: float = 0.01,
        forward_safety_dist_m: float = 0.0,
        side_safety_dist_m: float = 0.0,
        turn_axis_m: float = 0.0,
    ) -> None:
        """Writes a ``ROBOTLASER1`` message for a scan (time stamp ``scan.stamp_s``).

        Args:
            scan: the scan; beam angles are stored as first angle + mean signed increment.
            laser_pose_xyt: (3,) pose of the laser in the odometry frame, or None to compute it from
                ``robot_pose_xyt`` and the planar part of ``scan.T_base_sensor``.
            robot_pose_xyt: (3,) odometry pose of the robot base.
            tv_m_s: translational velocity, m/s.
            rv_rad_s: rotational velocity, rad/s.
            laser_type: CARMEN laser type code (0 = SICK LMS).
            accuracy_m: range accuracy, m.
            forward_safety_dist_m, side_safety_dist_m, turn_axis_m: CARMEN robot fields, m.

        Raises:
            DataFormatError: the scanner is tilted by more than 10 deg (not a planar scan).
        """
        try:
            mount, mirrored = _planar_mount(scan.T_base_sensor)
        except ValueError as err:
            raise format_error(self.path, None, f"ROBOTLASER1 of '{scan.sensor}': {err}") from None
        robot = np.asarray(robot_pose_xyt, dtype=np.float64)
        laser = compose_xyt(robot, mount) if laser_pose_xyt is None else np.asarray(laser_pose_xyt, float)
        start, res = self._angle_grid(scan.angles_rad, mirrored)
        n = len(scan.ranges_m)
        max_text = fmt_float(scan.max_range_m, 3)
        ranges = _ranges_text(np.asarray(scan.ranges_m, dtype=np.float64), float(max_text))
        fields = [str(int(laser_type)), _rad(start), _rad(res * max(n - 1, 0)), _rad(res), max_text]
        fields += [_m(accuracy_m), "0", str(n), *ranges, "0", *_pose_fields(laser), *_pose_fields(robot)]
        fields += [_m(v) for v in (tv_m_s, rv_rad_s, forward_safety_dist_m, side_safety_dist_m, turn_axis_m)]
        self._emit("ROBOTLASER1 " + " ".join(fields), scan.stamp_s)

    def close(self) -> None:
        """Closes the file; further writes raise."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> CarmenWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _angle_grid(self, angles_rad: np.ndarray, mirrored: bool) -> tuple[float, float]:
        angles = -np.asarray(angles_rad, dtype=np.float64) if mirrored else np.asarray(angles_rad, np.float64)
        if len(angles) == 0:
            return 0.0, 0.0
        res = float((angles[-1] - angles[0]) / max(len(angles) - 1, 1))
        grid = angles[0] + res * np.arange(len(angles))
        if np.abs(grid - angles).max() > 1e-6 and not self._warned_nonuniform:
            self._warned_nonuniform = True
            logger.warning("%s: non-uniform beam angles stored as a uniform grid (format limit)", self.path)
        return float(angles[0]), res

    def _emit(self, body: str, stamp_s: float | None = None) -> None:
        if self._file is None:
            raise format_error(self.path, None, "write called after close()")
        if stamp_s is not None:
            if not math.isfinite(stamp_s):
                raise format_error(self.path, None, f"{body.split()[0]}: time stamp must be finite")
            stamp = _s(stamp_s)
            body = f"{body} {stamp} {self.hostname} {stamp}"
        self._file.write(body + "\n")


def _m(v: float) -> str:
    return fmt_float(v, 6)


def _rad(v: float) -> str:
    return fmt_float(v, 9)


def _s(v: float) -> str:
    return fmt_float(v, 6)


def _pose_fields(xyt: np.ndarray) -> list[str]:
    x, y, t = np.asarray(xyt, dtype=np.float64).reshape(3)
    return [_m(x), _m(y), _rad(wrap_angle(t))]


def _ranges_text(ranges: np.ndarray, no_return_m: float) -> list[str]:
    """Range fields (3 decimals): no-returns as ``no_return_m``, valid beams clamped to stay valid."""
    valid = np.isfinite(ranges) & (ranges > 0) & (ranges < no_return_m)
    out = np.full(len(ranges), float(no_return_m))
    out[valid] = np.clip(np.round(ranges[valid], 3), 0.001, float(no_return_m) - 0.001)
    return [f"{v:.3f}" for v in out.tolist()]  # all values are >= 0.001: no negative zero to guard against


# ----------------------------------------------------------------------------------------------------------
# Reader


class OdomStream(NamedTuple):
    """ODOM messages.

    Attributes:
        stamps_s: (K,) time stamps, s.
        poses_xyt: (K, 3) robot base poses (x, y, theta) in the odometry frame, m, rad.
        tv_m_s: (K,) translational velocities, m/s.
        rv_rad_s: (K,) rotational velocities, rad/s.
    """

    stamps_s: np.ndarray
    poses_xyt: np.ndarray
    tv_m_s: np.ndarray
    rv_rad_s: np.ndarray


class TruePosStream(NamedTuple):
    """TRUEPOS messages (ground truth).

    Attributes:
        stamps_s: (K,) time stamps, s.
        poses_xyt: (K, 3) true robot base poses (x, y, theta) in the world frame, m, rad.
    """

    stamps_s: np.ndarray
    poses_xyt: np.ndarray


@dataclass
class CarmenLog:
    """Contents of a CARMEN log, in file order.

    Attributes:
        scans: laser scans of ROBOTLASER1/2, FLASER, RLASER and RAWLASER1..4 messages.
        laser_poses: (N, 3) laser pose (x, y, theta) in the odometry frame per scan as logged; NaN for
            RAWLASER.
        robot_poses: (N, 3) robot base pose per scan as logged (FLASER: odom pose); NaN for RAWLASER.
        odom: ODOM messages.
        truepos: TRUEPOS messages (ground truth); empty arrays when the log has none.
        truepos_odom: (K, 3) odometry poses logged with each TRUEPOS message.
        params: PARAM name -> value (text); a later PARAM overrides an earlier one.
        skipped: message type -> number of lines of that type that were not parsed (unknown types).
    """

    scans: list[LaserScan]
    laser_poses: np.ndarray
    robot_poses: np.ndarray
    odom: OdomStream
    truepos: TruePosStream
    truepos_odom: np.ndarray
    params: dict[str, str] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)


class _Fields:
    """Cursor over the tokens of one message line; every error names file, line, message type and layout."""

    def __init__(self, path: Path, line_no: int, tokens: list[str], layout: str) -> None:
        self.path, self.line_no, self.tokens, self.layout = path, line_no, tokens, layout
        self.kind = tokens[0]
        self.pos = 1

    def error(self, message: str) -> Exception:
        expected = f"{self.kind} {self.layout}"
        return format_error(self.path, self.line_no, f"{self.kind}: {message}; expected '{expected}'")

    def _take(self, name: str) -> str:
        if self.pos >= len(self.tokens):
            raise self.error(f"line ends early: field {self.pos} ({name}) is missing")
        tok = self.tokens[self.pos]
        self.pos += 1
        return tok

    def number(self, name: str) -> float:
        tok = self._take(name)
        try:
            value = float(tok)
        except ValueError:
            raise self.error(f"field {self.pos - 1} ({name}) must be a number, got {tok!r}") from None
        if not math.isfinite(value):
            raise self.error(f"field {self.pos - 1} ({name}) must be finite, got {tok!r}")
        return value

    def count(self, name: str) -> int:
        tok = self._take(name)
        if not tok.isdigit():
            raise self.error(f"field {self.pos - 1} ({name}) must be a non-negative integer, got {tok!r}")
        return int(tok)

    def ranges(self, n: int, name: str) -> np.ndarray:
        if self.pos + n > len(self.tokens):
            raise self.error(f"line ends early: {name} needs {n} values, {len(self.tokens) - self.pos} left")
        toks = self.tokens[self.pos : self.pos + n]
        self.pos += n
        try:
            return np.array([float(t) for t in toks], dtype=np.float64)
        except ValueError:
            raise self.error(f"{name} must be numbers, got {' '.join(toks[:8])!r}...") from None

    def numbers(self, names: str) -> np.ndarray:
        return np.array([self.number(name) for name in names.split()])

    def footer(self) -> float:
        """Parses ``ipc_timestamp ipc_hostname logger_timestamp`` and checks that nothing follows."""
        stamp = self.number("ipc_timestamp")
        self._take("ipc_hostname")
        self.number("logger_timestamp")
        if self.pos != len(self.tokens):
            raise self.error(f"{len(self.tokens) - self.pos} unexpected extra fields after logger_timestamp")
        return stamp


class _LogBuilder:
    """Accumulates parsed messages."""

    def __init__(self, T_base_laser: np.ndarray | None, flaser_max_range_m: float, path: Path) -> None:
        self.T_base_laser = T_base_laser
        self.flaser_max_range_m = flaser_max_range_m
        self.path = path
        self.scans: list[LaserScan] = []
        self.laser_poses: list[np.ndarray] = []
        self.robot_poses: list[np.ndarray] = []
        self.odom: list[np.ndarray] = []
        self.truepos: list[np.ndarray] = []
        self.params: dict[str, str] = {}
        self.skipped: dict[str, int] = {}
        self._mounts: dict[str, np.ndarray] = {}
        self._warned_mount = False

    def add_scan(self, f: _Fields, scan_args: dict, poses: tuple[np.ndarray, np.ndarray] | None) -> None:
        if self.T_base_laser is not None:
            T = self.T_base_laser.copy()
        elif poses is None:
            T = np.eye(4)
        else:
            mount = relative_xyt(poses[1], poses[0])
            self._check_mount(f, mount)
            T = xyt_to_T(mount)
        self.scans.append(LaserScan(T_base_sensor=T, min_range_m=0.0, **scan_args))
        nan = np.full(3, np.nan)
        self.laser_poses.append(nan if poses is None else poses[0])
        self.robot_poses.append(nan if poses is None else poses[1])

    def _check_mount(self, f: _Fields, mount: np.ndarray) -> None:
        first = self._mounts.setdefault(f.kind, mount)
        diff = np.abs(first - mount)
        diff[2] = abs(wrap_angle(first[2] - mount[2]))
        if diff.max() > _MOUNT_TOL and not self._warned_mount:
            self._warned_mount = True
            logger.warning(
                "%s:%d: %s: the laser pose relative to the robot pose changes between messages "
                "(%s vs %s); the log probably stores corrected poses - pass T_base_laser to read_carmen "
                "for the true mount",
                f.path, f.line_no, f.kind, np.round(first, 4).tolist(), np.round(mount, 4).tolist(),
            )

    def build(self) -> CarmenLog:
        odom = np.asarray(self.odom).reshape(-1, 6)
        true = np.asarray(self.truepos).reshape(-1, 7)
        return CarmenLog(
            scans=self.scans,
            laser_poses=np.asarray(self.laser_poses).reshape(-1, 3),
            robot_poses=np.asarray(self.robot_poses).reshape(-1, 3),
            odom=OdomStream(odom[:, 0].copy(), odom[:, 1:4].copy(), odom[:, 4].copy(), odom[:, 5].copy()),
            truepos=TruePosStream(true[:, 0].copy(), true[:, 1:4].copy()),
            truepos_odom=true[:, 4:7].copy(),
            params=self.params,
            skipped=self.skipped,
        )


def read_carmen(
    path: str | Path,
    T_base_laser: np.ndarray | None = None,
    *,
    flaser_max_range_m: float = FLASER_NO_RETURN_M,
) -> CarmenLog:
    """Reads a CARMEN log.

    Parses PARAM, ODOM, TRUEPOS, FLASER, RLASER, RAWLASER1..4 and ROBOTLASER1/2; other message types are
    counted in ``skipped``; comments (``#``) and blank lines are ignored. Range readings that are 0, negative,
    NaN/inf or at or beyond the maximum range become 0 (invalid).

    Args:
        path: the log file.
        T_base_laser: (4, 4) mount of the laser in the base frame to use for every scan instead of the one
            derived from the logged laser and robot poses (use it for logs with SLAM-corrected laser poses).
        flaser_max_range_m: FLASER/RLASER readings at or beyond this are no-returns, m (the format has no
            maximum-range field).

    Returns:
        The parsed log.

    Raises:
        MissingDataError: the file does not exist.
        DataFormatError: a known message is malformed (the message names file, line, message type and the
            expected layout).
    """
    path = Path(path)
    if not path.is_file():
        raise MissingDataError(f"{path}: CARMEN log not found")
    mount = None if T_base_laser is None else np.asarray(T_base_laser, dtype=np.float64)
    if mount is not None and mount.shape != (4, 4):
        raise format_error(path, None, f"T_base_laser must be (4, 4), got {mount.shape}")
    log = _LogBuilder(mount, float(flaser_max_range_m), path)
    with open(path, encoding="utf-8", errors="replace") as f:
        for line_no, raw in enumerate(f, start=1):
            tokens = raw.split()
            if not tokens or tokens[0].startswith("#"):
                continue
            parser = _PARSERS.get(tokens[0])
            if parser is None:
                log.skipped[tokens[0]] = log.skipped.get(tokens[0], 0) + 1
                continue
            parser(path, line_no, tokens, log)
    return log.build()


def _clean_ranges(ranges: np.ndarray, max_range_m: float) -> np.ndarray:
    """float32 ranges with 0 for NaN/inf, <= 0 and (when max_range_m > 0) >= max_range_m."""
    ok = np.isfinite(ranges) & (ranges > 0)
    if max_range_m > 0:
        ok &= ranges < max_range_m
    return np.where(ok, ranges, 0.0).astype(np.float32)


def _parse_param(path: Path, line_no: int, tokens: list[str], log: _LogBuilder) -> None:
    if len(tokens) < 3:
        raise format_error(path, line_no, "PARAM: expected 'PARAM param_name param_value'")
    value = tokens[2:]
    if len(value) >= 4 and _is_number(value[-3]) and _is_number(value[-1]):
        value = value[:-3]  # newer logs append "ipc_timestamp ipc_hostname logger_timestamp"
    log.params[tokens[1]] = " ".join(value)


def _parse_odom(path: Path, line_no: int, tokens: list[str], log: _LogBuilder) -> None:
    f = _Fields(path, line_no, tokens, "x y theta tv rv accel " + _FOOTER)
    values = f.numbers("x y theta tv rv accel")
    stamp = f.footer()
    log.odom.append(np.array([stamp, *values[:5]]))


def _parse_truepos(path: Path, line_no: int, tokens: list[str], log: _LogBuilder) -> None:
    f = _Fields(path, line_no, tokens, "true_x true_y true_theta odom_x odom_y odom_theta " + _FOOTER)
    values = f.numbers("true_x true_y true_theta odom_x odom_y odom_theta")
    stamp = f.footer()
    log.truepos.append(np.array([stamp, *values]))


def _parse_flaser(path: Path, line_no: int, tokens: list[str], log: _LogBuilder) -> None:
    layout = "num_readings [range_readings] x y theta odom_x odom_y odom_theta " + _FOOTER
    f = _Fields(path, line_no, tokens, layout)
    n = f.count("num_readings")
    ranges = f.ranges(n, "range_readings")
    laser = f.numbers("x y theta")
    robot = f.numbers("odom_x odom_y odom_theta")
    stamp = f.footer()
    scan = {
        "sensor": f"laser{_NUMBERED_LASER[f.kind]}",
        "stamp_s": stamp,
        "ranges_m": _clean_ranges(ranges, log.flaser_max_range_m),
        "angles_rad": np.linspace(-math.pi / 2, math.pi / 2, n),
        "max_range_m": log.flaser_max_range_m,
    }
    log.add_scan(f, scan, (laser, robot))


def _parse_laser_block(f: _Fields) -> dict:
    """Parses the RAWLASER fields shared by RAWLASER and ROBOTLASER messages into LaserScan arguments."""
    f.number("laser_type")
    start, fov, res, max_range = f.numbers("start_angle field_of_view angular_resolution maximum_range")
    f.number("accuracy")
    f.number("remission_mode")
    n = f.count("num_readings")
    ranges = f.ranges(n, "range_readings")
    f.ranges(f.count("num_remissions"), "remission values")
    if res == 0 and n > 1:
        res = fov / (n - 1)
    if max_range <= 0:  # some logs leave it 0: fall back to the largest reading
        max_range = float(np.max(np.where(np.isfinite(ranges), ranges, 0.0), initial=0.0))
        ranges_m = _clean_ranges(ranges, 0.0)
    else:
        ranges_m = _clean_ranges(ranges, max_range)
    return {
        "ranges_m": ranges_m,
        "angles_rad": start + res * np.arange(n, dtype=np.float64),
        "max_range_m": float(max_range),
    }


def _parse_rawlaser(path: Path, line_no: int, tokens: list[str], log: _LogBuilder) -> None:
    f = _Fields(path, line_no, tokens, _RAW_LAYOUT + " " + _FOOTER)
    scan = _parse_laser_block(f)
    scan["stamp_s"] = f.footer()
    scan["sensor"] = f"laser{f.kind[-1]}"
    log.add_scan(f, scan, None)


def _parse_robotlaser(path: Path, line_no: int, tokens: list[str], log: _LogBuilder) -> None:
    f = _Fields(path, line_no, tokens, _ROBOT_LAYOUT + " " + _FOOTER)
    scan = _parse_laser_block(f)
    laser = f.numbers("laser_pose_x laser_pose_y laser_pose_theta")
    robot = f.numbers("robot_pose_x robot_pose_y robot_pose_theta")
    f.numbers("laser_tv laser_rv forward_safety_dist side_safety_dist turn_axis")
    scan["stamp_s"] = f.footer()
    scan["sensor"] = f"laser{_NUMBERED_LASER[f.kind]}"
    log.add_scan(f, scan, (laser, robot))


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


_PARSERS = {
    "PARAM": _parse_param,
    "ODOM": _parse_odom,
    "TRUEPOS": _parse_truepos,
    "FLASER": _parse_flaser,
    "RLASER": _parse_flaser,
    "RAWLASER1": _parse_rawlaser,
    "RAWLASER2": _parse_rawlaser,
    "RAWLASER3": _parse_rawlaser,
    "RAWLASER4": _parse_rawlaser,
    "ROBOTLASER1": _parse_robotlaser,
    "ROBOTLASER2": _parse_robotlaser,
}
