"""The compiled kernels of Joint-VO-SF (:mod:`simnav.odometry.vosf_kernels`) against plain numpy references.

Images are QVGA (240 x 320), so the loops over whole levels take the multi-threaded path (``PARALLEL_MIN``); a
synthetic scene (a slanted, textured wall with a box in front) gives depth edges, occlusions and several clusters.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

from simnav.geometry import se3
from simnav.odometry import vosf_kernels as kern

H, W = 240, 320
CAM = np.array([277.0, 277.0, (W - 1) / 2, (H - 1) / 2])


def scene(shift_px: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(depth m, intensity) of a wall at 3-4 m with a box at 1.5 m; the texture moves by ``shift_px`` along u."""
    v, u = np.mgrid[0:H, 0:W].astype(float)
    depth = 3.0 + u / W + 0.3 * v / H
    box = (np.abs(u - 150) < 40) & (np.abs(v - 120) < 50)
    depth[box] = 1.5
    depth[:8, :20] = 0.0  # a hole
    us = u + shift_px
    intensity = 0.5 + 0.2 * np.sin(us / 7.0) * np.cos(v / 9.0) + 0.1 * np.sin(us / 2.3 + v / 3.1)
    return depth, intensity


def points(depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v, u = np.mgrid[0:H, 0:W].astype(float)
    return depth * (u - CAM[2]) / CAM[0], depth * (v - CAM[3]) / CAM[1]


def with_threads(n: int, fn, *args):
    """``fn(*args)`` with n Numba threads."""
    before = numba.get_num_threads()
    numba.set_num_threads(n)
    try:
        return fn(*args)
    finally:
        numba.set_num_threads(before)


def pipeline(depth1, intensity1, depth2, intensity2) -> list[np.ndarray]:
    """Every multi-threaded kernel on one pair of frames; their outputs."""
    pack1, pack2 = kern.level_pack(depth1, intensity1, 0.005), kern.level_pack(depth2, intensity2, 0.005)
    half = kern.downsample(depth1, intensity1, 0.1)
    x, y = points(depth1)
    centres = np.array([[0.0, 0.0, 1.5], [-1.0, -0.5, 3.4], [1.0, 0.5, 3.8], [0.5, -0.5, 3.6]])
    labels = kern.assign_labels(x, y, depth1, centres)
    idx = np.flatnonzero(depth1.ravel() > 0)
    T = se3.exp(np.array([0.004, -0.002, 0.01, 0.002, -0.003, 0.001]))
    r, J, ok = np.zeros((2, len(idx))), np.zeros((2, 6, len(idx))), np.zeros(len(idx), dtype=bool)
    kern.linearize(idx, np.zeros(0), x.ravel(), y.ravel(), pack1, True, T, CAM, pack2, False, True, 0.3,
                   kern.MODE_ROBUST, 0.15, 1e-4, 0.1, r, J, ok)
    delta, Hn, s2, m = kern.irls_cauchy(r, J, ok, 2, 0.2, 10, 0.98, 1e-6)
    edges = kern.depth_edges(depth1, 0.3).ravel()
    sums = kern.cluster_residuals(idx, labels.ravel(), edges, np.full(4, 3.0), x.ravel(), y.ravel(), pack1, T, CAM,
                                  pack2, False, True, 0.3, 0.15, 0.2)
    motions = np.stack([np.eye(4), T, np.eye(4), se3.inverse(T)])
    flow = kern.scene_flow(x, y, depth1, labels, motions, centres, np.ones((4, 4), dtype=bool), 100.0, 6.0)
    return [pack1, *half, labels, r, J, ok, delta, Hn, np.array([s2, m]), sums, flow]


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs at least 2 Numba threads")
def test_one_and_several_threads_give_identical_numbers():
    d1, i1 = scene()
    d2, i2 = scene(0.8)
    assert d1.size >= kern.PARALLEL_MIN  # the threaded path runs
    one = with_threads(1, pipeline, d1, i1, d2, i2)
    many = with_threads(numba.config.NUMBA_NUM_THREADS, pipeline, d1, i1, d2, i2)
    for a, b in zip(one, many):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("n", [5000, 60000])  # one thread / several
def test_irls_matches_a_dense_reweighted_least_squares(n):
    rng = np.random.default_rng(n)
    J = rng.normal(size=(2, 6, n))
    r = -np.einsum("jck,c->jk", J, [0.01, -0.02, 0.005, 0.001, 0.002, -0.003]) + 1e-3 * rng.normal(size=(2, n))
    r[:, ::50] += 0.5  # outliers
    ok = rng.random(n) > 0.1
    r[:, ~ok], J[:, :, ~ok] = 0.0, 0.0  # as linearize leaves unusable pixels
    delta, Hn, s2, m = kern.irls_cauchy(r, J, ok, 2, 0.2, 10, 0.98, 1e-6)
    # Reference: the same iterations with dense numpy arrays.
    A, b = J.transpose(0, 2, 1)[:, ok].reshape(-1, 6), r[:, ok].ravel()
    ref, last = np.zeros(6), np.inf
    for _ in range(10):
        e = b + A @ ref
        w = 1.0 / (1.0 + (e / (0.2 * np.abs(e).mean())) ** 2)
        Hr = A.T @ (w[:, None] * A)
        new = np.linalg.solve(Hr + (1e-9 * np.trace(Hr) / 6 + 1e-15) * np.eye(6), -A.T @ (w * b))
        chi2, change, ref = float(w @ e**2), np.max(np.abs(new - ref)), new
        if chi2 > 0.98 * last or change < 1e-6:
            break
        last = chi2
    assert m == 2 * ok.sum()
    np.testing.assert_allclose(delta, ref, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(Hn, Hr, rtol=1e-10)
    np.testing.assert_allclose(s2, chi2 / (m - 6), rtol=1e-10)
    np.testing.assert_allclose(delta, [0.01, -0.02, 0.005, 0.001, 0.002, -0.003], atol=1e-3)


def lloyd(points: np.ndarray, centres: np.ndarray, max_iterations: int, tol_m: float) -> tuple[np.ndarray,
                                                                                              np.ndarray]:
    """Plain Lloyd's K-means with kmeans' rules: every point searched every round, a centre without points stays."""
    c = centres.copy()
    for _ in range(max_iterations):
        labels = np.argmin(((points[:, None, :] - c[None]) ** 2).sum(axis=2), axis=1)
        new = c.copy()
        for k in range(len(c)):
            if np.any(labels == k):
                new[k] = points[labels == k].mean(axis=0)
        moved, c = np.max(np.linalg.norm(new - c, axis=1)), new
        if moved < tol_m:
            break
    return c, np.argmin(((points[:, None, :] - c[None]) ** 2).sum(axis=2), axis=1)


@pytest.mark.parametrize("n", [3000, 20000])  # one thread / several
def test_kmeans_skipping_points_by_their_bounds_gives_lloyds_labels(n):
    rng = np.random.default_rng(n)
    pts = rng.normal(size=(n, 3)) * [1.5, 1.0, 0.8] + [0.0, 0.0, 3.0]
    pts[: n // 4] += [2.0, 0.0, 1.0]  # a second blob
    init = pts[rng.choice(n, 24, replace=False)].copy()
    for iterations, tol in ((10, 0.01), (30, 1e-9)):
        centres, labels = kern.kmeans(pts, init, iterations, tol)
        ref_centres, ref_labels = lloyd(pts, init, iterations, tol)
        np.testing.assert_array_equal(labels, ref_labels)
        np.testing.assert_allclose(centres, ref_centres, rtol=0, atol=1e-12)


def test_kmeans_and_labels_are_the_nearest_centres():
    rng = np.random.default_rng(1)
    pts = np.vstack([rng.normal(c, 0.3, size=(2000, 3)) for c in ([0, 0, 2], [1, 0, 3], [0, 1, 4], [1, 1, 2])])
    centres, labels = kern.kmeans(pts, pts[[0, 2000, 4000, 6000]].copy(), 10, 1e-6)
    d2 = ((pts[:, None, :] - centres[None]) ** 2).sum(axis=2)
    np.testing.assert_array_equal(labels, np.argmin(d2, axis=1))
    np.testing.assert_allclose(centres, [pts[labels == k].mean(axis=0) for k in range(4)], atol=1e-6)
    depth, _ = scene()
    x, y = points(depth)
    img = kern.assign_labels(x, y, depth, centres)
    d2 = ((np.stack([x, y, depth], axis=-1)[:, :, None, :] - centres) ** 2).sum(axis=3)
    np.testing.assert_array_equal(img, np.where(depth > 0, np.argmin(d2, axis=2), -1))


def test_farthest_points_picks_the_point_farthest_from_every_centre_one_after_the_other():
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(5000, 3)) * [1.5, 1.0, 0.8] + [0.0, 0.0, 3.0]
    centres = pts[rng.choice(len(pts), 20, replace=False)].copy()
    picked = kern.farthest_points(pts, centres, 4)
    chosen = centres
    for row in picked:  # the numpy formulation, one pick at a time
        nearest = ((pts[:, None, :] - chosen[None]) ** 2).sum(axis=2).min(axis=1)
        np.testing.assert_array_equal(row, pts[np.argmax(nearest)])
        chosen = np.vstack([chosen, row])
    # duplicates of the farthest point: the first is taken, and the next pick goes elsewhere
    twice = np.vstack([pts, pts[:1] + 100.0, pts[:1] + 100.0])
    picked = kern.farthest_points(twice, centres, 2)
    np.testing.assert_array_equal(picked[0], pts[0] + 100.0)
    assert np.linalg.norm(picked[1] - picked[0]) > 1.0


def test_cluster_bookkeeping_matches_numpy():
    rng = np.random.default_rng(2)
    labels = rng.integers(-1, 5, size=3000).astype(np.int32)
    idx = np.flatnonzero(labels >= 0)
    depth = rng.uniform(1, 4, size=3000)
    order, offsets = kern.label_order(labels, idx, 5)
    for k in range(5):
        np.testing.assert_array_equal(order[offsets[k]:offsets[k + 1]], np.flatnonzero(labels == k))
    counts, sums = kern.cluster_depths(labels, idx, depth, 5)
    np.testing.assert_array_equal(counts, np.bincount(labels[idx], minlength=5))
    np.testing.assert_allclose(sums, np.bincount(labels[idx], depth[idx], minlength=5), rtol=1e-14)
    b = np.array([0.1, 0.9, 0.5, 1.0, 0.0])
    keep, scales = kern.background_pixels(labels, idx, b, 2.0 / 3.0)
    np.testing.assert_array_equal(keep, idx[b[labels[idx]] <= 2.0 / 3.0])
    np.testing.assert_allclose(scales, np.sqrt(1.0 - b[labels[keep]]))


def test_cluster_residuals_of_a_frame_against_itself():
    depth, intensity = scene()
    pack = kern.level_pack(depth, intensity, 0.005)
    x, y = points(depth)
    labels = np.where(depth > 0, (np.arange(H * W).reshape(H, W) // W) % 3, -1).astype(np.int32).ravel()
    idx = np.flatnonzero(depth.ravel() > 0)
    edges = kern.depth_edges(depth, 0.3).ravel()
    sums = kern.cluster_residuals(idx, labels, edges, np.full(3, 3.0), x.ravel(), y.ravel(), pack, np.eye(4), CAM,
                                  pack, False, True, 0.3, 0.15, 0.2)
    border = np.zeros((H, W), dtype=bool)
    border[[0, -1], :] = border[:, [0, -1]] = True  # rounding may project these just outside the image
    inner = idx[~border.ravel()[idx]]
    assert np.all(sums[:, 2] >= np.bincount(labels[inner], minlength=3))  # every pixel finds itself
    assert np.all(sums[:, 2] <= np.bincount(labels[idx], minlength=3))
    assert np.all(sums[:, 0] >= np.bincount(labels[inner][~edges[inner]], minlength=3))
    assert np.all(sums[:, 1] < 1e-9 * sums[:, 0]) and np.all(sums[:, 3] == 0.0)
