"""A short mission watched in a real headless Chromium: live through a meshcat server, then as the HTML replay.

The browser connects before the mission starts, so every frame is streamed to it. Checks: the scene tree in the
page holds the robot's prisms, the people and the navigator's layers at the poses the simulation recorded; the
screenshot has the robot's band colours and the people's red, and loses them when just those two nodes are hidden
(so the pixels are theirs; obstacle points, drawn in the band colours too, stay). The replay must open with the
network switched off. Screenshots are kept in runs/test-artifacts/viz/.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from simnav.io import read_tum
from simnav.mission.mission import MissionReport, MissionSettings, mission_robot, run_mission
from simnav.robot import load_robot
from simnav.viz import Recording, mission_observers, style
from simnav.world import load_world
from tests.viz.conftest import color_pixels, keep_artifact

pytestmark = pytest.mark.slow

PEOPLE = 3
ROBOT_COLORS = style.BAND_COLORS[:4]  # the Giraff's four prisms
SCENE = "viewer.scene_tree.children.meshcat"


@dataclass
class Watched:
    out: Path
    report: MissionReport
    web_url: str
    messages: int


@pytest.fixture(scope="module")
def watched(chromium, tmp_path_factory):
    """A 4 s mission in the flat world with three people and another robot, watched live; the server stays up
    for the tests of this module."""
    out = tmp_path_factory.mktemp("watched")
    world, robot = load_world("flat"), load_robot("giraff")
    settings = MissionSettings(duration_s=4.0, seed=2, sim={"pedestrians": PEOPLE, "wanderers": 1})
    with mission_observers(live=True, url=None, html_path=out / "replay.html", out_dir=out, rate_hz=10.0) as obs:
        chromium.open(obs[0].web_url)
        chromium.wait_for("typeof viewer !== 'undefined' && viewer.connection && viewer.connection.readyState === 1")
        report = run_mission(world, mission_robot(robot, settings), settings, out, observers=obs)
        yield Watched(out, report, obs[0].web_url, chromium.eval("viewer.num_messages_received"))


def robot_and_people_pixels(image: np.ndarray) -> tuple[int, int]:
    robot = sum(color_pixels(image, rgb, min_saturation=0.6) for rgb in ROBOT_COLORS)
    return robot, color_pixels(image, style.PERSON_COLOR, min_saturation=0.6)


def hidden(chromium, visible: bool) -> None:
    chromium.eval(f"for (const n of ['robot', 'people']) {SCENE}.children[n].object.visible = {str(visible).lower()};"
                  " viewer.set_dirty(); true")
    time.sleep(0.5)


def node_position(chromium, *path: str) -> list[float]:
    node = SCENE + "".join(f".children[{json.dumps(p)}]" for p in path)
    return chromium.eval(f"(p => [p.x, p.y, p.z])({node}.object.position)")


def test_the_live_view_shows_the_robot_and_the_people(chromium, watched, tmp_path):
    rec = Recording.load(watched.out)
    final = rec.base_xyyaw[-1]
    # the last streamed frame has arrived: the robot stands where the simulation ended
    gt = read_tum(watched.out / "trajectory_gt.txt")
    assert np.allclose(final[:2], gt.positions_m[-1][:2], atol=1e-6)
    chromium.wait_for(f"Math.hypot({SCENE}.children.robot.object.position.x - {final[0]}, "
                      f"{SCENE}.children.robot.object.position.y - {final[1]}) < 1e-4", timeout_s=20)
    time.sleep(1.0)
    shot = chromium.screenshot(tmp_path / "live_view.png")
    hidden(chromium, False)
    control = chromium.screenshot(tmp_path / "live_view_without_robot_and_people.png")
    hidden(chromium, True)
    for name in ("live_view.png", "live_view_without_robot_and_people.png"):
        print(f"artefact: {keep_artifact(tmp_path / name)}")
    robot_px, people_px = robot_and_people_pixels(shot)
    robot_ctl, people_ctl = robot_and_people_pixels(control)  # obstacle points keep their band colours
    assert robot_px - robot_ctl >= 300 and people_px >= 150, (robot_px, robot_ctl, people_px)
    assert people_ctl <= people_px // 10, (people_ctl, people_px)


def test_the_page_holds_the_scene_the_simulation_recorded(chromium, watched):
    rec = Recording.load(watched.out)
    assert watched.messages > 100  # streamed while the mission ran (the scene itself is a few dozen commands)
    assert chromium.eval("viewer.num_messages_received") > 8 * len(rec.times_s)
    tree = chromium.eval(f"(m => Object.fromEntries(Object.entries(m.children).map(([k, v]) => "
                         f"[k, Object.keys(v.children)])))({SCENE})")
    assert tree["people"] == [f"p{i}" for i in range(PEOPLE)] and tree["robots"] == ["r0"]
    assert {"prisms", "scan", "depth"} <= set(tree["robot"])
    assert {"pose", "obstacles", "candidates", "chosen"} <= set(tree["nav"])
    prisms = chromium.eval(f"Object.keys({SCENE}.children.robot.children.prisms.children)")
    assert prisms == ["base", "pole", "camera_block", "head"]
    for i in range(PEOPLE):
        assert np.allclose(node_position(chromium, "people", f"p{i}")[:2], rec.people[-1, i, :2], atol=1e-4)
    assert np.allclose(node_position(chromium, "nav")[:2], rec.est_xyyaw[-1, :2], atol=1e-4)
    points = chromium.eval(f"{SCENE}.children.robot.children.scan.children['<object>'].object.geometry"
                           ".attributes.position.count")
    assert points > 50


def test_the_html_replay_opens_offline_and_plays_the_mission(chromium, watched, tmp_path):
    html = watched.out / "replay.html"
    text = html.read_text()
    assert "<script src=" not in text and "<link" not in text and len(text) < 3_000_000
    rec = Recording.load(watched.out)
    chromium.call("Network.enable")
    chromium.call("Network.emulateNetworkConditions", offline=True, latency=0, downloadThroughput=-1,
                  uploadThroughput=-1)
    try:
        chromium.open(html.as_uri())
        duration = chromium.wait_for("typeof viewer !== 'undefined' && viewer.animator.actions.length > 0 "
                                     "&& viewer.animator.duration")
        assert duration == pytest.approx(rec.duration_s, abs=1e-3)
        # point clouds take turns, the route shows: at the start only the first cloud, at the end only the last
        clouds = f"Object.values({SCENE}.children.replay.children.points.children).map(n => n.object.visible)"
        route = f"{SCENE}.children.replay.children.routes.children.r0.object.visible"
        chromium.eval("viewer.animator.pause(); viewer.animator.seek(0); true")
        visible = chromium.eval(clouds)
        assert len(visible) == len(rec.point_frames) >= 3 and visible[0] and not any(visible[1:])
        assert chromium.eval(route)
        # jump to the end of the replay: the robot and the people are where the mission ended
        chromium.eval(f"viewer.animator.seek({duration}); true")
        visible = chromium.eval(clouds)
        assert visible[-1] and not any(visible[:-1]) and chromium.eval(route)
        time.sleep(1.0)
        assert np.allclose(node_position(chromium, "robot")[:2], rec.base_xyyaw[-1, :2], atol=1e-3)
        assert np.allclose(node_position(chromium, "people", "p1")[:2], rec.people[-1, 1, :2], atol=1e-3)
        shot = chromium.screenshot(tmp_path / "html_replay.png")
        print(f"artefact: {keep_artifact(tmp_path / 'html_replay.png')}")
    finally:
        chromium.call("Network.emulateNetworkConditions", offline=False, latency=0, downloadThroughput=-1,
                      uploadThroughput=-1)
    robot_px, people_px = robot_and_people_pixels(shot)
    assert robot_px >= 300 and people_px >= 150, (robot_px, people_px)
