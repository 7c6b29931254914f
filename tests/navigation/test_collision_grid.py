"""Collision grid: TP-obstacles against brute force, walls, obstacles inside the footprint, and the disk cache."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
from shapely import contains_xy
from shapely.geometry import Polygon

from simnav.navigation.collision_grid import CollisionGrid, default_cache_dir, points_in_polygon, signed_depth
from simnav.navigation.ptg import PTG

QUAD = np.array([(-0.15, 0.15), (0.2, 0.1), (0.2, -0.1), (-0.15, -0.15)])  # MRPT's default shape, front at x = 0.2
RECT = np.array([(-0.2, -0.17), (0.2, -0.17), (0.2, 0.17), (-0.2, 0.17)])


@pytest.fixture(scope="module")
def small_c() -> PTG:
    return PTG(family="C", num_paths=21, ref_distance_m=3.0)


def brute_force_tp(ptg: PTG, polygon: Polygon, points: np.ndarray, previous: bool = False) -> np.ndarray:
    """(P, N) normalised distance of the first path sample at which ``polygon`` contains each point (1 = never),
    or of the sample before it if ``previous``."""
    out = np.ones((len(points), ptg.num_paths))
    for k in range(ptg.num_paths):
        n = ptg.num_samples[k]
        x, y, phi = (ptg.poses[k, :n, i][None] for i in range(3))
        dx, dy = points[:, 0, None] - x, points[:, 1, None] - y
        inside = contains_xy(polygon, np.cos(phi) * dx + np.sin(phi) * dy, -np.sin(phi) * dx + np.cos(phi) * dy)
        hit = inside.any(axis=1)
        n_hit = np.argmax(inside[hit], axis=1)
        out[hit, k] = ptg.dist_m[k, np.maximum(n_hit - 1, 0) if previous else n_hit] / ptg.ref_distance_m
    return out


@pytest.mark.parametrize("family", ["C", "alpha", "CS"])
@pytest.mark.parametrize("conservative", [True, False])
def test_grid_is_sandwiched_by_brute_force_on_shrunk_and_grown_footprints(family, conservative) -> None:
    """Corner marking: a cell counts as hit (at the sample before) only when the footprint grown by a cell diagonal
    holds the point, and always when the footprint shrunk by a cell diagonal does (centres: half a diagonal)."""
    ptg = PTG(family=family, num_paths=15, ref_distance_m=2.5)
    res = 0.05
    grid = CollisionGrid(ptg, QUAD, resolution_m=res, conservative=conservative, use_cache=False)
    rng = np.random.default_rng(11)
    pts = rng.uniform(-2.6, 2.6, size=(400, 2))
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) > grid.max_radius_m + 2 * res]  # none in the start cells
    margin = (res * math.sqrt(2) if conservative else res / math.sqrt(2)) * 1.02
    grown, shrunk = Polygon(QUAD).buffer(margin), Polygon(QUAD).buffer(-margin)
    lower, upper = brute_force_tp(ptg, grown, pts, previous=True), brute_force_tp(ptg, shrunk, pts)
    got = np.stack([grid.tp_obstacles(p[None]) for p in pts])
    assert np.all(got >= lower - 1e-6) and np.all(got <= upper + 1e-6)
    assert np.sum(got < 1.0) > 100  # the test sees hits, not only free paths
    # a batch query is the running minimum of the single-point ones
    np.testing.assert_allclose(grid.tp_obstacles(pts), got.min(axis=0), atol=1e-7)


def test_wall_in_front_with_defaults(tmp_path) -> None:
    """Default PTG (121 C paths, 5 m) and grid (0.05 m): a wall 1 m ahead stops the straight path after
    1 - 0.2 m (the footprint's front edge), up to a cell diagonal and a sample earlier; paths turning away stay
    free."""
    ptg = PTG()
    grid = CollisionGrid(ptg, QUAD, cache_dir=tmp_path)
    assert grid.resolution_m == 0.05 and ptg.num_paths == 121
    wall = np.c_[np.full(401, 1.0), np.linspace(-2.0, 2.0, 401)]
    tp = grid.tp_obstacles(wall)
    straight = ptg.num_paths // 2
    assert (0.8 - 0.05 * math.sqrt(2) - ptg.config.sample_step_m) / 5 <= tp[straight] <= 0.8 / 5 + 1e-6
    # paths whose swept footprint never reaches x = 1 m are free; all others are blocked before the horizon
    reach = np.array([np.max(ptg.poses[k, : ptg.num_samples[k], 0]) for k in range(ptg.num_paths)])
    away = reach + grid.max_radius_m < 1.0 - 0.1
    assert away.sum() >= 10 and np.all(tp[away] == 1.0)
    assert np.all(tp[reach > 1.2] < 1.0)
    assert tp[straight] <= tp.min() + 0.02 / 5  # straight ahead hits it (about) first
    np.testing.assert_allclose(tp, tp[::-1], atol=0.05 / 5 * 2)  # the scene is symmetric


def test_obstacle_inside_the_footprint_blocks_only_approaching_paths(small_c) -> None:
    grid = CollisionGrid(small_c, QUAD, use_cache=False)
    mid = small_c.num_paths // 2
    # inside, near the front-left corner: turning left swings the footprint deeper, turning right escapes
    p = np.array([[0.15, 0.08]])
    assert points_in_polygon(p, QUAD)[0]
    tp = grid.tp_obstacles(p)
    assert np.all(tp[mid:] == 0.0)  # straight and left turns dig deeper (or scrape along it)
    assert np.all(tp[:3] > 0.3)  # the sharpest right turns get away
    assert np.all(grid.tp_obstacles(p, inside_behavior="stop") == 0.0)
    # the same point lets every backward path escape; straight back never meets it again
    back = CollisionGrid(PTG(family="C", backward=True, num_paths=21, ref_distance_m=3.0), QUAD, use_cache=False)
    tp_back = back.tp_obstacles([[0.19, 0.0]])
    assert np.all(tp_back > 0.3) and tp_back[mid] == 1.0
    # other obstacles still count on the escaping paths
    assert back.tp_obstacles([[0.19, 0.0], [-1.0, 0.0]])[mid] <= 0.85 / 3 + 1e-6  # rear edge at -0.15 m
    with pytest.raises(ValueError):
        grid.tp_obstacles(p, inside_behavior="ignore")


def test_obstacle_just_outside_the_side_does_not_block_moving_along_it(small_c) -> None:
    """A point 1 cm beside a rectangular robot lies in a cell the inflated footprint covers at the start: going
    straight (parallel) or turning away is allowed, turning towards it is not."""
    grid = CollisionGrid(small_c, RECT, use_cache=False)
    mid = small_c.num_paths // 2
    p = np.array([[0.1, 0.18]])
    assert not points_in_polygon(p, RECT)[0] and grid.start_row[grid.cell_index(p)[0]] >= 0
    tp = grid.tp_obstacles(p)
    assert tp[mid] == 1.0 and np.all(tp[:mid] > 0.3)  # straight and right turns
    assert np.all(tp[mid + 1:] == 0.0)  # left turns swing the front into it


def test_queries_ignore_far_points_and_accept_xyz(small_c) -> None:
    grid = CollisionGrid(small_c, QUAD, use_cache=False)
    assert np.all(grid.tp_obstacles(np.zeros((0, 2))) == 1.0)
    far = np.array([[50.0, 0.0], [0.0, -grid.half_extent_m - 0.01]])
    assert np.all(grid.tp_obstacles(far) == 1.0) and np.all(grid.cell_index(far) == -1)
    pts = np.array([[1.0, 0.2, 0.5], [0.7, -0.4, 1.2]])
    np.testing.assert_array_equal(grid.tp_obstacles(pts), grid.tp_obstacles(pts[:, :2]))
    k, d = grid.entries(1.0, 0.0)
    assert len(k) == len(d) > 0 and np.all((d >= 0) & (d <= 1))


def test_polygon_helpers() -> None:
    assert points_in_polygon([[0.0, 0.0], [0.3, 0.0], [0.19, 0.09]], QUAD).tolist() == [True, False, True]
    np.testing.assert_allclose(signed_depth([[0.0, 0.0], [0.3, 0.0], [0.0, 0.27]], RECT), [0.17, -0.1, -0.1])


def test_cache_round_trip_keys_and_corruption(small_c, tmp_path, caplog) -> None:
    t0 = time.perf_counter()
    first = CollisionGrid(small_c, QUAD, cache_dir=tmp_path)
    assert not first.loaded_from_cache and first.cache_path.exists() and first.cache_path.parent == tmp_path
    second = CollisionGrid(small_c, QUAD, cache_dir=tmp_path)
    assert second.loaded_from_cache and second.cache_key == first.cache_key and second.build_time_s == 0.0
    assert time.perf_counter() - t0 < 30
    for name in ("cell_ptr", "cell_k", "cell_d_norm", "start_cells", "escape_limit_norm"):
        np.testing.assert_array_equal(getattr(second, name), getattr(first, name))
    pts = np.random.default_rng(0).uniform(-3, 3, (300, 2))
    np.testing.assert_array_equal(second.tp_obstacles(pts), first.tp_obstacles(pts))

    # any parameter changes the key and the file
    other_poly = CollisionGrid(small_c, QUAD * 1.01, cache_dir=tmp_path)
    other_res = CollisionGrid(small_c, QUAD, resolution_m=0.04, cache_dir=tmp_path)
    other_ptg = CollisionGrid(PTG(family="C", num_paths=21, ref_distance_m=3.0, v_max_mps=0.5), QUAD,
                              cache_dir=tmp_path)
    keys = {g.cache_key for g in (first, other_poly, other_res, other_ptg)}
    assert len(keys) == 4 and not other_poly.loaded_from_cache and len(list(tmp_path.glob("*.npz"))) == 4
    assert PTG(family="C", num_paths=21, ref_distance_m=3.0, score_priority=0.5).config.path_parameters() == \
        small_c.config.path_parameters()  # the priority does not change the paths

    # corrupt, truncated, or someone else's file: rebuilt with a warning, never fatal
    good = first.cache_path.read_bytes()
    for bad in (b"not a zip file", good[: len(good) // 2], other_poly.cache_path.read_bytes()):
        first.cache_path.write_bytes(bad)
        caplog.clear()
        rebuilt = CollisionGrid(small_c, QUAD, cache_dir=tmp_path)
        assert not rebuilt.loaded_from_cache and "rebuilding" in caplog.text
        np.testing.assert_array_equal(rebuilt.cell_d_norm, first.cell_d_norm)
        assert CollisionGrid(small_c, QUAD, cache_dir=tmp_path).loaded_from_cache  # and rewritten
    assert not list(tmp_path.glob("*.tmp"))


def test_cache_dir_from_environment(small_c, tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("SIMNAV_CACHE_DIR", str(tmp_path / "root"))
    assert default_cache_dir() == tmp_path / "root" / "ptg"
    grid = CollisionGrid(small_c, QUAD)
    assert grid.cache_path.parent == tmp_path / "root" / "ptg" and grid.cache_path.exists()
    monkeypatch.delenv("SIMNAV_CACHE_DIR")
    assert default_cache_dir() == Path.home() / ".cache" / "simnav" / "ptg"
    off = CollisionGrid(small_c, QUAD, use_cache=False)
    assert off.cache_path is None and not off.loaded_from_cache
