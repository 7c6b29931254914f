"""Short-term memory: obstacles that leave the sensors' view are remembered for a while (thesis §6.C.5)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simnav.geometry import se2
from simnav.navigation.memory import MemoryConfig, ScanHistory, ShortTermMemory


def test_an_obstacle_seen_twice_is_remembered_after_it_leaves_the_view_then_fades() -> None:
    memory = ShortTermMemory(2, MemoryConfig(decay_s=1.0))
    T = se2.from_xy_yaw(1.0, 2.0, 0.5)
    seen = [np.array([[0.6, 0.1]]), np.zeros((0, 2))]
    for k in range(2):
        memory.update(0.05 * k, T, seen)
    # the robot moves 0.1 m forward; the obstacle (now in the blind zone) is no longer sensed
    T2 = T @ se2.from_xy_yaw(0.1, 0.0, 0.0)
    low, high = memory.update(0.1, T2, [np.zeros((0, 2)), np.zeros((0, 2))])
    assert len(high) == 0
    assert len(low) == 1
    np.testing.assert_allclose(low[0], [0.5, 0.1], atol=0.04)
    # without new hits, the evidence decays to unknown
    for k in range(20):
        low, _ = memory.update(0.15 + 0.1 * k, T2, [np.zeros((0, 2)), np.zeros((0, 2))])
    assert len(low) == 0


def test_a_single_hit_is_not_an_obstacle_and_free_space_ahead_erases_one() -> None:
    memory = ShortTermMemory(1)
    T = np.eye(3)
    (out,) = memory.update(0.0, T, [np.array([[0.4, 0.0]])])
    assert len(out) == 0
    memory.update(0.05, T, [np.array([[0.4, 0.0]])])
    (out,) = memory.update(0.1, T, [np.zeros((0, 2))])
    assert len(out) == 1
    # a cell in the cone ahead beyond the blind range, without hits, loses its evidence
    memory = ShortTermMemory(1, MemoryConfig(emit_range_m=1.0))
    for k in range(2):
        memory.update(0.05 * k, T, [np.array([[0.8, 0.0]])])
    (out,) = memory.update(0.1, T, [np.zeros((0, 2))])
    assert len(out) == 1
    for k in range(4):
        (out,) = memory.update(0.15 + 0.05 * k, T, [np.zeros((0, 2))])
    assert len(out) == 0


def test_recentring_keeps_cells_in_place_in_the_odom_frame() -> None:
    memory = ShortTermMemory(1, MemoryConfig(emit_range_m=1.0, decay_s=100.0, cone_range_m=0.0))
    T = np.eye(3)
    for k in range(2):
        memory.update(0.05 * k, T, [np.array([[-0.5, 0.3]])])
    # move 0.37 m sideways and turn: the remembered point must stay where it was in the odom frame
    T2 = se2.from_xy_yaw(0.0, 0.37, 1.0)
    (out,) = memory.update(0.2, T2, [np.zeros((0, 2))])
    assert len(out) == 1
    np.testing.assert_allclose(se2.transform_points(T2, out)[0], [-0.5, 0.3], atol=0.03)
    # a jump beyond the grid forgets everything
    (out,) = memory.update(0.3, se2.from_xy_yaw(50.0, 0.0, 0.0), [np.zeros((0, 2))])
    assert len(out) == 0


def _flat(points: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    ptr = np.zeros(len(points) + 1, dtype=np.int64)
    np.cumsum([len(p) for p in points], out=ptr[1:])
    return np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in points]), ptr


def _remembered(memory: ShortTermMemory, t: float, scan: np.ndarray, other: np.ndarray) -> np.ndarray:
    scan_xy, scan_ptr = _flat([scan])
    xy, ptr = _flat([other])
    out, out_ptr = memory.update_flat(t, np.eye(3), xy, ptr, scan_xy, scan_ptr)
    return out[out_ptr[0]:out_ptr[1]]


def test_a_scan_that_looks_past_a_remembered_cell_clears_it_other_sensors_cells_only_decay() -> None:
    person_beside = np.array([[0.0, 0.55]])  # beside the robot: outside the camera cone, where a person walks by
    wall_behind_it = np.column_stack([np.linspace(-1.0, 1.0, 101), np.full(101, 2.0)])
    nothing = np.zeros((0, 2))
    # seen by the scan for a while: remembered once the person has gone (nothing there, nothing further either)
    memory = ShortTermMemory(1)
    for k in range(10):
        _remembered(memory, 0.05 * k, person_beside, nothing)
    assert len(_remembered(memory, 0.5, nothing, nothing)) > 0
    # the same, but now the scan reaches the wall behind: the cell was seen free and is cleared within 1 s
    memory = ShortTermMemory(1)
    for k in range(10):
        _remembered(memory, 0.05 * k, person_beside, nothing)
    left = [len(_remembered(memory, 0.5 + 0.05 * k, wall_behind_it, nothing)) for k in range(20)]
    assert left[-1] == 0 and left[0] > 0
    # a cell another sensor (a camera) saw keeps its evidence though the scan looks past it: it may be a low box
    # under the scan plane
    memory = ShortTermMemory(1)
    for k in range(10):
        _remembered(memory, 0.05 * k, nothing, person_beside)
    left = [len(_remembered(memory, 0.5 + 0.05 * k, wall_behind_it, nothing)) for k in range(20)]
    assert left[-1] > 0


def test_a_low_box_closer_than_the_camera_sees_the_floor_is_remembered_until_it_decays() -> None:
    # a box 5 cm high, 1 m ahead; the camera sees it while it is 0.81 m away or more, the robot drives on to 0.55 m
    # and stops: without the band's free-space limit the cone "sees" the blind cell free and forgets the box at once
    def remembered_while_standing(free_x_m: np.ndarray | None) -> float:
        memory = ShortTermMemory(1, free_x_m=free_x_m)
        t, last = 0.0, 0.0
        for k in range(200):
            t = 0.05 * k
            x = min(0.45, 0.02 * k)
            seen = [np.array([[1.0 - x, 0.0]])] if 1.0 - x >= 0.81 else [np.zeros((0, 2))]
            (out,) = memory.update(t, se2.from_xy_yaw(x, 0.0, 0.0), seen)
            if len(out):
                last = t
        return last

    # last seen at 0.45 s: measured, remembered until 1.1 s
    assert remembered_while_standing(None) < 1.5
    # the Giraff's base band is seen whole from 0.885 m on: remembered until 5.6 s (the 3 s decay from saturation)
    assert remembered_while_standing(np.array([[0.885, 4.55]])) > 5.0
    # a cell inside the band's free range is still seen free
    memory = ShortTermMemory(1, MemoryConfig(emit_range_m=1.0), free_x_m=np.array([[0.6, 1.0]]))
    for k in range(2):
        memory.update(0.05 * k, np.eye(3), [np.array([[0.8, 0.0]])])
    for k in range(4):
        (out,) = memory.update(0.1 + 0.05 * k, np.eye(3), [np.zeros((0, 2))])
    assert len(out) == 0


def test_free_ranges_must_match_the_bands() -> None:
    import pytest

    with pytest.raises(ValueError, match="free_x_m must be"):
        ShortTermMemory(2, free_x_m=np.zeros((1, 2)))


def test_what_left_every_sensors_view_fades_with_the_blind_decay() -> None:
    from simnav.navigation.sensing import ViewSector

    lidar = ViewSector(0.0, 0.0, 0.0, np.radians(120.0), 5.0)  # 240 degrees ahead
    side, rear = np.array([[0.0, 0.5]]), np.array([[-0.5, 0.0]])  # in the lidar's view / behind it

    def remembered(config: MemoryConfig, view) -> tuple[int, int]:
        """Virtual obstacles near the side point and near the rear point 3 s after both were last seen."""
        memory = ShortTermMemory(1, config, view=view)
        for k in range(2):
            memory.update(0.05 * k, np.eye(3), [np.concatenate([side, rear])])
        for k in range(30):
            (out,) = memory.update(0.15 + 0.1 * k, np.eye(3), [np.zeros((0, 2))])
        near = lambda p: int(np.any(np.hypot(*(out - p).T) < 0.05))  # noqa: E731
        return near(side[0]), near(rear[0])

    cfg = MemoryConfig(decay_s=1.0, blind_decay_s=30.0)
    assert remembered(cfg, [lidar]) == (0, 1)
    assert remembered(MemoryConfig(decay_s=1.0), [lidar]) == (0, 0)  # the default: one decay everywhere
    assert remembered(cfg, None) == (0, 0)  # without the sensors' view everything counts as in view


def test_the_kernels_view_test_agrees_with_the_view_sectors() -> None:
    from simnav.navigation.memory import _in_view
    from simnav.navigation.sensing import ViewSector

    sectors = [ViewSector(0.1, 0.0, 0.0, np.radians(120.0), 5.0), ViewSector(0.05, 0.02, 0.3, np.radians(28.0), 2.0)]
    view = np.array([[v.x_m, v.y_m, v.yaw_rad, v.half_angle_rad, v.range_m] for v in sectors])
    xy = np.random.default_rng(0).uniform(-6.0, 6.0, (2000, 2))
    expected = sectors[0].contains(xy) | sectors[1].contains(xy)
    assert 0 < expected.sum() < len(xy)
    assert [_in_view(view, x, y) for x, y in xy] == expected.tolist()


def _scan(T_odom_lidar: np.ndarray, walls_odom: np.ndarray, fov_rad: float = math.radians(240)) -> np.ndarray:
    """(S, 2) the wall points within the field of view, in the frame of a lidar at the base origin, m."""
    local = se2.transform_points(se2.inverse(T_odom_lidar), walls_odom)
    return local[np.abs(np.arctan2(local[:, 1], local[:, 0])) <= fov_rad / 2]


def test_space_a_scan_saw_free_stays_free_after_the_robot_turned_away() -> None:
    # a wall along x = 2 seen from the origin facing +x; then the robot turns to face -x (the wall behind it)
    wall = np.column_stack([np.full(81, 2.0), np.linspace(-2.0, 2.0, 81)])
    history = ScanHistory(keep_s=20.0)
    history.add(0.0, se2.from_xy_yaw(0.0, 0.0, 0.0), _scan(se2.from_xy_yaw(0.0, 0.0, 0.0), wall))
    turned = se2.from_xy_yaw(0.0, 0.0, math.pi)
    history.add(1.0, turned, _scan(turned, wall))
    assert len(history) == 2
    before, at, past, aside = [1.5, 0.3], [1.95, 0.0], [2.5, 0.0], [-1.5, 0.0]
    # before the wall (by more than clearance_m): free; on it, past it, or where no scan had a return: not
    np.testing.assert_array_equal(history.seen_free(np.array([before, at, past, aside])),
                                  [True, False, False, False])


def test_the_newest_scan_in_a_bearing_decides() -> None:
    wall = np.column_stack([np.full(81, 2.0), np.linspace(-2.0, 2.0, 81)])
    person = np.array([[1.0, 0.0], [1.0, 0.05], [1.0, -0.05]])
    history, T = ScanHistory(step_m=0.0, step_rad=0.0), se2.from_xy_yaw(0.0, 0.0, 0.0)
    history.add(0.0, T, _scan(T, wall))
    history.add(0.5, T, _scan(T, np.vstack([wall, person])))  # someone walked in at 1 m
    assert not history.seen_free(np.array([[1.5, 0.0]]))[0]
    history.add(1.0, T, _scan(T, wall))  # and left
    assert history.seen_free(np.array([[1.5, 0.0]]))[0]


def test_scans_are_kept_only_apart_in_pose_and_for_keep_s() -> None:
    wall = np.column_stack([np.full(81, 2.0), np.linspace(-2.0, 2.0, 81)])
    history = ScanHistory(keep_s=5.0, step_m=0.05, step_rad=math.radians(5.0))
    for k in range(10):  # 4 mm apart, 3.6 cm in all: only the first is kept
        T = se2.from_xy_yaw(0.004 * k, 0.0, 0.0)
        history.add(0.1 * k, T, _scan(T, wall))
    assert len(history) == 1
    T = se2.from_xy_yaw(0.2, 0.0, 0.0)
    history.add(1.0, T, _scan(T, wall))
    assert len(history) == 2
    T = se2.from_xy_yaw(0.4, 0.0, 0.0)
    history.add(5.5, T, _scan(T, wall))  # the first, 5.5 s old, is dropped
    assert len(history) == 2
    history.reset()
    assert len(history) == 0 and not history.seen_free(np.array([[1.0, 0.0]]))[0]


def test_the_lidar_origin_sets_the_bearings() -> None:
    # a post at (1.0, 0.3) (base frame) before a wall along x = 2: (1.5, 0.6) lies right behind the post as seen
    # from a lidar 0.5 m ahead of the base origin, but beside it as seen from the base origin
    scan = np.vstack([[[1.0, 0.3]], np.column_stack([np.full(81, 2.0), np.linspace(-2.0, 2.0, 81)])])
    T, behind, before_wall = se2.from_xy_yaw(0.0, 0.0, 0.0), [1.5, 0.6], [1.5, -0.3]
    for origin, free in (((0.5, 0.0), [False, True]), ((0.0, 0.0), [True, True])):
        history = ScanHistory(origin_xy=origin)
        history.add(0.0, T, scan)
        np.testing.assert_array_equal(history.seen_free(np.array([behind, before_wall])), free)
    with pytest.raises(ValueError, match="ScanHistory"):
        ScanHistory(keep_s=0.0)


def test_a_point_the_rays_passed_close_to_a_scan_point_is_not_free() -> None:
    # the rays towards (1.05, 0.2) reach the wall along x = 2, but pass 0.11 m from a post at (1.0, 0.3): free
    # only for a disk of less than that around the point
    scan = np.vstack([[[1.0, 0.3]], np.column_stack([np.full(81, 2.0), np.linspace(-2.0, 2.0, 81)])])
    T, beside_post = se2.from_xy_yaw(0.0, 0.0, 0.0), np.array([[1.05, 0.2]])
    for clearance_m, free in ((0.01, True), (0.15, False)):
        history = ScanHistory(clearance_m=clearance_m)
        history.add(0.0, T, scan)
        assert history.seen_free(beside_post)[0] is np.bool_(free)


def test_bearings_wrap_around_behind_the_lidar() -> None:
    # a 360 degree scan of a round room of radius 2 m: right behind the lidar, either side of the bearing pi
    a = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    history, T = ScanHistory(clearance_m=0.2), se2.from_xy_yaw(0.0, 0.0, 0.0)
    history.add(0.0, T, 2.0 * np.column_stack([np.cos(a), np.sin(a)]))
    points = np.array([[-1.5, 0.01], [-1.5, -0.01], [-1.9, 0.0], [-1.9, 0.05], [0.1, 0.0]])
    np.testing.assert_array_equal(history.seen_free(points), [True, True, False, False, True])
