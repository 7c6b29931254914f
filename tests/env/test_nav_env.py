"""The navigation env: registration, the Gymnasium contract (check_env, seeding, pickling), vector envs, reward
terms, episode end, errors, and the 3D-PTG baseline policy."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import simnav
from simnav.env import ENV_IDS, NavEnv, PTGPolicy, rollout
from simnav.errors import ConfigError, SimnavError, UnknownNameError
from simnav.robot import load_robot

GL = os.environ.get("MUJOCO_GL") == "egl"
needs_gl = pytest.mark.skipif(not GL, reason="rendering needs OpenGL (EGL)")
QUIET_CORRIDOR = {"people": 0, "goal_max_m": 6.0}


def test_import_registers_without_loading_gymnasium():
    code = ("import sys, simnav; assert 'gymnasium' not in sys.modules; import gymnasium as gym; "
            "print(sorted(k for k in gym.registry if k.startswith('simnav/')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == str(sorted(ENV_IDS))


def test_ids_make_with_and_without_the_module_prefix():
    gym.register_envs(simnav)
    env = gym.make("simnav:simnav/CorridorNav-v0")
    assert isinstance(env.unwrapped, NavEnv) and env.spec.max_episode_steps == ENV_IDS["simnav/CorridorNav-v0"][
        "max_episode_steps"]
    assert env.unwrapped.config.world == "corridor"
    office = gym.make("simnav/OfficeNav-v0")
    assert office.unwrapped.config.world == "office" and office.observation_space["lidar"].shape == (682,)


@needs_gl
@pytest.mark.parametrize("sensors", ["lidar", "lidar+depth"])
def test_check_env_passes_without_warnings(sensors):
    env = gym.make("simnav/FlatNav-v0", render_mode="rgb_array", sensors=sensors, lidar_beams=90)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    obs, _ = env.reset(seed=1)
    assert set(obs) == ({"lidar", "goal", "velocity"} | ({"depth"} if sensors != "lidar" else set()))
    assert all(v.dtype == np.float32 for v in obs.values()) and obs["lidar"].shape == (90,)
    if sensors != "lidar":
        assert obs["depth"].shape == (120, 160) and obs["depth"].max() > 0
    frame = env.render()
    assert frame.shape == (480, 480, 3) and frame.dtype == np.uint8 and frame.std() > 0
    env.close()
    env.close()


def rollout_trace(env, seed: int, steps: int = 40) -> list:
    obs, info = env.reset(seed=seed)
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, 2)).astype(np.float32)
    trace = [(obs, info["goal_xy"])]
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        trace.append((obs, reward, terminated, info["distance_to_goal_m"], info["contacts"]))
        if terminated or truncated:
            obs, info = env.reset()
    return trace


def same(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    return bool(np.array_equal(a, b))


def test_same_seed_same_rollout_and_pickled_copies_agree():
    kwargs = {"people": 3, "robots": 1, "lidar_beams": 120}
    a, b = (gym.make("simnav/OfficeNav-v0", **kwargs) for _ in range(2))
    first, second = rollout_trace(a, seed=11), rollout_trace(b, seed=11)
    assert same(first, second)
    assert not same(first[:5], rollout_trace(a, seed=12)[:5])
    copy = pickle.loads(pickle.dumps(a))
    assert same(rollout_trace(copy, seed=11), first)
    a.close(), b.close(), copy.close()


def test_reward_terms_sum_up_and_a_wall_ends_the_episode():
    env = gym.make("simnav/CorridorNav-v0", **QUIET_CORRIDOR)
    obs, info = env.reset(seed=2)
    assert info["distance_to_goal_m"] == pytest.approx(obs["goal"][0], abs=1e-5)
    terms = ("reward_progress", "reward_time", "reward_contact", "reward_success")
    # turn left until a side wall of the 2 m wide corridor is close ahead, then drive into it
    for _ in range(300):
        ahead = obs["lidar"][len(obs["lidar"]) // 2]
        action = np.array([0.0, 1.0] if ahead > 0.25 else [1.0, 0.0], dtype=np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        assert reward == pytest.approx(sum(info[t] for t in terms))
        assert info["reward_time"] == pytest.approx(-0.1 * 0.1)
        if terminated:
            break
    assert terminated and not truncated
    assert info["collision"] and info["contacts"] == 1 and info["reward_contact"] == -10.0
    assert not info["is_success"] and info["reward_success"] == 0.0


def test_vector_envs_step_and_autoreset():
    for vectorization_mode, vector_kwargs in (("sync", {}), ("async", {"context": "spawn"})):
        envs = gym.make_vec("simnav/CorridorNav-v0", num_envs=2, vectorization_mode=vectorization_mode,
                            vector_kwargs=vector_kwargs, max_episode_steps=3, people=0, lidar_beams=60)
        obs, _ = envs.reset(seed=5)
        assert obs["lidar"].shape == (2, 60) and obs["goal"].dtype == np.float32
        first_goals = obs["goal"].copy()
        for step in range(4):
            obs, reward, terminated, truncated, info = envs.step(np.zeros((2, 2), dtype=np.float32))
            if step == 2:
                assert truncated.all() and not terminated.any()
        # NEXT_STEP autoreset: the step after the time limit starts new episodes (reward 0, a new draw)
        assert (reward == 0).all() and not truncated.any()
        assert not np.allclose(obs["goal"], first_goals)
        envs.close()


def test_ptg_policy_reaches_the_goal_in_an_easy_world():
    env = gym.make("simnav/CorridorNav-v0", **QUIET_CORRIDOR)
    policy = PTGPolicy(env)
    results = [rollout(env, policy, seed) for seed in range(3)]
    assert all(r.success and not r.collision for r in results), results
    assert all(r.final_distance_m <= 0.3 for r in results)
    env.close()


def test_bad_settings_are_one_clear_error():
    with pytest.raises(UnknownNameError, match="unknown world 'atlantis'"):
        NavEnv(world="atlantis")
    with pytest.raises(ConfigError, match="people"):
        gym.make("simnav/CorridorNav-v0", people=-1)
    with pytest.raises(ConfigError, match="control_dt_s"):
        NavEnv(world="corridor", control_dt_s=0.105)
    giraff = load_robot("giraff")
    lidar_only = giraff.model_copy(update={"sensors": giraff.sensors[:1]})
    with pytest.raises(SimnavError, match="no RGB-D camera"):
        NavEnv(world="corridor", robot=lidar_only, sensors="lidar+depth")
    with pytest.raises(UnknownNameError, match="pose source 'slam'"):
        NavEnv(world="corridor", pose_source="slam")
    env = NavEnv(world="corridor", people=0)
    with pytest.raises(SimnavError, match="reset"):
        env.step(np.zeros(2))
    env.reset(seed=0)
    with pytest.raises(SimnavError, match="2 finite numbers"):
        env.step(np.array([np.nan, 0.0]))
    with pytest.raises(SimnavError, match="unknown reset options"):
        env.reset(options={"start": 3})


def test_odometry_pose_source_measures_the_goal_from_its_estimate():
    env = gym.make("simnav/CorridorNav-v0", people=0, pose_source="wheels")
    assert [s.type for s in env.unwrapped.robot_spec.sensors] == ["lidar2d", "wheels"]
    obs, info = env.reset(seed=1)
    for _ in range(20):
        obs, _, terminated, _, info = env.step(np.array([0.6, 0.1], dtype=np.float32))
        assert not terminated
    # wheel odometry drifts a little: close to, but not exactly, the ground-truth distance
    assert obs["goal"][0] == pytest.approx(info["distance_to_goal_m"], abs=0.1)
    assert obs["goal"][0] != pytest.approx(info["distance_to_goal_m"], abs=1e-5)


def test_lidar_observation_is_range_over_max_range_capped_at_one():
    from simnav.env.nav_env import _scaled_ranges

    ranges = np.concatenate([np.random.default_rng(0).uniform(0.0, 7.0, 300), [0.0, -0.0, 5.6, np.nan]])
    ranges = ranges.astype(np.float32)
    scale = np.float32(1.0 / 5.6)
    expected = ranges * scale
    expected[ranges <= 0] = 1.0
    np.testing.assert_array_equal(_scaled_ranges(ranges, scale), np.minimum(expected, 1.0))
