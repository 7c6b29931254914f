"""Colours of the viewer (RGB in [0, 1]); the README lists them.

The robot's prisms and the obstacle points share one colour per height band (band 0 is the lowest prism), so a
point shows which section of the robot it can touch. The colours are far apart in hue from each other, from the
people (red), the other robots (blue) and the building (greys, beiges and browns), so that a screenshot test can
tell them apart by hue.
"""

from __future__ import annotations

RGB = tuple[float, float, float]

BAND_COLORS: tuple[RGB, ...] = (
    (0.15, 0.70, 0.25),  # green
    (0.55, 0.30, 0.85),  # purple
    (0.95, 0.80, 0.10),  # yellow
    (0.05, 0.70, 0.75),  # teal
    (0.60, 0.90, 0.10),  # lime
    (0.90, 0.35, 0.70),  # pink
)
"""Height band b of the robot (bottom first) is drawn in ``BAND_COLORS[b % len(BAND_COLORS)]``."""

PERSON_COLOR: RGB = (0.84, 0.10, 0.11)
PERSON_HEAD_COLOR: RGB = (0.85, 0.68, 0.55)
WANDERER_COLOR: RGB = (0.12, 0.40, 0.85)
WANDERER_MAST_COLOR: RGB = (0.80, 0.80, 0.80)
DOOR_COLOR: RGB = (0.55, 0.35, 0.20)
FLOOR_COLOR: RGB = (0.70, 0.70, 0.68)
TARGET_COLOR: RGB = (0.90, 0.00, 0.90)
ROUTE_COLOR: RGB = (0.70, 0.00, 0.70)
SCAN_COLOR: RGB = (1.00, 0.45, 0.00)
DEPTH_COLOR: RGB = (0.35, 0.50, 0.65)
UNBANDED_COLOR: RGB = (0.45, 0.45, 0.45)
"""Obstacle points outside every band (floor, above the robot, in a gap between prisms)."""
CANDIDATE_COLOR: RGB = (0.42, 0.42, 0.46)
CHOSEN_COLOR: RGB = (0.00, 0.90, 1.00)
GT_TRAIL_COLOR: RGB = (0.10, 0.10, 0.10)
EST_TRAIL_COLOR: RGB = (1.00, 1.00, 1.00)


def band_color(band: int) -> RGB:
    """The colour of height band ``band`` (0 = lowest)."""
    return BAND_COLORS[band % len(BAND_COLORS)]


def hex_color(rgb: RGB) -> int:
    """``0xRRGGBB`` of an RGB triple in [0, 1]."""
    r, g, b = (min(max(round(255 * c), 0), 255) for c in rgb)
    return (r << 16) | (g << 8) | b
