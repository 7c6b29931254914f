"""TUM trajectory files (``timestamp tx ty tz qx qy qz qw``) and their covariance sidecar.

One pose per line: the time stamp in seconds, the position of the frame in metres and its orientation as a
unit quaternion in ``qx qy qz qw`` order, all of the pose ``T_world_x`` (frame x in the world frame). This is
the format of the TUM RGB-D benchmark's ``groundtruth.txt`` and the one ``evo`` reads with
``read_tum_trajectory_file``.

Written files are deterministic: stamps and translations with 6 decimals (microseconds, micrometres),
quaternions with 9 decimals, sign chosen so that ``qw >= 0``, no negative zeros, ``\\n`` line ends.

The optional covariance sidecar ``<stem>.cov<suffix>`` (``est.txt`` -> ``est.cov.txt``) holds, per line, the
time stamp followed by the row-major upper triangle of the pose covariance: 21 values for a 6x6 SE(3)
covariance in ``(x y z rx ry rz)`` order (m, rad) or 6 values for a 3x3 planar covariance in ``(x y yaw)``
order. The covariance is expressed in whatever tangent convention the estimator that produced it uses; the
file only stores it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO

import numpy as np
from scipy.spatial.transform import Rotation

from simnav.geometry import se3
from simnav.io import MissingDataError, format_error

TUM_HEADER = "# timestamp tx ty tz qx qy qz qw"
SE3_COV_NAMES = ("x", "y", "z", "rx", "ry", "rz")
SE2_COV_NAMES = ("x", "y", "yaw")
_ORTHONORMAL_TOL = 1e-6


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A timed sequence of poses.

    Attributes:
        stamps_s: (N,) float64 time stamps, s.
        T: (N, 4, 4) float64 poses ``T_world_x`` (frame x in the world frame), translations in m.
    """

    stamps_s: np.ndarray
    T: np.ndarray

    def __post_init__(self) -> None:
        stamps = np.asarray(self.stamps_s, dtype=np.float64).reshape(-1)
        poses = np.asarray(self.T, dtype=np.float64).reshape(-1, 4, 4)
        if len(stamps) != len(poses):
            raise ValueError(f"Trajectory: {len(stamps)} stamps but {len(poses)} poses")
        object.__setattr__(self, "stamps_s", stamps)
        object.__setattr__(self, "T", poses)

    def __len__(self) -> int:
        return len(self.stamps_s)

    @property
    def positions_m(self) -> np.ndarray:
        """(N, 3) positions of frame x in the world frame, m."""
        return self.T[:, :3, 3].copy()

    @property
    def quaternions_xyzw(self) -> np.ndarray:
        """(N, 4) unit quaternions ``qx qy qz qw`` of the orientations, with ``qw >= 0``."""
        if len(self) == 0:
            return np.zeros((0, 4))
        return _canonical_quat(Rotation.from_matrix(self.T[:, :3, :3]).as_quat())


def sidecar_path(path: str | Path) -> Path:
    """Path of the covariance sidecar of a trajectory file.

    ``est.txt`` -> ``est.cov.txt``; ``est`` -> ``est.cov``.
    """
    path = Path(path)
    return path.with_name(f"{path.stem}.cov{path.suffix}")


