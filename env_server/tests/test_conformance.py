"""One conformance suite for every shipped env id and a few adapter ids, through the real server."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

from env_server.client import RemoteVectorEnv
from env_server.envs import REGISTRY

ENV_IDS = sorted(REGISTRY) + ["gym:Pendulum-v1", "mo:deep-sea-treasure-v0", "dmc:cartpole-swingup"]
B = 2
STEPS = 20


def _actions(space: gymnasium.spaces.Space, seed: int) -> np.ndarray:
    space.seed(seed)
    return np.stack([np.stack([space.sample() for _ in range(B)]) for _ in range(STEPS)])


def _rollout(address: str, env_id: str, seed: int, actions: np.ndarray):
    with RemoteVectorEnv(address, env_id, B, seed=seed) as env:
        first = np.array(env.reset()[0], copy=True)
        out = [env.step(a) for a in actions]
    return env.session_spec, first, out


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_conformance(address: str, env_id: str) -> None:
    with RemoteVectorEnv(address, env_id, B, seed=0) as env:
        spec = env.session_spec
        actions = _actions(spec.action_space, 0)
    names = [o.name for o in spec.objectives]
    assert names and len(set(names)) == len(names), names
    k = len(names)
    assert spec.num_envs == B
    if env_id in REGISTRY:
        assert names == [o.name for o in REGISTRY[env_id].objectives]

    spec, first, steps = _rollout(address, env_id, 7, actions)
    obs_space = spec.observation_space
    assert all(obs_space.contains(o) for o in first), (first, obs_space)
    low = np.array([o.min for o in spec.objectives]) - 1e-5
    high = np.array([o.max for o in spec.objectives]) + 1e-5
    since_reset = np.zeros(B, int)
    returns = np.zeros((B, k))
    for obs, reward, terminated, truncated, infos in steps:
        assert reward.shape == (B, k) and reward.dtype == np.float32
        assert np.all(reward >= low) and np.all(reward <= high), (reward, low, high)
        assert not np.any(terminated & truncated)
        assert all(obs_space.contains(o) for o in obs)
        since_reset += 1
        returns += reward
        done = terminated | truncated
        if done.any():
            assert infos["_server_episode"].tolist() == done.tolist()
            assert infos["_final_obs"].tolist() == done.tolist()
        else:
            assert "server_episode" not in infos and "final_obs" not in infos
        for i in np.flatnonzero(done):
            e = infos["server_episode"]
            assert e["length"][i] == since_reset[i]
            np.testing.assert_allclose(e["episode_return"][i], returns[i], rtol=1e-5, atol=1e-5)
            assert obs_space.contains(infos["final_obs"][i])
            since_reset[i] = 0
            returns[i] = 0

    # Same seed and actions -> identical observations and rewards.
    _, first_again, steps_again = _rollout(address, env_id, 7, actions)
    np.testing.assert_array_equal(first, first_again)
    for a, b in zip(steps, steps_again):
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_array_equal(a[1], b[1])


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_renders(address: str, env_id: str) -> None:
    """Every env draws a frame of the asked size that shows something (not one flat colour)."""
    with RemoteVectorEnv(address, env_id, 1, seed=0) as env:
        env.reset()
        env.step(_actions(env.session_spec.action_space, 0)[0][:1])
        frames = env.render(width=64, height=48)
        assert env.render_fps > 0
    assert frames.shape == (1, 48, 64, 3) and frames.dtype == np.uint8
    colours = np.unique(frames.reshape(-1, 3), axis=0)
    assert len(colours) >= 3 and frames.std() > 5.0, (env_id, len(colours), frames.std())
