from __future__ import annotations

import math

import numpy as np
import pytest

from simnav.agents import DoorLeaf
from simnav.agents.doors import _BLOCKED, _UNSURE, DoorLeaves, DoorStage, _sweep_verdict, door_segments
from simnav.world.schema import Door

DT = 0.05
FAR = np.array([[50.0, 50.0]])


def _door(**kw: float) -> DoorLeaf:
    base = dict(hinge=(1.0, 2.0), width_m=0.9, closed_yaw_deg=0.0, swing_deg=90.0, open_s=5.0, closed_s=3.0,
                move_s=1.0, auto_open_radius_m=1.2)
    base.update(kw)
    return DoorLeaf(Door(**base))


def _run(
    leaf: DoorLeaf, t0: float, t1: float, nearby: np.ndarray | None = None
) -> list[tuple[float, float, float]]:
    """(t, opening, yaw rate) after each update from t0 to t1."""
    out = []
    steps = int(round((t1 - t0) / DT))
    for k in range(1, steps + 1):
        t = t0 + k * DT
        leaf.update(t, DT, nearby)
        out.append((t, leaf.opening, leaf.yaw_rate_rad_s))
    return out


def test_schedule_open_close_open() -> None:
    leaf = _door()
    assert leaf.opening == 1.0 and leaf.yaw_rad == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(leaf.segment_xy(), [[1.0, 2.0], [1.0, 2.9]], atol=1e-12)
    trace = {round(t, 2): (o, w) for t, o, w in _run(leaf, 0.0, 12.0, FAR)}
    assert trace[4.9][0] == 1.0
    assert 0.0 < trace[5.5][0] < 1.0 and trace[5.5][1] < 0.0  # closing: yaw decreases for a positive swing
    assert trace[6.5][0] == 0.0 and trace[8.9][0] == 0.0
    assert 0.0 < trace[9.5][0] < 1.0 and trace[9.5][1] > 0.0
    assert trace[10.5][0] == 1.0


def test_segment_endpoints_and_center() -> None:
    leaf = _door()
    _run(leaf, 0.0, 7.0, FAR)
    seg = leaf.segment_xy()
    np.testing.assert_allclose(seg, [[1.0, 2.0], [1.9, 2.0]], atol=1e-12)  # closed: across the doorway
    np.testing.assert_allclose(leaf.center_xy, [1.45, 2.0])
    assert door_segments([leaf, _door()]).shape == (2, 2, 2)
    assert door_segments([]).shape == (0, 2, 2)


def test_yaw_rate_matches_motion_and_negative_swing() -> None:
    leaf = _door(swing_deg=-90.0)
    previous = leaf.yaw_rad
    rates = []
    for k in range(1, int(11.0 / DT) + 1):
        leaf.update(k * DT, DT, FAR)
        assert leaf.yaw_rad - previous == pytest.approx(leaf.yaw_rate_rad_s * DT, abs=1e-12)
        rates.append((leaf.stage, leaf.yaw_rate_rad_s))
        previous = leaf.yaw_rad
    assert all(w >= 0.0 for s, w in rates if s == DoorStage.CLOSING)  # closing a negative swing turns yaw up
    assert all(w <= 0.0 for s, w in rates if s == DoorStage.OPENING)
    assert any(w != 0.0 for _, w in rates)


def test_opens_early_for_someone_waiting() -> None:
    leaf = _door()
    _run(leaf, 0.0, 6.5, FAR)
    assert leaf.opening == 0.0
    waiting = np.array([[1.45, 1.2]])  # 0.8 m from the doorway centre
    trace = _run(leaf, 6.5, 8.0, waiting)
    assert trace[-1][1] == 1.0  # opened within move_s, well before the scheduled 9 s
    assert all(w >= 0.0 for _, _, w in trace)
    # stays open while someone is near, far beyond open_s
    assert all(o == 1.0 for _, o, _ in _run(leaf, 8.0, 20.0, waiting))
    # then open_s more after they leave, then closes
    after = _run(leaf, 20.0, 27.0, FAR)
    assert all(o == 1.0 for t, o, _ in after if t < 24.95)
    assert after[-1][1] == 0.0


def test_reverses_while_closing_and_never_closes_on_someone() -> None:
    leaf = _door()
    _run(leaf, 0.0, 5.4, FAR)
    assert leaf.stage == DoorStage.CLOSING
    opening = leaf.opening
    leaf.update(5.45, DT, np.array([[1.45, 2.5]]))
    assert leaf.stage == DoorStage.OPENING and leaf.opening > opening - 1e-9
    leaf2 = _door()
    assert all(o == 1.0 for _, o, _ in _run(leaf2, 0.0, 30.0, np.array([[2.0, 2.0]])))