class TumWriter:
    """Streams poses into a TUM trajectory file, one line per :meth:`write`.

    Writing the same poses through :class:`TumWriter` or :func:`write_tum` gives the same bytes. When
    covariances are given, the sidecar (:func:`sidecar_path`) is opened at the first pose; then every pose
    needs one of the same size.

    Example:
        >>> with TumWriter("est.txt") as w:  # doctest: +SKIP
        ...     w.write(0.0, np.eye(4))
    """

    def __init__(self, path: str | Path) -> None:
        """Creates (or truncates) the file and writes the header.

        Args:
            path: trajectory file; missing parent folders are created.
        """
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: IO[str] | None = open(self.path, "w", encoding="ascii", newline="\n")  # noqa: SIM115
        self._file.write(TUM_HEADER + "\n")
        self._cov_file: IO[str] | None = None
        self._cov_dim: int | None = None
        self._count = 0

    @property
    def count(self) -> int:
        """Number of poses written so far."""
        return self._count

    def write(self, stamp_s: float, T: np.ndarray, covariance: np.ndarray | None = None) -> None:
        """Appends one pose.

        Args:
            stamp_s: time stamp, s.
            T: (4, 4) pose ``T_world_x``; the rotation block must be orthonormal to 1e-6.
            covariance: optional (6, 6) SE(3) covariance in ``(x y z rx ry rz)`` order or (3, 3) planar
                covariance in ``(x y yaw)`` order; its upper triangle goes to the sidecar.

        Raises:
            DataFormatError: the pose or covariance is malformed, or covariances come for some poses only.
        """
        if self._file is None:
            raise format_error(self.path, None, "write() called after close()")
        what = f"pose {self._count}"
        stamp = _check_stamp(self.path, what, stamp_s)
        pose = _check_pose(self.path, what, T)
        cov_line = self._covariance_line(what, stamp, covariance)
        self._file.write(format_tum_line(stamp, pose) + "\n")
        if cov_line is not None and self._cov_file is not None:
            self._cov_file.write(cov_line + "\n")
        self._count += 1

    def close(self) -> None:
        """Flushes and closes the file (and the sidecar); further writes raise."""
        for f in (self._file, self._cov_file):
            if f is not None:
                f.close()
        self._file = None
        self._cov_file = None

    def __enter__(self) -> TumWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _covariance_line(self, what: str, stamp: float, covariance: np.ndarray | None) -> str | None:
        has_cov = covariance is not None
        if self._count > 0 and has_cov != (self._cov_dim is not None):
            state = "with" if self._cov_dim is not None else "without"
            raise format_error(
                self.path, None, f"{what}: the first pose was written {state} a covariance; give all or none"
            )
        if covariance is None:
            return None
        cov = _check_covariance(self.path, what, covariance, self._cov_dim)
        if self._cov_file is None:
            self._open_sidecar(cov.shape[0])
        return format_covariance_line(stamp, cov)

    def _open_sidecar(self, dim: int) -> None:
        self._cov_dim = dim
        self._cov_file = open(sidecar_path(self.path), "w", encoding="ascii", newline="\n")  # noqa: SIM115
        for line in covariance_header(dim):
            self._cov_file.write(line + "\n")


def write_tum(
    path: str | Path, stamps_s: np.ndarray, T_world_x: np.ndarray, covariances: np.ndarray | None = None
) -> None:
    """Writes a whole trajectory to a TUM file (and its covariance sidecar when covariances are given).

    Args:
        path: trajectory file, e.g. ``est.txt``; the sidecar goes to ``est.cov.txt``.
        stamps_s: (N,) time stamps, s.
        T_world_x: (N, 4, 4) poses of frame x in the world frame, m.
        covariances: optional (N, 6, 6) SE(3) covariances in ``(x y z rx ry rz)`` order (m, rad) or (N, 3, 3)
            planar covariances in ``(x y yaw)`` order.

    Raises:
        DataFormatError: shapes disagree, or a pose/covariance is malformed.
    """
    stamps = np.asarray(stamps_s, dtype=np.float64).reshape(-1)
    poses = np.asarray(T_world_x, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) != len(stamps):
        raise format_error(
            path, None, f"expected (N,) stamps and (N, 4, 4) poses, got {stamps.shape} and {poses.shape}"
        )
    covs = None if covariances is None else np.asarray(covariances, dtype=np.float64)
    if covs is not None and (covs.ndim != 3 or len(covs) != len(stamps)):
        raise format_error(path, None, f"expected (N, 6, 6) or (N, 3, 3) covariances, got {covs.shape}")
    with TumWriter(path) as writer:
        for i, stamp in enumerate(stamps):
            writer.write(float(stamp), poses[i], None if covs is None else covs[i])
        if covs is not None and len(stamps) == 0 and covs.shape[1:] in ((6, 6), (3, 3)):
            writer._open_sidecar(covs.shape[1])


