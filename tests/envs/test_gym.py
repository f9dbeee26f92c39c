"""The Gymnasium environments (drivee2e_jax.envs.gym) on the tiny example suite."""

from __future__ import annotations

import warnings
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode

from drivee2e_jax.envs.gym import ENV_ID, DriveE2EEnv, DriveE2EVectorEnv
from drivee2e_jax.metrics.driving_score import STATUS_NAMES

TINY = str(Path(__file__).resolve().parents[2] / "drivee2e_jax" / "scenario" / "examples" / "tiny")
EPISODE_STEPS = 49  # the tiny suite's 5 s logs at dt = 0.1 s


def test_check_env_passes_without_warnings():
    env = gymnasium.make(ENV_ID, suite=TINY, split="train")
    assert isinstance(env.unwrapped, DriveE2EEnv)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    assert [str(w.message) for w in caught] == []
    # one episode to its end: truncated at the end of the log, with its scores
    u = env.unwrapped
    obs, info = u.reset(seed=3, options={"index": 1})
    assert info["scenario_index"] == 1 and obs in u.observation_space
    steps, terminated, truncated = 0, False, False
    while not (terminated or truncated) and steps < 100:
        obs, reward, terminated, truncated, info = u.step(np.array([0.3, 0.0, 0.0], np.float32))
        assert isinstance(reward, float) and obs in u.observation_space
        steps += 1
    assert steps == EPISODE_STEPS and truncated and not terminated
    ep = info["scores"]
    assert 0 < ep["route_completion"] <= 100 and 0 <= ep["driving_score"] <= ep["route_completion"]
    assert STATUS_NAMES[ep["status"]] == "Failed - TickRuntime" and ep["length"] == EPISODE_STEPS
    env.close()


def test_vector_env_steps_autoresets_and_reports_episode_scores():
    envs = gymnasium.make_vec(ENV_ID, num_envs=2, vectorization_mode="vector_entry_point", suite=TINY, split="train")
    assert isinstance(envs, DriveE2EVectorEnv)
    assert envs.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert envs.action_space.shape == (2, 3) and envs.single_action_space.shape == (3,)
    assert set(envs.single_observation_space.spaces) >= {"ego", "route", "agents", "lanes", "signal_state"}
    assert "privileged" not in envs.single_observation_space.spaces
    obs, info = envs.reset(seed=0, options={"index": [0, 1]})
    assert obs in envs.observation_space
    np.testing.assert_array_equal(info["scenario_index"], [0, 1])
    envs.action_space.seed(0)
    ended = None
    for t in range(EPISODE_STEPS + 2):
        actions = envs.action_space.sample()
        obs, reward, terminated, truncated, info = envs.step(actions)
        assert obs in envs.observation_space
        assert reward.shape == (2,) and np.isfinite(reward).all()
        for key in ("collision", "red_light", "outside_lanes", "route_completion", "progress_m"):
            assert info[key].shape == (2,) and info[f"_{key}"].all()
        done = terminated | truncated
        if t < EPISODE_STEPS - 1:
            assert not done.any() and "scores" not in info
        if done.any():
            ended = (t, obs, info, done)
            break
    t, obs, info, done = ended
    assert t == EPISODE_STEPS - 1 and done.all()
    np.testing.assert_array_equal(info["_scores"], done)
    ep = info["scores"]
    assert ((ep["route_completion"] > 0) & (ep["route_completion"] <= 100)).all()
    assert ((ep["driving_score"] >= 0) & (ep["driving_score"] <= ep["route_completion"] + 1e-4)).all()
    assert [STATUS_NAMES[s] for s in ep["status"]] == ["Failed - TickRuntime"] * 2
    np.testing.assert_array_equal(ep["scenario_index"], [0, 1])
    np.testing.assert_array_equal(ep["length"], [EPISODE_STEPS] * 2)
    # SAME_STEP: the returned observation starts the next episode, the last one is in final_obs
    assert info["_final_obs"].all() and info["final_obs"][0] in envs.single_observation_space
    assert info["final_info"]["_scores"].all()
    assert not np.allclose(info["final_obs"][0]["gps"], obs["gps"][0]) or not np.allclose(
        info["final_obs"][1]["gps"], obs["gps"][1])
    # the next step runs the new episodes and reports no episode end
    obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
    assert not (terminated | truncated).any() and "scores" not in info
    assert np.isfinite(info["progress_m"]).all()
    envs.close()


def test_bad_arguments():
    with pytest.raises(ValueError, match="action"):
        DriveE2EVectorEnv(TINY, "train", 1, action="steering-wheel")
    with pytest.raises(ValueError, match="num_envs"):
        DriveE2EVectorEnv(TINY, "train", 0)


def test_vector_env_meets_gymnasium_conventions():
    """Gymnasium has no checker for vector envs: its single-env checks that carry
    over (space limits, batched spaces, seeded determinism) and its own vector
    wrapper RecordEpisodeStatistics (what CleanRL reads) on ours."""
    from gymnasium.utils.env_checker import check_space_limit, data_equivalence
    from gymnasium.vector.utils import batch_space
    from gymnasium.wrappers.vector import RecordEpisodeStatistics

    envs = gymnasium.make_vec(ENV_ID, num_envs=2, vectorization_mode="vector_entry_point", suite=TINY, split="train")
    check_space_limit(envs.single_observation_space, "observation")
    check_space_limit(envs.single_action_space, "action")
    assert envs.observation_space == batch_space(envs.single_observation_space, 2)
    assert envs.action_space == batch_space(envs.single_action_space, 2)
    envs.action_space.seed(1)
    actions = [envs.action_space.sample() for _ in range(3)]
    runs = []
    for _ in range(2):  # same seed, same actions -> same data
        out = [envs.reset(seed=7)]
        out += [envs.step(a) for a in actions]
        runs.append(out)
    assert data_equivalence(runs[0], runs[1])
    stats = RecordEpisodeStatistics(envs)
    stats.reset(seed=0)
    for _ in range(EPISODE_STEPS):
        obs, reward, terminated, truncated, info = stats.step(envs.action_space.sample())
    assert (terminated | truncated).all() and info["_episode"].all() and "scores" in info
    np.testing.assert_array_equal(info["episode"]["l"], [EPISODE_STEPS] * 2)
    stats.close()


def test_the_env_turns_on_the_persistent_compile_cache(monkeypatch):
    """Issue 39 item 9: building an env enables JAX's persistent cache, as
    every drivee2e command does, so a new process takes the env's compiled
    step from disk (measured in docs/performance.md, "Host policies":
    experiments/perf/gym_start.py, 18.7 s of XLA compiling in every process
    before, 2.8 s in the second after). A subprocess check took 27 s of CI."""
    from drivee2e_jax.envs import gym as gym_module

    calls = []
    monkeypatch.setattr(gym_module.compile_cache, "enable", lambda: calls.append(1))
    DriveE2EVectorEnv(TINY, "train", num_envs=2)
    DriveE2EEnv(TINY, "train")
    assert len(calls) == 2
