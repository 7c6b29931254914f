"""Pinhole camera model and the camera frame conventions used by simnav.

Frames:

* **optical** frame: z forward (along the optical axis), x right, y down in the image. All methods of
  :class:`PinholeCamera` take and return points in this frame, in metres.
* **body** frame of a camera: x forward, y left, z up (REP-103 style, like the robot base).
* **MuJoCo camera** frame: the camera looks along -z, x right, y up in the image.

Pixel coordinates ``(u, v)`` have their origin at the centre of the top-left pixel: pixel ``(i, j)`` (column
i, row j) covers ``[i - 0.5, i + 0.5) x [j - 0.5, j + 0.5)``, so the image spans
``[-0.5, W - 0.5) x [-0.5, H - 0.5)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

R_BODY_OPTICAL: np.ndarray = np.array([
    [0.0, 0.0, 1.0],
    [-1.0, 0.0, 0.0],
    [0.0, -1.0, 0.0],
])
"""(3, 3) rotation of the optical frame in the camera body frame: its columns are the optical x, y, z axes
expressed in the body frame (optical x = -body y, optical y = -body z, optical z = body x), so
``p_body = R_BODY_OPTICAL @ p_optical`` and
``T_body_optical = se3.from_rotation_translation(R_BODY_OPTICAL)``."""

R_MUJOCOCAM_OPTICAL: np.ndarray = np.diag([1.0, -1.0, -1.0])
"""(3, 3) rotation of the optical frame in a MuJoCo camera frame (which looks along -z, x right, y up):
optical x = camera x, optical y = -camera y, optical z = -camera z, so
``p_mjcam = R_MUJOCOCAM_OPTICAL @ p_optical``.
With ``T_world_mjcam`` from the simulator,
``T_world_optical = T_world_mjcam @ se3.from_rotation_translation(R_MUJOCOCAM_OPTICAL)``."""

R_BODY_OPTICAL.setflags(write=False)
R_MUJOCOCAM_OPTICAL.setflags(write=False)


def _points(x: ArrayLike, dim: int, name: str) -> np.ndarray:
    """Converts ``x`` to float64 and checks that its last dimension is ``dim``."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim < 1 or a.shape[-1] != dim:
        raise ValueError(f"{name} must have shape (N, {dim}), got {a.shape}")
    return a