def read_tum(path: str | Path) -> Trajectory:
    """Reads a TUM trajectory file.

    Lines starting with ``#`` and blank lines are skipped; values may be separated by spaces, tabs or commas.
    Quaternions are normalised.

    Args:
        path: the file.

    Returns:
        The trajectory (stamps in s, poses ``T_world_x``).

    Raises:
        MissingDataError: the file does not exist.
        DataFormatError: a line does not hold 8 finite numbers or its quaternion has zero norm.
    """
    stamps, rows = [], []
    for line_no, values in _numeric_lines(path, "timestamp tx ty tz qx qy qz qw", lambda n: n == 8):
        if np.linalg.norm(values[4:]) < 1e-12:
            raise format_error(path, line_no, "quaternion qx qy qz qw has zero norm")
        stamps.append(values[0])
        rows.append(values[1:])
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    if rows:
        data = np.asarray(rows)
        quats = data[:, 3:] / np.linalg.norm(data[:, 3:], axis=1, keepdims=True)
        poses[:, :3, :3] = Rotation.from_quat(quats).as_matrix()
        poses[:, :3, 3] = data[:, :3]
    return Trajectory(np.asarray(stamps, dtype=np.float64), poses)


def read_tum_covariance(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Reads a covariance sidecar written by :func:`write_tum` / :class:`TumWriter`.

    Args:
        path: the sidecar (``est.cov.txt``), not the trajectory file.

    Returns:
        ``(stamps_s (N,), covariances (N, d, d))`` with d = 6 (x y z rx ry rz) or 3 (x y yaw), symmetric.

    Raises:
        MissingDataError: the file does not exist.
        DataFormatError: a line has neither 1 + 21 nor 1 + 6 numbers, or the sizes differ between lines.
    """
    stamps, covs = [], []
    dim = None
    expected = "timestamp + 21 (6x6) or 6 (3x3) upper-triangle values"
    for line_no, values in _numeric_lines(path, expected, lambda n: n in (22, 7)):
        line_dim = 6 if len(values) == 22 else 3
        if dim is not None and line_dim != dim:
            want = 1 + dim * (dim + 1) // 2
            raise format_error(path, line_no, f"expected {want} values as on the first line")
        dim = line_dim
        stamps.append(values[0])
        covs.append(_from_upper(np.asarray(values[1:]), dim))
    if dim is None:
        return np.zeros(0), np.zeros((0, 6, 6))
    return np.asarray(stamps), np.stack(covs)


def format_tum_line(stamp_s: float, T: np.ndarray) -> str:
    """One TUM line ``timestamp tx ty tz qx qy qz qw`` for a (4, 4) pose (no line end)."""
    w, x, y, z = se3.to_quat_wxyz(T[:3, :3])
    q = (x, y, z, w)
    fields = [fmt_float(stamp_s, 6)]
    fields += [fmt_float(v, 6) for v in T[:3, 3]]
    fields += [fmt_float(v, 9) for v in q]
    return " ".join(fields)


def format_covariance_line(stamp_s: float, cov: np.ndarray) -> str:
    """One sidecar line: the stamp and the row-major upper triangle of ``cov`` (no line end)."""
    upper = cov[np.triu_indices(cov.shape[0])]
    return " ".join([fmt_float(stamp_s, 6)] + [fmt_sci(v) for v in upper])


def covariance_header(dim: int) -> list[str]:
    """Comment lines documenting the sidecar layout for a (dim, dim) covariance."""
    names = SE3_COV_NAMES if dim == 6 else SE2_COV_NAMES
    units = "x y z in m, rx ry rz in rad" if dim == 6 else "x y in m, yaw in rad"
    cols = [f"c_{names[i]}_{names[j]}" for i, j in zip(*np.triu_indices(dim), strict=True)]
    return [
        f"# pose covariance ({' '.join(names)}; {units}): row-major upper triangle of the {dim}x{dim} matrix",
        "# timestamp " + " ".join(cols),
    ]


def fmt_float(value: float, decimals: int) -> str:
    """Fixed-point text of ``value`` with ``decimals`` digits; never prints a negative zero."""
    text = f"{float(value):.{decimals}f}"
    if text.startswith("-") and not text.strip("-0."):
        return text[1:]
    return text


def fmt_sci(value: float) -> str:
    """Scientific text with 9 significant decimals (``1.234567890e-03``); never prints a negative zero."""
    value = float(value)
    return f"{0.0 if value == 0 else value:.9e}"


def _canonical_quat(q: np.ndarray) -> np.ndarray:
    """(N, 4) xyzw quaternions with the sign chosen so that qw >= 0."""
    return np.where(q[:, 3:4] < 0, -q, q)


def _check_stamp(path: Path, what: str, stamp_s: float) -> float:
    stamp = float(stamp_s)
    if not np.isfinite(stamp):
        raise format_error(path, None, f"{what}: time stamp must be finite, got {stamp}")
    return stamp


def _check_pose(path: Path, what: str, T: np.ndarray) -> np.ndarray:
    pose = np.asarray(T, dtype=np.float64)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise format_error(path, None, f"{what}: expected a finite (4, 4) pose, got shape {pose.shape}")
    R = pose[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > _ORTHONORMAL_TOL or np.linalg.det(R) <= 0:
        raise format_error(path, None, f"{what}: the rotation block is not a proper rotation matrix")
    return pose


def _check_covariance(path: Path, what: str, covariance: np.ndarray, dim: int | None) -> np.ndarray:
    cov = np.asarray(covariance, dtype=np.float64)
    ok_shape = cov.shape in ((6, 6), (3, 3)) if dim is None else cov.shape == (dim, dim)
    if not ok_shape or not np.all(np.isfinite(cov)):
        want = "(6, 6) or (3, 3)" if dim is None else f"({dim}, {dim}) as for the first pose"
        raise format_error(path, None, f"{what}: expected a finite {want} covariance, got shape {cov.shape}")
    return cov


def _from_upper(values: np.ndarray, dim: int) -> np.ndarray:
    cov = np.zeros((dim, dim))
    cov[np.triu_indices(dim)] = values
    return cov + np.triu(cov, 1).T


def _numeric_lines(
    path: str | Path, expected: str, count_ok: Callable[[int], bool]
) -> Iterator[tuple[int, list[float]]]:
    """Yields ``(line_no, values)`` of each data line of a whitespace/comma separated numeric file."""
    path = Path(path)
    if not path.is_file():
        raise MissingDataError(f"{path}: file not found")
    with open(path, encoding="utf-8", errors="replace") as f:
        for line_no, raw in enumerate(f, start=1):
            text = raw.strip()
            if not text or text.startswith("#"):
                continue
            tokens = text.replace(",", " ").split()
            if not count_ok(len(tokens)):
                raise format_error(path, line_no, f"expected '{expected}', got {len(tokens)} values")
            yield line_no, _parse_floats(path, line_no, tokens, expected)


def _parse_floats(path: Path, line_no: int, tokens: list[str], expected: str) -> list[float]:
    try:
        values = [float(t) for t in tokens]
    except ValueError:
        got = " ".join(tokens)
        raise format_error(path, line_no, f"expected numbers '{expected}', got {got!r}") from None
    if not all(np.isfinite(values)):
        raise format_error(path, line_no, f"expected finite numbers '{expected}', got {' '.join(tokens)!r}")
    return values

