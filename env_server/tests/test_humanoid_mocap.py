"""humanoid-mocap: exact replay of a shipped (synthetic) clip scores ~1 on all five objectives;
the zero action terminates early; the eq. 8 scalarization option."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from env_server.envs.humanoid_mocap import CHANNELS, HumanoidMocap, scalarized
from env_server.mocap import ACTIONS_KEY, SHIPPED_CLIPS


@pytest.fixture(scope="module")
def env() -> HumanoidMocap:
    task = HumanoidMocap()
    yield task
    task.close()


@pytest.fixture(scope="module")
def clips() -> dict[str, np.ndarray]:
    with h5py.File(SHIPPED_CLIPS, "r") as f:
        assert "NOT CMU" in f.attrs["note"]
        return {k: f[k][ACTIONS_KEY][:] for k in f.keys()}


def test_spaces_and_objectives(env: HumanoidMocap) -> None:
    assert [o.name for o in env.objectives] == ["com", "vel", "app", "quat", "trunc"]
    assert env.action_space.shape == (56,)
    assert env.observation_space.shape == (sum(s.stop - s.start for s in env.obs_slices.values()),)
    # Reference frames for the next 5 steps are observed.
    assert (
        env.obs_slices["walker/reference_rel_joints"].stop - env.obs_slices["walker/reference_rel_joints"].start
        == 5 * 56
    )
    assert [c[1] for c in CHANNELS] == [o.name for o in env.objectives]


@pytest.mark.parametrize("seed", [0, 1])
def test_exact_replay_scores_maximum(env: HumanoidMocap, clips, seed: int) -> None:
    obs, info = env.reset(seed=seed)
    actions = clips[env.clip_id][info["clip_step"] :]
    assert len(actions) >= 10
    rewards = []
    for a in actions:
        out = env.step(a.astype(np.float32))
        rewards.append(out.reward.copy())
        if out.terminated or out.truncated:
            break
    rewards = np.array(rewards)
    assert not out.terminated and out.truncated  # ran to the clip's end
    assert rewards.min() > 0.98, rewards.min(axis=0)
    assert out.info["termination_error"] < 0.01


def test_zero_action_terminates_early(env: HumanoidMocap) -> None:
    done = 0
    for seed in range(40):
        _, info = env.reset(seed=seed)
        if info["clip_step"] > 30:
            continue  # start early in a clip, so that there is motion left to miss
        for t in range(200):
            out = env.step(np.zeros(56, np.float32))
            if out.terminated or out.truncated:
                break
        assert out.terminated and not out.truncated, (seed, env.clip_id, info, out.info)
        assert out.info["termination_error"] > 0.3 and out.reward[4] == 0.0  # trunc at its floor
        assert out.info["clip_step"] < 100 - 6
        done += 1
        if done == 2:
            break
    assert done == 2


def test_channels_are_unweighted_and_eq8(env: HumanoidMocap) -> None:
    env.reset(seed=3)
    rng = np.random.default_rng(0)
    out = env.step(rng.uniform(-0.2, 0.2, 56).astype(np.float32))
    channels = env.task.last_reward_channels
    for i, (key, _, weight) in enumerate(CHANNELS):
        assert out.reward[i] == pytest.approx(np.clip(channels[key] / weight, 0, 1), rel=1e-5)
    # eq. 8 with lambda = 1 is exactly dm_control's comic reward.
    assert scalarized(out.reward, 1.0) == pytest.approx(sum(channels.values()), rel=1e-5)


def test_scalarized_option() -> None:
    task = HumanoidMocap(scalarized_lambda=0.3)
    assert [o.name for o in task.objectives] == ["reward"]
    vec = HumanoidMocap()
    task.reset(seed=5)
    vec.reset(seed=5)
    a = np.full(56, 0.05, np.float32)
    for _ in range(3):
        s, v = task.step(a), vec.step(a)
        assert s.reward.shape == (1,)
        assert s.reward[0] == pytest.approx(scalarized(v.reward, 0.3), rel=1e-5)


def test_dict_observation_carries_the_flat_values_by_name(env: HumanoidMocap) -> None:
    named = HumanoidMocap(dict_observation=True)
    try:
        flat, _ = env.reset(seed=3)
        obs, _ = named.reset(seed=3)
        assert named.observation_space.contains(obs)
        assert list(obs) == [k for k, s in env.obs_slices.items() if s.stop > s.start]
        assert any("reference" in k for k in obs) and any("reference" not in k for k in obs)
        np.testing.assert_array_equal(np.concatenate(list(obs.values())), flat)
    finally:
        named.close()
