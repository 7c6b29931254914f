"""Shared fixtures: tiny explicit worlds with analytically known geometry."""

from __future__ import annotations

import pytest

from simnav.world.schema import WorldSpec


def box_room_spec(**extra) -> WorldSpec:
    """A closed 6 x 4 m room (wall centre lines on x = 0, 6 and y = 0, 4; 0.1 m thick, so the free interior is
    [0.05, 5.95] x [0.05, 3.95]) with the robot spawned in the middle facing +x."""
    data = dict(
        name="box_room",
        walls=[dict(points=[[0, 0], [6, 0], [6, 4], [0, 4], [0, 0]], thickness_m=0.1, height_m=2.5)],
        roadmap=dict(nodes=[[1, 1], [5, 1], [5, 3], [1, 3]], edges=[[0, 1], [1, 2], [2, 3], [3, 0]]),
        spawns=[dict(x_m=3.0, y_m=2.0, yaw_deg=0.0)],
        agents=dict(pedestrians=0, robots=0),
    )
    data.update(extra)
    return WorldSpec.model_validate(data)


@pytest.fixture
def box_room() -> WorldSpec:
    return box_room_spec()
