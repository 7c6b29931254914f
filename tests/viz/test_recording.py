"""The recorder driven by a simulator alone (no navigator, as a Gymnasium env would), its file, and its replay."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from simnav.errors import SimnavError
from simnav.robot import load_robot
from simnav.sim import Simulator
from simnav.viz import NullViewer, Recorder, Recording, VizConfig, VizObserver, replay_commands
from simnav.viz.recording import RECORDING_FILE
from simnav.world import load_world

STEPS = 40  # 2 s at the default 20 Hz control rate


@pytest.fixture(scope="module")
def sim_recording(tmp_path_factory):
    """Two simulated seconds in the flat world with two people, recorded at 10 Hz without a navigator."""
    out = tmp_path_factory.mktemp("sim-recording")
    with Simulator(load_world("flat"), load_robot("giraff"), seed=4) as sim:
        observer = VizObserver([Recorder(out, VizConfig(rate_hz=10.0))])
        observer.attach(sim)
        for _ in range(STEPS):
            observer.observe(sim.step(0.3, 0.2))
        observer.finish()
        final = dict(pose=sim.pose_xy_yaw, people=np.column_stack([sim.crowd.positions_xy, sim.crowd.yaws_rad]),
                     doors=np.array([d.yaw_rad for d in sim.doors]), time_s=sim.time_s)
    return out, final


def test_a_simulator_alone_is_recorded_at_the_configured_rate(sim_recording):
    out, final = sim_recording
    rec = Recording.load(out)
    assert rec.scene.world.name == "flat" and rec.scene.robot.name == "giraff" and rec.scene.paths is None
    assert len(rec.times_s) == 21 and np.allclose(np.diff(rec.times_s[1:]), 0.1)
    assert rec.times_s[-1] == pytest.approx(final["time_s"])
    # the last frame is the simulator's final state
    x, y, yaw = final["pose"]
    assert np.allclose(rec.base_xyyaw[-1], [x, y, yaw], atol=1e-6)
    assert rec.people.shape == (21, 2, 3) and np.allclose(rec.people[-1], final["people"], atol=1e-4)
    assert np.allclose(rec.door_yaws_rad[-1], final["doors"], atol=1e-5)
    # without a navigator: no estimate, no obstacles, no chosen path, no route
    assert np.isnan(rec.est_xyyaw).all() and (rec.ptg == -1).all() and len(rec.routes) == 0
    # point clouds once per simulated second, thinned to the cap, in the robot's frame
    assert list(rec.point_frames) == [0, 11]  # t = 0.05 s and the first frame from 1.05 s on
    scan, depth = rec.points["scan"][1], rec.points["depth"][1]
    assert 50 <= len(scan) <= VizConfig().record_max_points and 50 <= len(depth) <= VizConfig().record_max_points
    assert np.all(np.linalg.norm(scan[:, :2], axis=1) < 8.5) and np.allclose(scan[:, 2], 0.30, atol=0.01)
    assert (out / RECORDING_FILE).stat().st_size < 60_000


def test_a_recording_survives_its_file(sim_recording, tmp_path):
    out, _ = sim_recording
    rec = Recording.load(out / RECORDING_FILE)
    again = Recording.load(rec.save(tmp_path / "copy.npz"))
    assert again.scene == rec.scene and again.rate_hz == rec.rate_hz
    for name in ("times_s", "base_xyyaw", "people", "robots", "door_yaws_rad", "point_frames"):
        assert np.array_equal(getattr(again, name), getattr(rec, name), equal_nan=True), name
    assert np.array_equal(again.points["depth"].xyz, rec.points["depth"].xyz)


def test_the_replay_animates_every_moving_thing(sim_recording):
    import umsgpack

    rec = Recording.load(sim_recording[0])
    commands = replay_commands(rec)
    assert all(c.path.startswith(("/meshcat", "/Grid", "/Axes", "/Lights", "/Cameras")) or c.path == ""
               for c in commands)
    animation = umsgpack.unpackb(next(c for c in commands if c.kind == "set_animation").payload)
    paths = {a["path"] for a in animation["animations"]}
    assert {"/meshcat/robot", "/meshcat/people/p0", "/meshcat/people/p1", "/meshcat/doors/d0", "/meshcat"} <= paths
    robot = next(a for a in animation["animations"] if a["path"] == "/meshcat/robot")
    position = next(t for t in robot["clip"]["tracks"] if t["name"] == ".position")
    assert len(position["keys"]) == len(rec.times_s)
    assert position["keys"][-1]["time"] == pytest.approx(rec.duration_s)
    assert np.allclose(position["keys"][-1]["value"][:2], rec.base_xyyaw[-1, :2])
    clouds = {c.path for c in commands if c.kind == "set_object" and c.path.startswith("/meshcat/replay/points")}
    assert clouds == {"/meshcat/replay/points/k0/scan", "/meshcat/replay/points/k0/depth",
                      "/meshcat/replay/points/k1/scan", "/meshcat/replay/points/k1/depth"}


def test_a_folder_without_a_recording_or_a_bad_file_is_one_clear_error(tmp_path):
    with pytest.raises(SimnavError, match=f"{tmp_path}: no viz recording; expected .*{RECORDING_FILE}"):
        Recording.load(tmp_path)
    bad = tmp_path / RECORDING_FILE
    bad.write_text("not a recording")
    with pytest.raises(SimnavError, match="not a simnav viz recording"):
        Recording.load(tmp_path)
    np.savez(bad, header=np.array('{"format": "other"}'))
    with pytest.raises(SimnavError, match="not a readable simnav viz recording .*format 'other'"):
        Recording.load(bad)


def test_a_null_viewer_is_never_asked_for_anything():
    class Untouchable:
        def __getattr__(self, name):
            raise AssertionError(f"the null viewer's observer read sim.{name}")

    observer = VizObserver([NullViewer()])
    assert observer.sinks == [] and observer.web_url is None
    observer.attach(Untouchable())
    for _ in range(100):
        observer.observe([])
    observer.finish()


def test_a_plain_mission_records_without_loading_meshcat(tmp_path):
    """Every `simnav mission` runs the recorder: it must not import meshcat (or start anything)."""
    code = (
        "import sys, pathlib\n"
        "from simnav.mission.mission import MissionSettings, mission_robot, run_mission\n"
        "from simnav.robot import load_robot\n"
        "from simnav.world import load_world\n"
        "from simnav.viz import mission_observers\n"
        f"out = pathlib.Path({str(tmp_path)!r})\n"
        "s = MissionSettings(duration_s=1.0, seed=1, sim={'pedestrians': 1, 'wanderers': 0})\n"
        "with mission_observers(live=False, url=None, html_path=None, out_dir=out, rate_hz=10.0) as obs:\n"
        "    assert all(o.web_url is None for o in obs)\n"
        "    run_mission(load_world('polygonal'), mission_robot(load_robot('giraff'), s), s, out, observers=obs)\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('meshcat', 'zmq', 'tornado')))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"
    rec = Recording.load(tmp_path)
    assert len(rec.times_s) == 11 and rec.scene.paths is not None and len(rec.routes) >= 1
    assert np.isfinite(rec.est_xyyaw).all() and (rec.ptg >= 0).any()


def test_viz_config_refuses_nonsense():
    with pytest.raises(SimnavError, match="rate_hz"):
        VizConfig(rate_hz=0.0)
    with pytest.raises(SimnavError, match="points_rate_hz"):
        VizConfig(rate_hz=1.0, points_rate_hz=2.0)
    assert VizConfig().rate_hz == 10.0 and math.isclose(VizConfig().points_rate_hz, 1.0)
