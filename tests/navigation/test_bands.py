"""Sorting obstacle points into the robot's height bands (thesis §6.C.4)."""

from __future__ import annotations

import numpy as np
import pytest

from simnav.navigation.bands import Band, planar_bands, robot_bands, sort_into_bands
from simnav.robot import load_robot


def _bands() -> list[Band]:
    square = np.array([[0.3, -0.3], [0.3, 0.3], [-0.3, 0.3], [-0.3, -0.3]])
    mast = np.array([[0.05, -0.1], [0.05, 0.1], [-0.05, 0.1], [-0.05, -0.1]])
    return [Band("base", 0.0, 0.6, square), Band("mast", 0.6, 1.5, mast)]


def test_points_go_to_the_band_that_holds_their_height() -> None:
    pts = np.array([[1.0, 0.0, 0.3], [2.0, 0.0, 1.0], [3.0, 0.0, 0.6], [4.0, 0.0, 0.599]])
    low, high = sort_into_bands(pts, _bands(), max_xy_m=10.0)
    np.testing.assert_allclose(low, [[1.0, 0.0], [4.0, 0.0]])
    np.testing.assert_allclose(high, [[2.0, 0.0], [3.0, 0.0]])


def test_floor_points_above_the_robot_far_points_and_nan_are_dropped() -> None:
    pts = np.array([[1.0, 0.0, 0.005], [1.0, 0.0, 1.7], [20.0, 0.0, 0.3], [np.nan, 0.0, 0.3], [1.0, np.inf, 0.3]])
    low, high = sort_into_bands(pts, _bands(), max_xy_m=10.0)
    assert low.shape == (0, 2) and high.shape == (0, 2)


def test_robot_bands_follow_the_prisms_and_planar_band_covers_all_of_them() -> None:
    robot = load_robot("rhodon")
    bands = robot_bands(robot)
    assert [b.z_min_m for b in bands] == sorted(b.z_min_m for b in bands)
    (planar,) = planar_bands(robot)
    assert planar.z_min_m == 0.0 and planar.z_max_m == np.inf  # every point is projected
    # the planar section reaches as far forward as the arm
    assert planar.polygon[:, 0].max() == pytest.approx(max(np.max(np.asarray(p.polygon)[:, 0]) for p in robot.prisms))


def test_band_orders_vertices_counter_clockwise_and_rejects_bad_shapes() -> None:
    cw = np.array([[0.3, 0.3], [0.3, -0.3], [-0.3, -0.3], [-0.3, 0.3]])
    b = Band("b", 0.0, 1.0, cw)
    x, y = b.polygon[:, 0], b.polygon[:, 1]
    assert np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y) > 0
    with pytest.raises(ValueError, match="polygon"):
        Band("b", 0.0, 1.0, np.zeros((2, 2)))
    with pytest.raises(ValueError, match="z_max_m"):
        Band("b", 1.0, 1.0, cw)
