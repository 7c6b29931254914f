"""Trajectory metrics: RPE per second against hand-computed values, ATE after alignment, KITTI drift, errors."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from simnav.errors import ConfigError
from simnav.geometry import se3
from simnav.io import DataFormatError, Trajectory
from simnav.metrics import ate, drift_per_segment, planar_trajectory, plot_trajectories, rpe_per_second


def arc(stamps_s: np.ndarray, v_m_s: float, w_rad_s: float, start_xyt=(0.0, 0.0, 0.0)) -> Trajectory:
    """Constant twist (v, w) from ``start_xyt``: a circular arc (a straight line for w = 0)."""
    x0, y0, yaw0 = start_xyt
    t = np.asarray(stamps_s) - stamps_s[0]
    yaw = yaw0 + w_rad_s * t
    if w_rad_s == 0:
        dx, dy = v_m_s * t, np.zeros_like(t)
    else:
        r = v_m_s / w_rad_s
        dx, dy = r * np.sin(w_rad_s * t), r * (1 - np.cos(w_rad_s * t))
    c, s = math.cos(yaw0), math.sin(yaw0)
    return planar_trajectory(stamps_s, np.c_[x0 + c * dx - s * dy, y0 + s * dx + c * dy, yaw])


def test_rpe_of_a_scale_error_is_the_speed_error_whatever_the_frames_and_stamps():
    """gt: 0.5 m/s straight at 20 Hz from (3, 1, 30 deg); estimate: 2 % too fast, from the origin, at jittered
    10 Hz stamps (the ground truth is interpolated between its samples). Every pair: 0.02 * 0.5 m/s = 1 cm/s."""
    gt = arc(np.arange(0, 10.0001, 0.05), 0.5, 0.0, (3.0, 1.0, math.radians(30)))
    k = np.arange(99)
    stamps = 0.037 + 0.1 * k + 0.01 * np.sin(k)
    est = planar_trajectory(stamps, np.c_[1.02 * 0.5 * (stamps - 0.0), np.zeros_like(stamps), np.zeros_like(stamps)])
    result = rpe_per_second(est, gt, delta_s=1.0, tol_s=0.05)
    assert result.pairs >= 80
    assert result.trans_rmse_cm_s == pytest.approx(1.0, abs=1e-6)
    assert result.trans_mean_cm_s == pytest.approx(1.0, abs=1e-6)
    assert result.trans_median_cm_s == pytest.approx(1.0, abs=1e-6)
    assert result.rot_rmse_deg_s == pytest.approx(0.0, abs=1e-6)
    dt = np.diff(stamps)
    assert dt.min() < 0.1 < dt.max()  # pairs are not exactly 1 s apart: the errors are divided by the true dt


def test_rpe_of_a_yaw_rate_bias_matches_the_hand_computed_arc_error():
    """gt: v = 0.5 m/s, w = 0.2 rad/s; estimate: w = 0.25 rad/s. Over dt = 1 s the relative motions are chords
    c(w) = (v/w) (sin w, 1 - cos w) rotated by w; the error is |c(0.25) - c(0.2)| (cm/s) and 0.05 rad/s (deg/s)."""
    v, w_gt, w_est = 0.5, 0.2, 0.25
    gt = arc(np.arange(0, 20.0001, 0.05), v, w_gt, (-2.0, 4.0, 1.0))
    est = arc(np.arange(0, 20.0001, 0.1), v, w_est)

    def chord(w: float) -> np.ndarray:
        return v / w * np.array([math.sin(w), 1 - math.cos(w)])

    expected_cm_s = float(np.linalg.norm(chord(w_est) - chord(w_gt))) * 100  # = 2.4811... cm/s
    expected_deg_s = math.degrees(w_est - w_gt)  # = 2.8648 deg/s
    result = rpe_per_second(est, gt)
    assert result.pairs == 191
    assert result.trans_rmse_cm_s == pytest.approx(expected_cm_s, rel=1e-6)
    assert result.trans_median_cm_s == pytest.approx(expected_cm_s, rel=1e-6)
    assert result.rot_mean_deg_s == pytest.approx(expected_deg_s, rel=1e-6)
    assert result.rot_max_deg_s == pytest.approx(expected_deg_s, rel=1e-6)
    assert len(result.trans_errors_cm_s) == len(result.stamps_s) == result.pairs


def test_rpe_skips_pairs_outside_the_ground_truth():
    gt = arc(np.arange(2.0, 6.0001, 0.05), 0.5, 0.1)
    est = arc(np.arange(0.0, 10.0001, 0.1), 0.5, 0.1)
    result = rpe_per_second(est, gt)
    assert result.pairs == 31  # first poses 2.0 .. 5.0 s
    assert result.stamps_s.min() == pytest.approx(2.0) and result.stamps_s.max() == pytest.approx(5.0)


def wavy_path(n: int = 200) -> Trajectory:
    t = np.linspace(0, 40, n)
    return planar_trajectory(t, np.c_[0.3 * t, 2 * np.sin(0.2 * t), np.arctan2(0.4 * np.cos(0.2 * t), 0.3)])


def test_ate_of_a_rigidly_moved_copy_is_zero_after_se3_alignment_and_the_offset_without():
    gt = wavy_path()
    T_moved = se3.from_rpy(0.0, 0.0, math.radians(40), [5.0, -3.0, 0.0])
    est = Trajectory(gt.stamps_s, T_moved @ gt.T)
    aligned = ate(est, gt, "se3")
    assert aligned.rmse_m < 1e-9 and aligned.max_m < 1e-9 and aligned.pairs == len(gt)
    assert aligned.alignment == "se3-planar"  # planar trajectories are aligned by a rotation about z
    np.testing.assert_allclose(aligned.aligned.T, gt.T, atol=1e-9)

    shifted = Trajectory(gt.stamps_s, se3.from_rotation_translation(np.eye(3), [1.0, 2.0, 0.5]) @ gt.T)
    raw = ate(shifted, gt, "none")
    assert raw.rmse_m == pytest.approx(math.sqrt(1 + 4 + 0.25)) and raw.max_m == pytest.approx(raw.rmse_m)
    assert ate(shifted, gt, "se3").rmse_m < 1e-9


def test_ate_aligns_3d_trajectories_with_evo_and_sim3_recovers_the_scale():
    t = np.linspace(0, 10, 150)
    gt = Trajectory(t, np.stack([se3.from_rpy(0.1 * np.sin(s), 0.2 * s, 0.3 * s, [np.cos(s), np.sin(s), 0.2 * s])
                                 for s in t]))
    T_moved = se3.from_rpy(0.3, -0.2, 1.0, [1.0, 2.0, 3.0])
    est = Trajectory(t, T_moved @ gt.T)
    result = ate(est, gt, "se3")
    assert result.alignment == "se3" and result.rmse_m < 1e-9
    scaled = est.T.copy()
    scaled[:, :3, 3] *= 0.5
    sim3 = ate(Trajectory(t, scaled), gt, "sim3")
    assert sim3.scale == pytest.approx(2.0) and sim3.rmse_m < 1e-9
    assert ate(Trajectory(t, scaled), gt, "se3").rmse_m > 0.1


def test_ate_of_a_straight_run_aligns_in_the_plane():
    gt = arc(np.arange(0, 5.0001, 0.1), 0.4, 0.0, (1.0, 1.0, 0.5))
    est = arc(np.arange(0, 5.0001, 0.1), 0.4, 0.0)  # the same run, in the odom frame
    result = ate(est, gt)
    assert result.alignment == "se3-planar" and result.rmse_m < 1e-9


def test_drift_of_a_one_percent_scale_error_is_one_percent():
    gt = arc(np.arange(0, 30.0001, 0.02), 0.5, 0.0, (2.0, 0.0, 1.0))  # 15 m at 1 cm steps
    est = arc(np.arange(0, 30.0001, 0.02), 0.505, 0.0)
    drift = drift_per_segment(est, gt)
    assert sorted(drift) == [1.0, 2.0, 5.0, 10.0]  # 20, 50, 100 m are longer than the path
    for length, d in drift.items():
        assert d.length_m == length and d.segments > 0
        assert d.translation_pct == pytest.approx(1.0, abs=0.011)
        assert d.rotation_deg_per_m == pytest.approx(0.0, abs=1e-9)
    assert drift[10.0].segments == pytest.approx(5 / 0.01, abs=2)  # a start every 1 cm over the first 5 m


def test_drift_of_a_yaw_rate_bias_in_deg_per_m():
    gt = arc(np.arange(0, 20.0001, 0.05), 0.5, 0.0)
    est = arc(np.arange(0, 20.0001, 0.05), 0.5, 0.01)  # 0.01 rad/s at 0.5 m/s = 0.02 rad/m
    drift = drift_per_segment(est, gt, lengths_m=(2,))
    assert drift[2].rotation_deg_per_m == pytest.approx(math.degrees(0.02), rel=0.03)


def test_inputs_are_validated_with_clear_errors():
    gt = arc(np.arange(0, 5.0001, 0.1), 0.5, 0.1)
    later = arc(np.arange(100, 105.0001, 0.1), 0.5, 0.1)
    for metric in (rpe_per_second, ate, drift_per_segment):
        with pytest.raises(DataFormatError, match="do not overlap in time"):
            metric(later, gt)
    with pytest.raises(DataFormatError, match="estimate: needs at least 2 poses"):
        ate(Trajectory(gt.stamps_s[:1], gt.T[:1]), gt)
    repeated = Trajectory(np.r_[gt.stamps_s[:3], gt.stamps_s[2:]], np.concatenate([gt.T[:3], gt.T[2:]]))
    with pytest.raises(DataFormatError, match="ground truth: time stamps must be strictly increasing"):
        rpe_per_second(gt, repeated)
    with pytest.raises(DataFormatError, match="no pair of estimate poses 10 s"):
        rpe_per_second(gt, gt, delta_s=10.0)
    with pytest.raises(ConfigError, match="align"):
        ate(gt, gt, "affine")
    with pytest.raises(ConfigError, match="delta_s"):
        rpe_per_second(gt, gt, delta_s=0.0)
    with pytest.raises(ConfigError, match="segment lengths"):
        drift_per_segment(gt, gt, lengths_m=(-1,))


def test_results_serialise_and_plot(tmp_path):
    gt = wavy_path()
    est = Trajectory(gt.stamps_s, se3.from_rpy(0, 0, 0.3, [1, 0, 0]) @ gt.T)
    report = {"rpe": rpe_per_second(est, gt).as_dict(), "ate": ate(est, gt).as_dict(),
              "drift": {str(k): v.as_dict() for k, v in drift_per_segment(est, gt).items()}}
    text = json.dumps(report)
    assert "trans_rmse_cm_s" in text and "rmse_m" in text and "translation_pct" in text
    assert "stamps_s" not in text
    png = plot_trajectories(est, gt, tmp_path / "plots" / "xy.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_ate_of_a_straight_camera_run_uses_the_orientations():
    # a camera driving straight ahead along its optical axis (z), tilted, estimated in its first optical frame:
    # the positions are collinear, so only the orientations fix the rotation about the line
    T_world_cam0 = se3.from_rpy(-np.pi / 2 - 0.5, 0.0, -np.pi / 2, [1.0, 2.0, 1.1])
    stamps = np.arange(20) * 0.1
    T_gt = np.array([T_world_cam0 @ se3.from_rpy(0, 0, 0, [0, 0, 0.05 * k]) for k in range(20)])
    T_est = np.array([se3.inverse(T_world_cam0) @ T for T in T_gt])
    result = ate(Trajectory(stamps, T_est), Trajectory(stamps, T_gt))
    assert result.rmse_m < 1e-6
    assert result.alignment == "se3-axes"
