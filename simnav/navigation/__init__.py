"""Navigation: the 3D-PTG reactive navigator (thesis §6.C) in numpy, with numba kernels for the per-step loops.

* :mod:`simnav.navigation.navigator`: :class:`ReactiveNavigator3D`, one navigation step from obstacle points and a
  pose to a velocity command; waypoints, speed regulation, short-term memory, recovery.
* :mod:`simnav.navigation.bands`: the robot as a stack of prisms (:func:`robot_bands`; :func:`planar_bands` for the
  2D navigator) and obstacle points sorted into their height bands.
* :mod:`simnav.navigation.ptg`: Parameterized Trajectory Generators (circular arcs, asymptotic heading, arc +
  straight, ...), their motion commands and the inverse map workspace -> TP-space.
* :mod:`simnav.navigation.collision_grid`: the collision look-up grid of one (PTG, prism polygon) pair, cached on
  disk, giving TP-obstacles (normalised collision-free distance per path); :mod:`simnav.navigation.ptgspace`
  combines a PTG's grids over the bands (eq. 6.4).
* :mod:`simnav.navigation.holonomic`: ND and VFF in TP-space.
* :mod:`simnav.navigation.memory`: short-term memory and where the lidar saw free space;
  :mod:`simnav.navigation.sensing`: readings to points.

No simulator imports (mujoco, meshcat, dynamixel_sdk).
"""

from __future__ import annotations

from simnav.navigation.bands import Band, planar_bands, robot_bands, sort_into_bands
from simnav.navigation.collision_grid import CollisionGrid, default_cache_dir, points_in_polygon, signed_depth
from simnav.navigation.holonomic import make_holonomic
from simnav.navigation.navigator import NavCommand, NavigatorConfig, ReactiveNavigator3D
from simnav.navigation.ptg import PTG, PTG_FAMILIES, PTGConfig, TPPoint, alpha_to_index, index_to_alpha

__all__ = [
    "PTG",
    "PTG_FAMILIES",
    "Band",
    "CollisionGrid",
    "NavCommand",
    "NavigatorConfig",
    "PTGConfig",
    "ReactiveNavigator3D",
    "TPPoint",
    "alpha_to_index",
    "default_cache_dir",
    "index_to_alpha",
    "make_holonomic",
    "planar_bands",
    "points_in_polygon",
    "robot_bands",
    "signed_depth",
    "sort_into_bands",
]
