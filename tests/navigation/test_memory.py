"""Short-term memory: obstacles that leave the sensors' view are remembered for a while (thesis §6.C.5)."""

from __future__ import annotations

import numpy as np

from simnav.geometry import se2
from simnav.navigation.memory import MemoryConfig, ShortTermMemory


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
