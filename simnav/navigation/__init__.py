"""Navigation: the 3D-PTG reactive navigator (thesis §6.C) in pure numpy.

* :mod:`simnav.navigation.ptg`: Parameterized Trajectory Generators (circular arcs, asymptotic heading, arc +
  straight, ...), their motion commands and the inverse map workspace -> TP-space.
* :mod:`simnav.navigation.collision_grid`: the collision look-up grid of one (PTG, prism polygon) pair, cached on
  disk, giving TP-obstacles (normalised collision-free distance per path).

No simulator imports (mujoco, meshcat, dynamixel_sdk).
"""

from __future__ import annotations

from simnav.navigation.collision_grid import CollisionGrid, default_cache_dir, points_in_polygon, signed_depth
from simnav.navigation.ptg import PTG, PTG_FAMILIES, PTGConfig, TPPoint, alpha_to_index, index_to_alpha

__all__ = [
    "PTG",
    "PTG_FAMILIES",
    "CollisionGrid",
    "PTGConfig",
    "TPPoint",
    "alpha_to_index",
    "default_cache_dir",
    "index_to_alpha",
    "points_in_polygon",
    "signed_depth",
]
