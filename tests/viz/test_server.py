"""The meshcat server process and the pipelined connection: what a browser's websocket receives, clean shutdown,
joining a server by URL, and a live view that skips frames instead of waiting for a stalled server."""

from __future__ import annotations

import os
import signal
import socket
import time
from urllib.parse import urlparse

import numpy as np
import pytest
import umsgpack

from simnav.errors import SimnavError
from simnav.viz import MeshcatConnection, MeshcatServer, MeshcatViewer, VizConfig, meshcat_connection
from simnav.viz.commands import set_transform
from simnav.viz.frame import SceneInfo, VizFrame
from simnav.world import load_world


def port_open(url: str) -> bool:
    parsed = urlparse(url)
    with socket.socket() as s:
        s.settimeout(1.0)
        return s.connect_ex((parsed.hostname, parsed.port)) == 0


def websocket_messages(web_url: str) -> list[dict]:
    """What a browser receives on connecting: the server replays its scene tree (read until 2 s of silence)."""
    from websockets.sync.client import connect

    parsed = urlparse(web_url)
    out = []
    with connect(f"ws://{parsed.hostname}:{parsed.port}/", open_timeout=10) as ws:
        try:
            while True:
                out.append(umsgpack.unpackb(ws.recv(timeout=2.0)))
        except TimeoutError:
            return out


def test_commands_reach_a_browser_and_the_server_stops_cleanly():
    server = MeshcatServer()
    try:
        assert server.running and server.web_url.startswith("http://127.0.0.1:") and port_open(server.web_url)
        with MeshcatConnection(server.zmq_url) as connection:
            assert connection.web_url == server.web_url
            poses = [np.eye(4) for _ in range(50)]
            for i, T in enumerate(poses):
                T[:3, 3] = [i, 2.0 * i, 0.5]
            assert connection.send(set_transform(f"/meshcat/people/p{i}", T) for i, T in enumerate(poses)) == 50
            connection.flush()
            assert connection.pending == 0
            # a second client joins the same server by its ZMQ URL
            with MeshcatConnection(server.zmq_url) as other:
                assert other.web_url == server.web_url
        messages = websocket_messages(server.web_url)
        by_path = {m["path"]: m for m in messages}
        assert by_path["/meshcat/people/p7"]["type"] == "set_transform"
        assert np.allclose(np.array(by_path["/meshcat/people/p7"]["matrix"]).reshape(4, 4).T[:3, 3], [7, 14, 0.5])
    finally:
        server.close()
    assert server.process.returncode is not None and not server.log_path.exists()
    assert not port_open(server.web_url)
    server.close()  # twice is fine


def test_the_server_is_stopped_when_the_block_fails():
    with pytest.raises(RuntimeError, match="boom"), meshcat_connection() as connection:
        url = connection.web_url
        assert port_open(url)
        raise RuntimeError("boom")
    assert not port_open(url)


def test_joining_a_url_where_no_server_answers_is_one_clear_error():
    with socket.socket() as s:  # a free port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    started = time.monotonic()
    with pytest.raises(SimnavError, match=f"no server answers at tcp://127.0.0.1:{port}"):
        MeshcatConnection(f"tcp://127.0.0.1:{port}", connect_timeout_s=0.5)
    assert time.monotonic() - started < 5.0
    with pytest.raises(SimnavError, match="expected a ZMQ URL"):
        MeshcatConnection("not a url", connect_timeout_s=0.5)


def test_a_stalled_server_makes_the_viewer_skip_frames_not_wait():
    world = load_world("corridor")
    from simnav.robot import load_robot

    scene = SceneInfo(world, load_robot("giraff"), people=3, robots=0)
    frame = VizFrame(0.0, np.eye(3), np.zeros((3, 3)), np.zeros((0, 3)), np.zeros(0))
    with MeshcatServer() as server, MeshcatConnection(server.zmq_url, timeout_s=5.0) as connection:
        viewer = MeshcatViewer(connection, VizConfig(max_pending=20))
        viewer.show(scene)
        os.kill(server.process.pid, signal.SIGSTOP)
        try:
            started = time.monotonic()
            for _ in range(50):
                viewer.draw(frame)
            elapsed = time.monotonic() - started
        finally:
            os.kill(server.process.pid, signal.SIGCONT)
        assert viewer.drawn >= 1 and viewer.dropped >= 40 and elapsed < 2.0
        connection.flush()
        assert connection.pending == 0


def test_a_simulator_alone_streams_to_the_browser():
    """No navigator (a Gymnasium env's case): the robot, people and lidar still reach a browser's websocket."""
    from simnav.robot import load_robot
    from simnav.sim import Simulator
    from simnav.viz import VizObserver

    with Simulator(load_world("flat"), load_robot("giraff"), seed=2) as sim, meshcat_connection() as connection:
        viewer = MeshcatViewer(connection)
        observer = VizObserver([viewer])
        observer.attach(sim)
        for _ in range(10):
            observer.observe(sim.step(0.2, 0.0))
        observer.finish()
        assert viewer.drawn == 6 and viewer.dropped == 0 and connection.pending == 0
        x, y, _ = sim.pose_xy_yaw
        messages = websocket_messages(connection.web_url)
    by_path = {m["path"]: m for m in messages}
    robot = np.array(by_path["/meshcat/robot"]["matrix"]).reshape(4, 4).T
    assert np.allclose(robot[:2, 3], [x, y], atol=1e-6)
    assert {"/meshcat/people/p0", "/meshcat/people/p1", "/meshcat/robot/scan"} <= set(by_path)
    assert "/meshcat/nav/obstacles" not in by_path


def test_a_gymnasium_env_streams_to_the_browser_and_closes_its_server():
    import gymnasium as gym

    import simnav  # noqa: F401  (registers the envs)
    from simnav.viz import MeshcatEnvWrapper

    env = MeshcatEnvWrapper(gym.make("simnav/FlatNav-v0", people=2, robots=0))
    try:
        obs, _ = env.reset(seed=4)
        for _ in range(10):  # 1 s at the env's 10 Hz
            obs, reward, terminated, truncated, _ = env.step(np.array([0.5, 0.0], dtype=np.float32))
        assert isinstance(reward, float) and "lidar" in obs
        assert env.viewer.drawn >= 9 and env.viewer.dropped == 0
        x, y, _ = env.unwrapped.simulator.pose_xy_yaw
        env.viewer.connection.flush()
        messages = websocket_messages(env.web_url)
    finally:
        env.close()
    by_path = {m["path"]: m for m in messages}
    robot = np.array(by_path["/meshcat/robot"]["matrix"]).reshape(4, 4).T
    assert np.allclose(robot[:2, 3], [x, y], atol=1e-6)
    assert {"/meshcat/people/p0", "/meshcat/people/p1", "/meshcat/robot/scan"} <= set(by_path)
    assert not port_open(env.web_url)
