"""Watch a simnav Gymnasium env live in meshcat."""

from __future__ import annotations

import contextlib
from typing import Any

import gymnasium as gym

from simnav.viz.config import VizConfig
from simnav.viz.observer import VizObserver


class MeshcatEnvWrapper(gym.Wrapper):
    """Streams a simnav env (``simnav/OfficeNav-v0``, ...) to meshcat while it runs: the building, the robot's
    prisms, people, other robots, doors and the sensor readings, at ``config.rate_hz`` simulated Hz.

    The meshcat server is started (or the one at ``url``, a ZMQ url, is joined) when the wrapper is made, and shut
    down by :meth:`close`. Observations, rewards and infos pass through unchanged::

        env = MeshcatEnvWrapper(gym.make("simnav/OfficeNav-v0"))
        print(env.web_url)                    # open it in a browser
        obs, info = env.reset(seed=0)

    Args:
        env: a simnav env (possibly wrapped, e.g. by ``gym.make``'s TimeLimit).
        url: ZMQ url of a running meshcat server, or None to start one.
        config: viewer options (``rate_hz`` among them).
    """

    def __init__(self, env: gym.Env, url: str | None = None, config: VizConfig | None = None) -> None:
        super().__init__(env)
        from simnav.viz.server import meshcat_connection
        from simnav.viz.viewer import MeshcatViewer

        self.config = config or VizConfig()
        self._stack = contextlib.ExitStack()
        connection = self._stack.enter_context(meshcat_connection(url))
        self.viewer = MeshcatViewer(connection, self.config)
        self.web_url: str | None = self.viewer.web_url
        self._observer = VizObserver([self.viewer], self.config)

    def reset(self, **kwargs: Any):
        obs, info = self.env.reset(**kwargs)
        nav_env = self.env.unwrapped
        self._observer.attach(nav_env.simulator)
        self._observer.observe(nav_env.last_readings)
        return obs, info

    def step(self, action):
        result = self.env.step(action)
        self._observer.observe(self.env.unwrapped.last_readings)
        return result

    def close(self) -> None:
        try:
            self._observer.finish()
        finally:
            self._stack.close()
            super().close()
