"""scripts/probe_critic.py: the tasks it rolls a checkpoint's policy out on, as env_server
makes them (a reward vector per step, one entry per objective)."""

from __future__ import annotations

import gymnasium
import numpy as np
import probe_critic
import pytest


def test_a_gym_task_has_its_scalar_reward_as_the_one_objective():
    env, plain = probe_critic.make_env("gym:Pendulum-v1"), gymnasium.make("Pendulum-v1")
    env.reset(seed=0)
    plain.reset(seed=0)
    action = np.array([0.5], dtype=np.float32)
    reward = env.step(action)[1]
    assert np.shape(reward) == (1,)
    assert reward[0] == plain.step(action)[1]


def test_an_mo_task_keeps_its_reward_vector():
    env = probe_critic.make_env("mo:deep-sea-treasure-v0")
    env.reset(seed=0)
    reward = env.step(0)[1]
    assert np.shape(reward) == (2,)


def test_another_kind_of_task_is_refused_with_what_was_asked():
    with pytest.raises(
        SystemExit,
        match=r"expected an MO-Gymnasium \(mo:\.\.\.\) or gymnasium \(gym:\.\.\.\) task, got 'dmc:cartpole-swingup'",
    ):
        probe_critic.make_env("dmc:cartpole-swingup")