@dataclass(frozen=True)
class PinholeCamera:
    """Ideal pinhole camera (no distortion).

    Attributes:
        width: image width W, pixels.
        height: image height H, pixels.
        fx: focal length along u, pixels.
        fy: focal length along v, pixels.
        cx: principal point u, pixels (0 = centre of the first column).
        cy: principal point v, pixels (0 = centre of the first row).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        size = (self.width, self.height)
        if any(int(n) != n or n < 1 for n in size):
            raise ValueError(f"image size must be positive integers, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0 and math.isfinite(self.fx) and math.isfinite(self.fy)):
            raise ValueError(f"focal lengths must be positive and finite, got fx={self.fx}, fy={self.fy}")

    @classmethod
    def from_fovy(cls, width: int, height: int, fovy_deg: float) -> PinholeCamera:
        """Camera with a vertical field of view, as MuJoCo defines its ``fovy`` cameras.

        Args:
            width: image width W, pixels.
            height: image height H, pixels.
            fovy_deg: full vertical field of view, degrees, in (0, 180).

        Returns:
            Camera with ``fx = fy = (H / 2) / tan(fovy / 2)``, ``cx = (W - 1) / 2``, ``cy = (H - 1) / 2``.
        """
        if not 0.0 < fovy_deg < 180.0:
            raise ValueError(f"fovy_deg must be in (0, 180), got {fovy_deg}")
        f = (height / 2.0) / math.tan(math.radians(fovy_deg) / 2.0)
        return cls(int(width), int(height), f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def hfov_rad(self) -> float:
        """Full horizontal field of view from the left to the right image edge, rad."""
        return math.atan((self.cx + 0.5) / self.fx) + math.atan((self.width - 0.5 - self.cx) / self.fx)

    @property
    def vfov_rad(self) -> float:
        """Full vertical field of view from the top to the bottom image edge, rad."""
        return math.atan((self.cy + 0.5) / self.fy) + math.atan((self.height - 0.5 - self.cy) / self.fy)

    def project(self, points_optical: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Projects points onto the image.

        Args:
            points_optical: (N, 3) points in the optical frame, m.

        Returns:
            ``(uv, valid)``: (N, 2) pixel coordinates and an (N,) bool mask, true where ``z > 0`` and the
            pixel lies in ``[-0.5, W - 0.5) x [-0.5, H - 0.5)``. Rows with ``z <= 0`` have ``uv = NaN``.
        """
        P = _points(points_optical, 3, "points_optical")
        z = P[..., 2]
        front = z > 0.0
        safe_z = np.where(front, z, 1.0)
        u = np.where(front, self.fx * P[..., 0] / safe_z + self.cx, np.nan)
        v = np.where(front, self.fy * P[..., 1] / safe_z + self.cy, np.nan)
        with np.errstate(invalid="ignore"):
            inside = (u >= -0.5) & (u < self.width - 0.5) & (v >= -0.5) & (v < self.height - 0.5)
        return np.stack([u, v], axis=-1), front & inside

    def back_project(self, uv: ArrayLike, depth_m: ArrayLike) -> np.ndarray:
        """Lifts pixels with known depth to 3D points.

        Args:
            uv: (N, 2) pixel coordinates.
            depth_m: (N,) depth along the optical axis (the z coordinate, not the ray length), m.

        Returns:
            (N, 3) points in the optical frame, m.
        """
        uv = _points(uv, 2, "uv")
        d = np.asarray(depth_m, dtype=np.float64)
        if d.shape != uv.shape[:-1]:
            raise ValueError(f"depth_m must have shape {uv.shape[:-1]}, got {d.shape}")
        x = (uv[..., 0] - self.cx) / self.fx
        y = (uv[..., 1] - self.cy) / self.fy
        return np.stack([x * d, y * d, d], axis=-1)

    def rays_optical(self) -> np.ndarray:
        """Viewing rays of all pixel centres, scaled to unit z.

        Returns:
            (H, W, 3) rays ``(x/z, y/z, 1)`` in the optical frame; ``rays[v, u]`` belongs to pixel (u, v).
        """
        x = (np.arange(self.width, dtype=np.float64) - self.cx) / self.fx
        y = (np.arange(self.height, dtype=np.float64) - self.cy) / self.fy
        rays = np.ones((self.height, self.width, 3))
        rays[..., 0] = x[None, :]
        rays[..., 1] = y[:, None]
        return rays

    def back_project_depth(self, depth_m: ArrayLike) -> np.ndarray:
        """Lifts a whole depth image to 3D points.

        Args:
            depth_m: (H, W) depth image (z along the optical axis), m; 0 marks an invalid pixel.

        Returns:
            (H, W, 3) points in the optical frame, m; invalid (0-depth) pixels give (0, 0, 0).
        """
        d = np.asarray(depth_m, dtype=np.float64)
        if d.shape != (self.height, self.width):
            raise ValueError(f"depth_m must have shape ({self.height}, {self.width}), got {d.shape}")
        return self.rays_optical() * d[..., None]

    def scaled(self, factor: float) -> PinholeCamera:
        """Camera of the image resized by ``factor`` (e.g. 0.5 for the next pyramid level).

        The new size is ``round(W * factor) x round(H * factor)``; intrinsics use the exact per-axis ratios
        ``s = W' / W`` (equal to ``factor`` when ``W * factor`` is an integer) and keep pixel centres at
        integer coordinates: ``fx' = fx * s``, ``cx' = (cx + 0.5) * s - 0.5`` (likewise for y).

        Args:
            factor: resize factor, > 0.

        Returns:
            The camera of the resized image.
        """
        if not factor > 0.0:
            raise ValueError(f"factor must be positive, got {factor}")
        w, h = round(self.width * factor), round(self.height * factor)
        if w < 1 or h < 1:
            raise ValueError(f"scaling {self.width}x{self.height} by {factor} leaves an empty image")
        sx, sy = w / self.width, h / self.height
        return PinholeCamera(
            width=w,
            height=h,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
        )


def box_room_depth(T_world_camera: np.ndarray, K: np.ndarray, shape: tuple[int, int], room: ArrayLike,
                   boxes: ArrayLike = ()) -> tuple[np.ndarray, np.ndarray]:
    """Exact z-depth of a room of axis-aligned boxes, seen from inside: synthetic frames with known geometry.

    Args:
        T_world_camera: (4, 4) pose of the optical frame in the world.
        K: (3, 3) intrinsics.
        shape: image (height, width).
        room: (2, 3) opposite corners ``[min, max]`` of the room (the camera is inside), m.
        boxes: (B, 2, 3) corners ``[min, max]`` of solid boxes in the room, m.

    Returns:
        (H, W) z-depth (float64, m; the ray parameter, as the optical z of every ray is 1) and (H, W, 3) world
        points hit.
    """
    h, w = shape
    room = np.asarray(room, dtype=np.float64)
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    d, o = rays @ T_world_camera[:3, :3].T, T_world_camera[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        depth = np.nanmin(np.maximum((room[0] - o) * inv, (room[1] - o) * inv), axis=-1)  # leaving the room
        for lo, hi in np.asarray(boxes, dtype=np.float64).reshape(-1, 2, 3):
            t1, t2 = (lo - o) * inv, (hi - o) * inv
            t_in, t_out = np.nanmax(np.minimum(t1, t2), axis=-1), np.nanmin(np.maximum(t1, t2), axis=-1)
            depth = np.where((t_out >= t_in) & (t_in > 1e-6) & (t_in < depth), t_in, depth)
    return depth, o + d * depth[..., None]