def test_phase_shifts_the_schedule() -> None:
    leaf = _door(phase_s=6.0)  # 6 s into the cycle: closed
    assert leaf.opening == 0.0 and leaf.stage == DoorStage.CLOSED
    _run(leaf, 0.0, 3.5, FAR)
    assert leaf.stage == DoorStage.OPENING and leaf.opening == pytest.approx(0.5)
    _run(leaf, 3.5, 4.5, FAR)
    assert leaf.opening == 1.0


def test_presence_sensor_pauses_a_leaf_that_would_sweep_into_someone() -> None:
    leaf = _door()
    _run(leaf, 0.0, 6.5, FAR)
    assert leaf.opening == 0.0
    in_swing = np.array([[1.5, 2.4, 0.2]])  # waits inside the quarter circle the leaf sweeps when opening
    for k in range(1, 61):
        leaf.update(6.5 + k * DT, DT, in_swing[:, :2], in_swing)
        gap = leaf._clearance_m(leaf.opening, in_swing)[0]
        assert gap >= 0.0  # never touches
    assert 0.0 < leaf.opening < 1.0 and leaf.yaw_rate_rad_s == 0.0  # paused part-way
    assert gap < 2 * leaf.spec.safety_clearance_m  # stopped at the edge of its sensing zone
    stepped_back = np.array([[1.45, 1.2, 0.2]])  # out of the swing, still near enough to keep it opening
    trace = _run(leaf, 9.5, 11.0, stepped_back[:, :2])
    assert trace[-1][1] == 1.0


def test_presence_sensor_ignores_someone_the_leaf_moves_away_from() -> None:
    leaf = _door()
    _run(leaf, 0.0, 6.5, FAR)
    behind = np.array([[1.45, 1.75, 0.2]])  # on the far side of the closed leaf, touching it
    for k in range(1, 41):
        leaf.update(6.5 + k * DT, DT, behind[:, :2], behind)
    assert leaf.opening == 1.0


def test_leaves_update_together_as_each_one_alone() -> None:
    specs = [_door().spec, _door(hinge=(3.0, 2.0), closed_yaw_deg=180.0, swing_deg=-90.0, phase_s=6.0).spec,
             _door(hinge=(2.0, 0.5), closed_yaw_deg=90.0, closed_s=0.0, move_s=0.7, phase_s=2.0).spec]
    together, alone = DoorLeaves(specs), [DoorLeaf(spec) for spec in specs]
    assert len(together) == 3 and together[1].spec == specs[1]
    rng = np.random.default_rng(0)
    people = rng.uniform(0.0, 4.0, (6, 2))
    for k in range(1, 600):
        people += rng.normal(0.0, 0.05, people.shape)
        circles = np.column_stack([people, np.full(len(people), 0.2)])
        together.update(k * DT, DT, people, circles)
        for leaf in alone:
            leaf.update(k * DT, DT, people, circles)
        state = [(leaf.opening, leaf.stage, leaf.yaw_rad, leaf.yaw_rate_rad_s, leaf.time_s) for leaf in together]
        assert state == [(leaf.opening, leaf.stage, leaf.yaw_rad, leaf.yaw_rate_rad_s, leaf.time_s) for leaf in alone]
    np.testing.assert_array_equal(together.segments_xy(), door_segments(alone))
    np.testing.assert_array_equal(together.yaw_rates_rad_s, [leaf.yaw_rate_rad_s for leaf in alone])


def test_compiled_swing_check_agrees_with_the_reference_formula() -> None:
    leaf = _door()
    rng = np.random.default_rng(3)
    for _ in range(3000):
        before, after = rng.uniform(0.0, 1.0, 2)
        blockers = np.column_stack([rng.uniform(0.0, 3.0, (3, 2)), rng.uniform(0.05, 0.4, 3)])
        verdict = _sweep_verdict(leaf._params[0], before, after, blockers)
        assert verdict == _UNSURE or (verdict == _BLOCKED) == leaf._sweeps_into(before, after, blockers)


def test_a_swing_too_close_to_call_is_left_to_the_reference_formula() -> None:
    leaf = _door(phase_s=6.0)  # closed
    behind = np.array([[0.85, 2.0, 0.09]])  # beside the hinge, inside the clearance, at a distance the swing keeps
    assert _sweep_verdict(leaf._params[0], 0.0, 0.1, behind) == _UNSURE
    assert not leaf._sweeps_into(0.0, 0.1, behind)
    for k in range(1, 31):
        leaf.update(k * DT, DT, behind[:, :2], behind)
    assert leaf.opening == 1.0  # opened for them as if they were not there
