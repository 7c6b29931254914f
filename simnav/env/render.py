"""``render()`` images of the navigation env: a top view that follows the robot, and the robot camera's view.

Both are MuJoCo OpenGL renders (EGL, headless), kept apart from the depth camera's own renderer (its own thread,
context and resolution).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from simnav.errors import SimnavError
from simnav.world.mjcf import GROUP_ROBOT

GOAL_RGBA = np.array([0.1, 0.85, 0.2, 0.9], dtype=np.float32)
GOAL_RADIUS_M = 0.25
TOP_VIEW_MARGIN_M = 3.0  # the camera sits this much higher than the span needs, so tall walls stay in view


class TopView:
    """Renders the world from straight above the robot, with the goal as a green disc.

    Args:
        model: the compiled scene (its offscreen buffer is enlarged to the image size if needed).
        size_px: (height, width) of the image.
        span_m: side of the square area around the robot that the view shows, m.
        camera: name of a robot camera whose view is inset at the top-left corner (None: no inset).
        camera_size_px: (height, width) of that camera's view.
    """

    def __init__(self, model: mujoco.MjModel, size_px: tuple[int, int], span_m: float,
                 camera: str | None = None, camera_size_px: tuple[int, int] = (120, 160)) -> None:
        height, width = size_px
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, height)
        try:
            self._top = mujoco.Renderer(model, height, width)
        except Exception as err:  # no GL platform (MUJOCO_GL=disable, no EGL library): one clear error
            raise SimnavError(f"render_mode='rgb_array' needs OpenGL (EGL): {type(err).__name__}: {err}") from None
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self._camera.elevation, self._camera.azimuth = -90.0, 90.0  # looking down, +x to the right, +y up
        half_fovy = math.radians(model.vis.global_.fovy) / 2
        self._camera.distance = span_m / 2 / math.tan(half_fovy) + TOP_VIEW_MARGIN_M
        self._robot_camera = camera
        self._inset = None
        if camera is not None:
            cam_h, cam_w = min(camera_size_px[0], height), min(camera_size_px[1], width)
            self._inset = mujoco.Renderer(model, cam_h, cam_w)
            self._inset_option = mujoco.MjvOption()
            self._inset_option.geomgroup[GROUP_ROBOT] = 0  # the camera does not see its own robot

    def render(self, data: mujoco.MjData, robot_xy: np.ndarray, goal_xy: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 top view centred on ``robot_xy`` (world frame, m) with the goal marked."""
        self._camera.lookat[:] = (robot_xy[0], robot_xy[1], 0.0)
        self._top.update_scene(data, camera=self._camera)
        _add_disc(self._top.scene, goal_xy)
        image = self._top.render()
        if self._inset is not None:
            self._inset.update_scene(data, camera=self._robot_camera, scene_option=self._inset_option)
            view = self._inset.render()
            image[:view.shape[0], :view.shape[1]] = view
        return image

    def close(self) -> None:
        """Release the GL contexts."""
        for renderer in (self._top, self._inset):
            if renderer is not None:
                renderer.close()
        self._inset = None


def _add_disc(scene: mujoco.MjvScene, xy: np.ndarray) -> None:
    if scene.ngeom >= scene.maxgeom:
        return
    mujoco.mjv_initGeom(scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_CYLINDER,
                        np.array([GOAL_RADIUS_M, 0.01, 0.0]), np.array([xy[0], xy[1], 0.02]),
                        np.eye(3).ravel(), GOAL_RGBA)
    scene.ngeom += 1
