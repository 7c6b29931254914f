"""Geometry: SE(2)/SE(3) poses and twists, and the pinhole camera model.

Poses are homogeneous matrices named ``T_a_b`` (pose of frame b in frame a); twists put the translational
part first. Pure numpy, no simulator imports.
"""

from __future__ import annotations

from simnav.geometry import camera, se2, se3
from simnav.geometry.camera import PinholeCamera

__all__ = ["PinholeCamera", "camera", "se2", "se3"]
