"""Kernels of simnav.odometry.rangeflow, and the robustness rules both range-flow odometries share."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from simnav.errors import ConfigError
from simnav.geometry import se2
from simnav.odometry import make_scan_odometry
from simnav.odometry import rangeflow as rf
from simnav.odometry.base import planar_scan
from simnav.odometry.rf2o import RF2OConfig

ODOMETRIES = ["rf2o", "srf"]


def _level(n: int = 200, fov_deg: float = 180.0, circular: bool = False) -> rf.LevelGeometry:
    half = math.radians(fov_deg) / 2
    angles = np.linspace(-math.pi, math.pi, n, endpoint=False) if circular else np.linspace(-half, half, n)
    return rf.level_geometry(angles, circular)


def _wall_ranges(geom: rf.LevelGeometry, d_m: float = 2.0) -> np.ndarray:
    """Ranges to the wall x = d_m (all beams within +-90 deg hit it)."""
    return d_m / geom.cos


def _pose_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """Translation (m) and |rotation| (deg) of ``inv(T_true) @ T_est``."""
    E = se2.inverse(T_true) @ T_est
    return math.hypot(E[0, 2], E[1, 2]), abs(math.degrees(math.atan2(E[1, 0], E[0, 0])))


# ---- beam layout and pyramid ------------------------------------------------------------------------------


def test_layout_detects_full_turn_and_moves_the_opening_to_the_end():
    full = rf.beam_layout(np.linspace(-math.pi, math.pi, 360, endpoint=False) + 1e-3)
    assert full.circular and len(full.angles_rad) == 360
    assert np.all(np.diff(full.angles_rad) > 0)

    # A 270 deg scanner facing backwards-left: after sorting, its opening is in the middle of (-pi, pi].
    raw = se2.wrap_angle(np.linspace(0.0, math.radians(270), 271))
    layout = rf.beam_layout(np.sort(raw))
    assert not layout.circular
    assert np.all(np.diff(layout.angles_rad) > 0)
    assert layout.angles_rad[-1] - layout.angles_rad[0] == pytest.approx(math.radians(270))


def test_layout_drops_duplicate_directions():
    angles = np.r_[np.linspace(-math.pi, math.pi, 361)[1:], math.pi]  # +pi twice, and -pi == +pi
    layout = rf.beam_layout(np.sort(se2.wrap_angle(angles)))
    assert len(layout.angles_rad) == 360 and layout.circular


def test_pyramid_halves_resolution_and_respects_the_minimum_size():
    layout = rf.beam_layout(np.linspace(-2.0, 2.0, 1080))
    geoms = rf.pyramid_geometry(layout, levels=5, min_level_beams=16)
    assert [g.n for g in geoms] == [1080, 540, 270, 135, 68]
    assert len(rf.pyramid_geometry(layout, levels=10, min_level_beams=100)) == 4  # 1080, 540, 270, 135
    assert np.allclose(geoms[1].angles_rad, geoms[0].angles_rad[::2])


def test_gated_smoothing_does_not_mix_across_depth_discontinuities():
    geom = _level(40)
    r = np.where(np.arange(40) < 20, 1.0, 3.0)
    r[30] = 0.0  # invalid beam
    out = rf.gated_average(r, geom.window, gate_m=0.3)
    assert np.allclose(out[:20], 1.0) and np.allclose(np.delete(out[20:], 10), 3.0)
    assert out[30] == 0.0  # an invalid centre stays invalid

    noisy = 2.0 + np.random.default_rng(0).normal(scale=0.01, size=40)
    assert np.std(rf.gated_average(noisy, geom.window, 0.3)) < 0.7 * np.std(noisy)


# ---- derivatives ------------------------------------------------------------------------------------------


def test_gradient_matches_analytic_wall_and_ignores_the_far_side_of_an_edge():
    geom = _level(181)
    r = _wall_ranges(geom)
    grad, ok = rf.range_gradient(r, r * geom.cos, r * geom.sin, geom)
    analytic = 2.0 * geom.sin / geom.cos**2
    inner = slice(20, -20)
    assert ok.all()
    assert np.allclose(grad[inner], analytic[inner], rtol=1e-3)

    # Left half at 2 m, right half at 5 m (a depth jump): the edge beams take the gradient of their own side.
    step = np.where(np.arange(181) < 90, 2.0, 5.0)
    grad, _ = rf.range_gradient(step, step * geom.cos, step * geom.sin, geom)
    jump_per_rad = 3.0 / float(geom.gap_next[89])
    assert abs(grad[89]) < 0.05 * jump_per_rad and abs(grad[90]) < 0.05 * jump_per_rad


def test_gradient_uses_the_actual_non_uniform_spacing():
    u = np.linspace(-1.0, 1.0, 301)
    angles = 1.2 * (u + 0.15 * np.sin(math.pi * u))  # strongly non-uniform, monotonic
    geom = rf.level_geometry(angles, circular=False)
    r = 3.0 + 0.5 * angles  # dr/dtheta = 0.5 exactly
    grad, ok = rf.range_gradient(r, r * geom.cos, r * geom.sin, geom)
    assert ok.all() and np.allclose(grad, 0.5, atol=1e-6)


def test_gradient_wraps_around_on_a_full_turn():
    geom = _level(360, circular=True)
    r = 3.0 + np.sin(geom.angles_rad)
    grad, ok = rf.range_gradient(r, r * geom.cos, r * geom.sin, geom)
    assert ok.all()
    assert np.allclose(grad, np.cos(geom.angles_rad), atol=1e-3)  # including the first and last beam


# ---- warping ----------------------------------------------------------------------------------------------


def test_warp_with_identity_reproduces_the_scan():
    geom = _level(181)
    r = _wall_ranges(geom)
    r[50:60] = 0.0
    out = rf.warp_scan(r, geom, np.eye(3), geom)
    assert np.allclose(out, r, atol=1e-9)


def test_warp_renders_the_scene_from_the_new_viewpoint(rangesim):
    world = rangesim.l_room()
    angles = rangesim.uniform_angles(720, 270)
    sim = rangesim.ScanSimulator(world, angles)
    T_world_a = se2.from_xy_yaw(2.0, 2.2, 0.1)
    T_a_b = se2.from_xy_yaw(0.06, -0.03, math.radians(2.0))
    geom = rf.level_geometry(planar_scan(sim.scan(T_world_a)).angles_rad, circular=False)
    r_b = planar_scan(sim.scan(T_world_a @ T_a_b)).ranges_m
    r_a = planar_scan(sim.scan(T_world_a)).ranges_m
    warped = rf.warp_scan(r_b, geom, T_a_b, geom)  # scan b seen from a
    both = (warped > 0) & (r_a > 0)
    assert both.mean() > 0.9
    close = np.abs(warped[both] - r_a[both]) < 1e-3
    assert close.mean() > 0.95  # the rest are beams at depth edges and newly disoccluded surface


def test_warp_z_buffer_keeps_the_closest_or_the_farthest():
    # A wall at x = 4 m behind a 0.2 m wide object at x = 1 m, seen from 1 m to the left: both project around -45 deg.
    geom = _level(721)
    r = np.where(np.abs(np.tan(geom.angles_rad)) <= 0.1, 1.0, 4.0) / geom.cos
    T_dst_src = se2.from_xy_yaw(0.0, -1.0, 0.0)
    closest = rf.warp_scan(r, geom, T_dst_src, geom, keep="closest")
    farthest = rf.warp_scan(r, geom, T_dst_src, geom, keep="farthest")
    both = np.abs(geom.angles_rad + math.radians(45)) < math.radians(2)  # object spans about -48..-42 deg
    assert both.sum() > 10
    assert np.all(closest[both] < 1.6) and np.all(farthest[both] > 5.0)
    with pytest.raises(ValueError, match="keep"):
        rf.warp_scan(r, geom, T_dst_src, geom, keep="median")


def test_warp_onto_a_circular_grid_fills_across_the_wrap():
    geom = _level(360, circular=True)
    r = np.full(360, 2.0)
    out = rf.warp_scan(r, geom, se2.from_xy_yaw(0.0, 0.0, math.radians(5.0)), geom)
    assert np.all(out > 0) and np.allclose(out, 2.0, atol=1e-3)


# ---- constraints, solvers, filter ---------------------------------------------------------------------------


@pytest.mark.parametrize("symmetric", [True, False])
def test_range_flow_constraint_recovers_a_small_translation(symmetric):
    geom = _level(361, fov_deg=120)
    r_ref = _wall_ranges(geom, 3.0)
    r_new = _wall_ranges(geom, 3.0 - 0.002)  # moved 2 mm towards the wall
    terms = rf.flow_terms(r_ref, r_new, geom, symmetric=symmetric)
    xi = np.linalg.lstsq(terms.A, -terms.rt_m[terms.rows], rcond=None)[0]
    assert xi[0] == pytest.approx(0.002, abs=1e-5)


def test_robust_solvers_reject_gross_outliers():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(600, 3))
    xi_true = np.array([0.03, -0.01, 0.02])
    b = A @ xi_true + rng.normal(scale=1e-3, size=600)
    b[rng.choice(600, 90, replace=False)] += rng.uniform(0.5, 2.0, size=90)
    plain = np.linalg.lstsq(A, b, rcond=None)[0]
    cauchy = rf.irls_cauchy(A, b, iterations=5, k_ratio=0.1, lever_m=1.0)
    parabola = rf.irls_truncated_parabola(A, b, 10, 4.0, 0.995, lever_m=1.0)
    assert np.linalg.norm(plain - xi_true) > 0.02
    assert np.linalg.norm(cauchy.xi - xi_true) < 5e-3
    assert np.linalg.norm(parabola.xi - xi_true) < 5e-3
    for sol in (cauchy, parabola):
        assert np.all(np.isfinite(sol.covariance)) and np.all(np.linalg.eigvalsh(sol.covariance) > 0)


def test_truncated_parabola_kernel_is_smooth_and_flat_beyond_c():
    c = 0.5
    r = np.array([0.0, 0.25, 0.5, 0.7, 3.0])
    assert np.allclose(rf.truncated_parabola_weights(r, c), [1.0, 0.75, 0.0, 0.0, 0.0])
    energies = [rf.truncated_parabola_energy(np.array([x]), c) for x in (0.4999, 0.5, 0.6, 10.0)]
    assert np.allclose(energies, c * c / 4, rtol=1e-6)
    assert rf.cauchy_weights(np.array([0.0, 2.0]), 2.0).tolist() == [1.0, 0.5]


def test_solver_stays_finite_when_a_direction_is_unobservable():
    A = np.zeros((100, 3))
    A[:, 1] = 1.0
    A[:, 2] = np.linspace(-1, 1, 100)  # vx never appears: a corridor along x
    sol = rf.irls_truncated_parabola(A, A @ [0.0, 0.02, 0.01] + 1e-4, 10, 4.0, 0.995, lever_m=1.0)
    assert np.all(np.isfinite(sol.xi)) and sol.xi[0] == 0.0
    assert sol.covariance[0, 0] == pytest.approx(rf.MAX_VARIANCE)
    assert rf.degeneracy_ratio(rf.unit_information(A + [1e-9, 0, 0]), 1.0) < 1e-6


def test_motion_filter_blends_only_poorly_constrained_directions():
    xi_m, prior = np.array([0.1, 0.2, 0.3]), np.array([1.0, 1.0, 1.0])
    eig = (np.array([1e-12, 1e-12, 1e3]), np.eye(3))  # the third axis is unconstrained
    out = rf.motion_filter(xi_m, eig, prior, k_l=0.0, k_e=5e3)
    assert out[:2] == pytest.approx(xi_m[:2]) and out[2] == pytest.approx(1.0, abs=1e-6)
    out = rf.motion_filter(xi_m, (np.zeros(3), np.eye(3)), prior, k_l=1.0, k_e=5e3)
    assert out == pytest.approx((xi_m + prior) / 2)  # (3.77) with E = 0: [(1 + k_l) I] xi = xi_M + k_l xi_prior


def test_fast_se2_helpers_match_the_geometry_module():
    rng = np.random.default_rng(2)
    for xi in np.c_[rng.normal(size=(20, 2)), rng.uniform(-3, 3, 20)].tolist() + [[0.1, 0.2, 0.0]]:
        T = rf.se2_exp(np.array(xi))
        assert np.allclose(T, se2.exp(xi)) and np.allclose(rf.se2_log(T), se2.log(T))
        assert np.allclose(rf.se2_inverse(T), se2.inverse(T))
        B = se2.from_xy_yaw(*rng.normal(size=3))
        assert np.allclose(B @ T @ se2.inverse(B), se2.exp(rf.se2_adjoint(B) @ se2.log(T)))


def test_unknown_option_names_the_allowed_ones():
    with pytest.raises(ConfigError, match="unknown RF2O option.*levelz.*allowed:.*levels"):
        rf.make_config(RF2OConfig, {"levelz": 3}, "RF2O")
    with pytest.raises(ConfigError, match="levels must be"):
        rf.make_config(RF2OConfig, {"levels": 0}, "RF2O")


# ---- robustness rules shared by both odometries ------------------------------------------------------------


def _room_scans(rangesim, n: int = 6, noise_m: float = 0.0, **sim_kwargs) -> tuple[list, list[np.ndarray]]:
    poses = rangesim.trajectory(n, speed_mps=0.5)
    sim = rangesim.ScanSimulator(rangesim.l_room(), rangesim.uniform_angles(1080, 270), noise_m=noise_m,
                                 **sim_kwargs)
    return [sim.scan(T, 0.1 * i) for i, T in enumerate(poses)], poses


def _assert_finite(est) -> None:
    for a in (est.T_odom_base, est.twist_base, est.covariance):
        assert np.all(np.isfinite(a))


@pytest.mark.parametrize("name", ODOMETRIES)
def test_static_robot_gives_identity(name, rangesim):
    sim = rangesim.ScanSimulator(rangesim.l_room(), rangesim.uniform_angles(1080, 270))
    odo = make_scan_odometry(name)
    T = se2.from_xy_yaw(2.0, 2.0, 0.4)
    for i in range(5):
        est = odo.process(sim.scan(T, 0.1 * i))
        _assert_finite(est)
    assert np.allclose(est.T_odom_base, np.eye(3), atol=1e-9)
    assert np.allclose(est.twist_base, 0.0, atol=1e-8) and not est.degenerate

    noisy = rangesim.ScanSimulator(rangesim.l_room(), rangesim.uniform_angles(1080, 270), noise_m=0.01)
    odo.reset()
    for i in range(10):
        est = odo.process(noisy.scan(T, 0.1 * i))
        _assert_finite(est)
    dist, yaw = _pose_error(est.T_odom_base, np.eye(3))
    assert dist < 5e-3 and yaw < 0.1


@pytest.mark.parametrize("name", ODOMETRIES)
def test_all_invalid_scan_predicts_with_inflated_covariance(name, rangesim):
    scans, poses = _room_scans(rangesim, n=8)
    blank = replace(scans[3], ranges_m=np.zeros_like(scans[3].ranges_m))
    odo = make_scan_odometry(name)
    out = [odo.process(s) for s in scans[:3]] + [odo.process(blank)] + [odo.process(s) for s in scans[4:]]
    for est in out:
        _assert_finite(est)
    lost = out[3]
    assert lost.degenerate and lost.valid_points == 0 and not lost.extra["measured"]
    assert np.all(np.linalg.eigvalsh(lost.covariance) >= 0.99)  # lost_variance = 1 (m², m², rad²)
    # Constant velocity over the lost scan: the motion continues at the previous speed.
    assert np.allclose(lost.twist_base, out[2].twist_base, atol=1e-9)
    assert out[-1].extra["measured"] and np.all(np.linalg.eigvalsh(out[-1].covariance) < 1e-3)
    dist, yaw = _pose_error(out[-1].T_odom_base, se2.inverse(poses[0]) @ poses[-1])
    assert dist < 0.02 and yaw < 0.5  # the predicted steps were at (almost) the true speed


@pytest.mark.parametrize("name", ODOMETRIES)
def test_nan_inf_and_sparse_scans_never_raise(name, rangesim):
    scans, poses = _room_scans(rangesim, n=6)
    rng = np.random.default_rng(3)
    broken = []
    for s in scans:
        r = s.ranges_m.copy()
        r[rng.random(len(r)) < 0.2] = np.nan
        r[rng.random(len(r)) < 0.1] = np.inf
        r[rng.random(len(r)) < 0.05] = -1.0
        broken.append(replace(s, ranges_m=r))
    odo = make_scan_odometry(name)
    for s in broken:
        est = odo.process(s)
        _assert_finite(est)
    dist, yaw = _pose_error(est.T_odom_base, se2.inverse(poses[0]) @ poses[-1])
    assert dist < 0.01 and yaw < 0.2

    sparse = scans[0].ranges_m.copy()
    sparse[10:] = 0.0  # 10 valid beams out of 1080
    est = odo.process(replace(scans[0], ranges_m=sparse, stamp_s=1.0))
    _assert_finite(est)
    assert not est.extra["measured"] and est.degenerate


@pytest.mark.parametrize("name", ODOMETRIES)
def test_featureless_corridor_is_flagged_degenerate(name, rangesim):
    sim = rangesim.ScanSimulator(rangesim.corridor(), rangesim.uniform_angles(1080, 270), noise_m=0.01)
    odo = make_scan_odometry(name)
    out = [odo.process(sim.scan(se2.from_xy_yaw(0.05 * i, 0.3, 0.02 * math.sin(i)), 0.1 * i)) for i in range(8)]
    for est in out:
        _assert_finite(est)
    assert all(est.degenerate for est in out[1:])
    # The motion along the corridor is unobservable: its variance is inflated; across it stays small.
    assert out[-1].covariance[0, 0] > 0.5 and out[-1].covariance[1, 1] < 1e-3


@pytest.mark.parametrize("name", ODOMETRIES)
def test_upside_down_and_backward_mounts_give_the_upright_trajectory(name, rangesim):
    poses = rangesim.trajectory(12, speed_mps=0.5)
    finals = []
    for mount in (rangesim.mount(), rangesim.mount(roll_deg=180), rangesim.mount(yaw_deg=180, x_m=-0.2, y_m=0.05)):
        sim = rangesim.ScanSimulator(rangesim.l_room(), rangesim.uniform_angles(1080, 270), T_base_sensor=mount)
        odo = make_scan_odometry(name)
        for i, T in enumerate(poses):
            est = odo.process(sim.scan(T, 0.1 * i))
        finals.append(est.T_odom_base)
        dist, yaw = _pose_error(est.T_odom_base, se2.inverse(poses[0]) @ poses[-1])
        assert dist < 5e-3 and yaw < 0.1
    for T in finals[1:]:
        dist, yaw = _pose_error(T, finals[0])
        assert dist < 5e-3 and yaw < 0.1


@pytest.mark.parametrize("name", ODOMETRIES)
@pytest.mark.parametrize("angles", ["full_turn", "non_uniform"])
def test_full_turn_and_non_uniform_scanners(name, angles, rangesim):
    if angles == "full_turn":
        beams = rangesim.uniform_angles(360, 360) + 0.01
    else:
        u = np.linspace(-1.0, 1.0, 900)
        beams = math.radians(120) * (u + 0.15 * np.sin(math.pi * u))
    sim = rangesim.ScanSimulator(rangesim.l_room(), beams, noise_m=0.005)
    poses = rangesim.trajectory(15, speed_mps=0.5)
    odo = make_scan_odometry(name)
    for i, T in enumerate(poses):
        est = odo.process(sim.scan(T, 0.1 * i))
        _assert_finite(est)
        assert not est.degenerate or i == 0
    dist, yaw = _pose_error(est.T_odom_base, se2.inverse(poses[0]) @ poses[-1])
    assert dist < 0.015 and yaw < 0.3


@pytest.mark.parametrize("name", ODOMETRIES)
def test_twist_covariance_and_bookkeeping(name, rangesim):
    scans, poses = _room_scans(rangesim, n=3)
    odo = make_scan_odometry(name)
    first = odo.process(scans[0])
    assert np.array_equal(first.T_odom_base, np.eye(3)) and np.all(first.twist_base == 0)
    est = odo.process(scans[1])
    xi_true = se2.log(se2.inverse(poses[0]) @ poses[1]) / 0.1
    assert np.allclose(est.twist_base, xi_true, atol=5e-3)
    assert est.valid_points > 900 and est.runtime_s > 0 and est.stamp_s == pytest.approx(0.1)
    assert np.allclose(est.covariance, est.covariance.T) and np.all(np.linalg.eigvalsh(est.covariance) > 0)
    odo.reset()
    assert np.array_equal(odo.process(scans[2]).T_odom_base, np.eye(3))


# ---- one kernel call per scan (rangeflow_fused) ------------------------------------------------------------


def test_packed_pyramid_and_warp_match_the_per_level_kernels(rangesim):
    from simnav.odometry.rangeflow_fused import build_packed_pyramid, pack_geometry, warp_packed

    for circular, n, fov in [(False, 1080, 270), (True, 360, 360)]:
        layout = rf.beam_layout(rangesim.uniform_angles(n, fov) + (0.01 if circular else 0.0))
        geoms = rf.pyramid_geometry(layout, 5, 16)
        packed = pack_geometry(geoms)
        scan = rangesim.ScanSimulator(rangesim.l_room(), layout.angles_rad, noise_m=0.01).scan(
            se2.from_xy_yaw(2.5, 2.2, 0.3))
        ranges = np.asarray(scan.ranges_m, dtype=np.float64)
        flat = build_packed_pyramid(ranges, packed, 0.3, True)
        for lv, level in enumerate(rf.build_pyramid(ranges, geoms, 0.3, True)):
            assert np.array_equal(packed.split(flat)[lv], level)
        T = se2.from_xy_yaw(0.08, -0.03, 0.05)
        for farthest in (False, True):
            warped = packed.split(warp_packed(flat, packed, T, farthest))
            for lv, g in enumerate(geoms):
                expected = rf.warp_scan(packed.split(flat)[lv], g, T, g, keep="farthest" if farthest else "closest")
                assert np.array_equal(warped[lv], expected)


@pytest.mark.parametrize(("name", "config"), [("rf2o", {}), ("srf", {"mode": "CA"}), ("srf", {"mode": "KA"}),
                                              ("srf", {"mode": "MA"})])
def test_one_call_coarse_to_fine_equals_the_python_loop(name, config, rangesim):
    # The Python loop (used for scans on different grids) is the reference: same kernels, same order, same bits.
    scans, _ = _room_scans(rangesim, n=25, noise_m=0.01, seed=3)
    fused, loop = make_scan_odometry(name, **config), make_scan_odometry(name, **config)
    calls = []

    def python_loop(references, ref, new, xi_prior):
        calls.append(len(references))
        return rf.coarse_to_fine([ref.packed.split(r) for r in references], ref.geoms, new, loop._solve_level,
                                 xi_prior, loop._ctf)

    loop._coarse_to_fine = python_loop
    for scan in scans:
        a, b = fused.process(scan), loop.process(scan)
        assert np.array_equal(a.T_odom_base, b.T_odom_base) and np.array_equal(a.covariance, b.covariance)
        assert a.valid_points == b.valid_points and a.degenerate == b.degenerate
    assert len(calls) >= 24 and (max(calls) == 2) == (config.get("mode") == "MA")


@pytest.mark.parametrize("name", ODOMETRIES)
def test_a_scanner_whose_beams_change_mid_run_is_aligned_across_the_change(name, rangesim):
    # Scans on different grids take the Python loop (and SRF warps the keyscan level by level).
    poses = rangesim.trajectory(12, speed_mps=0.5)
    sims = [rangesim.ScanSimulator(rangesim.l_room(), rangesim.uniform_angles(n, 270), noise_m=0.005)
            for n in (1080, 1000)]
    odo = make_scan_odometry(name)
    for i, T in enumerate(poses):
        est = odo.process(sims[i // 6].scan(T, 0.1 * i))
        _assert_finite(est)
        assert est.extra["measured"] or i == 0
    dist, yaw = _pose_error(est.T_odom_base, se2.inverse(poses[0]) @ poses[-1])
    assert dist < 0.01 and yaw < 0.2


def test_vectorisable_atan2_matches_libm_within_two_ulp():
    from numba import njit

    @njit
    def angles(y, x):
        out = np.empty(len(x))
        for i in range(len(x)):
            out[i] = rf.atan2_vectorisable(y[i], x[i])
        return out

    rng = np.random.default_rng(0)
    x = rng.normal(size=200_000) * np.exp(rng.uniform(-15, 15, 200_000))
    y = rng.normal(size=200_000) * np.exp(rng.uniform(-15, 15, 200_000))
    x[:100], y[100:200], x[200:300] = 0.0, 0.0, y[200:300]  # axes and the diagonal
    x[300:400] = -y[300:400]
    got, expected = angles(y, x), np.arctan2(y, x)
    assert np.all(np.abs(got - expected) <= 2 * np.spacing(np.abs(expected)) + 1e-300)
    signed_zeros = angles(np.array([-0.0, 0.0, -0.0, 0.0]), np.array([-1.0, -1.0, 1.0, 0.0]))
    assert np.array_equal(signed_zeros, [-math.pi, math.pi, -0.0, 0.0])
    assert np.array_equal(np.signbit(signed_zeros), [True, False, True, False])
