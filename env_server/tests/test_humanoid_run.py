"""humanoid-run rewards match their definitions, through the server at B=1 and B=8."""

from __future__ import annotations

import numpy as np
import pytest
from dm_control import suite

from env_server.client import RemoteVectorEnv

STEPS = 15


@pytest.mark.parametrize("num_envs", [1, 8])
def test_rewards_match_definitions(address: str, num_envs: int) -> None:
    seed = 11
    rng = np.random.default_rng(3)
    actions = rng.uniform(-1, 1, (STEPS, num_envs, 21)).astype(np.float32)
    with RemoteVectorEnv(address, "humanoid-run", num_envs, seed=seed) as env:
        assert env.session_spec.max_episode_steps == 1000
        assert env.single_observation_space.shape == (67,)
        assert env.single_action_space.shape == (21,)
        obs0, _ = env.reset()
        got = [env.step(a) for a in actions]
    rewards = np.stack([g[1] for g in got])  # [T, B, 2]
    np.testing.assert_allclose(rewards[..., 1], -np.linalg.norm(actions, axis=-1), rtol=1e-6)
    assert not any(g[2].any() or g[3].any() for g in got)

    # An independently built dm_control env per instance, seeded with seed + i at construction.
    for i in {0, num_envs - 1}:
        ref = suite.load("humanoid", "run", task_kwargs={"random": seed + i})
        ts = ref.reset()
        flat = np.concatenate([np.asarray(v, np.float32).ravel() for v in ts.observation.values()])
        np.testing.assert_array_equal(obs0[i], flat)
        for t in range(STEPS):
            ts = ref.step(actions[t, i])
            assert rewards[t, i, 0] == np.float32(ts.reward)
            flat = np.concatenate([np.asarray(v, np.float32).ravel() for v in ts.observation.values()])
            np.testing.assert_array_equal(got[t][0][i], flat)
