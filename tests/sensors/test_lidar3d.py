"""3D lidar: every return lies on the room's walls or floor."""

from __future__ import annotations

import numpy as np

from simnav.robot import load_robot
from simnav.sim import Simulator

ROBOT = """
name: scanner
prisms:
  - {name: body, z_min_m: 0.0, z_max_m: 1.1, polygon: [[0.2, -0.2], [0.2, 0.2], [-0.2, 0.2], [-0.2, -0.2]]}
sensors:
  - {name: vlp, type: lidar3d, preset: vlp16_low, noise_std_m: 0.0, mount: {xyz_m: [0.0, 0.0, 1.0]}}
"""


def test_points_lie_on_walls_or_floor(tmp_path, box_room):
    path = tmp_path / "scanner.yaml"
    path.write_text(ROBOT)
    with Simulator(box_room, load_robot(path)) as sim:
        sim.step(0.0, 0.0)
        cloud = sim.latest("vlp")
        T_world_base = sim.T_world_base
    assert cloud.ranges_m.shape == (16, 450)
    assert np.isfinite(cloud.ranges_m).all() and (cloud.ranges_m > 0).mean() > 0.99
    p = cloud.points_base() @ T_world_base[:3, :3].T + T_world_base[:3, 3]
    on_floor = np.abs(p[:, 2]) < 1e-3
    on_wall = (np.minimum(np.abs(p[:, 0] - 0.05), np.abs(p[:, 0] - 5.95)) < 1e-3) | \
              (np.minimum(np.abs(p[:, 1] - 0.05), np.abs(p[:, 1] - 3.95)) < 1e-3)
    assert (on_floor | on_wall).all()
    assert on_wall.mean() > 0.99  # from 1 m up with +-15 degrees, the 6 x 4 m room shows walls only
