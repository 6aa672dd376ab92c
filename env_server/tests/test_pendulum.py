"""pendulum: task is Pendulum-v1's own reward, action_norm is -|u|."""

from __future__ import annotations

import gymnasium
import numpy as np

from env_server.envs.pendulum import Pendulum


def test_rewards_match_pendulum_v1_and_the_action_norm() -> None:
    task = Pendulum()
    reference = gymnasium.make("Pendulum-v1")
    obs, _ = task.reset(seed=3)
    ref_obs, _ = reference.reset(seed=3)
    np.testing.assert_array_equal(obs, ref_obs)
    rng = np.random.default_rng(0)
    for _ in range(50):
        u = rng.uniform(-2, 2, size=(1,)).astype(np.float32)
        out = task.step(u)
        ref_obs, ref_reward, _, _, _ = reference.step(u)
        np.testing.assert_array_equal(out.observation, ref_obs)
        assert out.reward[0] == np.float32(ref_reward)
        assert out.reward[1] == np.float32(-abs(u[0]))
