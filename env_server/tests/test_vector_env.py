"""RemoteVectorEnv as a gymnasium VectorEnv, checked against gymnasium's own vector env.

Remote "gym:Pendulum-v1" and a local `gymnasium.make_vec("Pendulum-v1")` (SyncVectorEnv)
get the same seeds and actions, so everything gymnasium defines (spaces, observations,
rewards, autoreset, the `_key`-masked infos, partial resets, its vector wrappers) must
come out the same on both sides.
"""

from __future__ import annotations

import subprocess
import sys

import gymnasium
import numpy as np
import pytest
from conftest import server_env
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers import vector as wrappers

from env_server.client import RemoteEnv, RemoteVectorEnv, register
from env_server.envs import REGISTRY

B = 2
STEPS = 205  # past Pendulum's 200-step time limit


def _local(mode: AutoresetMode) -> gymnasium.vector.VectorEnv:
    return gymnasium.make_vec("Pendulum-v1", B, vectorization_mode="sync", vector_kwargs={"autoreset_mode": mode})


def _actions(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-2, 2, (STEPS, B, 1)).astype(np.float32)


def _without_server_records(infos: dict) -> dict:
    return {k: v for k, v in infos.items() if k not in ("server_episode", "_server_episode")}


@pytest.mark.parametrize("mode", [AutoresetMode.SAME_STEP, AutoresetMode.NEXT_STEP])
def test_steps_as_gymnasiums_sync_vector_env(address: str, mode: AutoresetMode) -> None:
    local = _local(mode)
    with RemoteVectorEnv(address, "gym:Pendulum-v1", B, autoreset=mode) as remote:
        assert isinstance(remote, gymnasium.vector.VectorEnv) and remote.num_envs == B
        assert remote.metadata["autoreset_mode"] is mode
        assert remote.single_observation_space == local.single_observation_space
        assert remote.single_action_space == local.single_action_space
        assert remote.observation_space == local.observation_space
        assert remote.action_space == local.action_space
        assert remote.reward_space.shape == (1,)
        obs, infos = remote.reset(seed=5)
        local_obs, local_infos = local.reset(seed=5)
        np.testing.assert_array_equal(obs, local_obs)
        assert infos == local_infos == {}
        ends = 0
        for action in _actions(0):
            obs, reward, terminated, truncated, infos = remote.step(action)
            local_obs, local_reward, local_terminated, local_truncated, local_infos = local.step(action)
            assert remote.observation_space.contains(obs)
            np.testing.assert_array_equal(obs, local_obs)
            assert reward.shape == (B, 1) and reward.dtype == np.float32
            np.testing.assert_allclose(reward[:, 0], local_reward, rtol=1e-6)
            assert terminated.tolist() == local_terminated.tolist()
            assert truncated.tolist() == local_truncated.tolist()
            assert data_equivalence(_without_server_records(infos), local_infos), (infos, local_infos)
            ends += int(truncated.sum())
        assert ends == B  # the comparison covered an autoreset
    local.close()


def test_runs_under_gymnasiums_vector_wrappers(address: str) -> None:
    """Episode statistics and observation normalization over the remote env equal the same
    wrappers over gymnasium's own vector env; TransformReward turns the [B, 1] reward into [B].
    gymnasium's observation wrappers refuse SAME_STEP autoreset (final_obs would escape them)."""
    local = wrappers.NormalizeObservation(wrappers.RecordEpisodeStatistics(_local(AutoresetMode.NEXT_STEP)))
    remote_env = RemoteVectorEnv(address, "gym:Pendulum-v1", B, autoreset="next_step")
    remote_stats = wrappers.RecordEpisodeStatistics(wrappers.TransformReward(remote_env, lambda r: r[:, 0]))
    remote = wrappers.NormalizeObservation(remote_stats)
    try:
        np.testing.assert_allclose(remote.reset(seed=3)[0], local.reset(seed=3)[0], rtol=1e-5)
        for action in _actions(1):
            obs, _, _, truncated, infos = remote.step(action)
            local_obs, _, _, _, local_infos = local.step(action)
            np.testing.assert_allclose(obs, local_obs, rtol=1e-4, atol=1e-5)
        assert list(remote_stats.length_queue) == [200, 200]
        np.testing.assert_allclose(remote_stats.return_queue, local.env.return_queue, rtol=1e-6)
    finally:
        remote.close()
        local.close()
    assert remote_env.closed


def test_record_episode_statistics_agrees_with_the_server_record(address: str) -> None:
    stats = wrappers.RecordEpisodeStatistics(
        wrappers.TransformReward(RemoteVectorEnv(address, "pendulum", B, discount=1.0), lambda r: r.sum(axis=1))
    )
    try:
        stats.reset(seed=0)
        for action in _actions(2)[:200]:
            _, _, _, truncated, infos = stats.step(action)
        assert truncated.all() and infos["_episode"].all() and infos["_server_episode"].all()
        server = infos["server_episode"]
        np.testing.assert_allclose(infos["episode"]["r"], server["episode_return"].sum(axis=1), rtol=1e-5)
        assert infos["episode"]["l"].tolist() == server["length"].tolist() == [200, 200]
    finally:
        stats.close()


def test_mo_gymnasium_record_episode_statistics_agrees_with_the_server_record(address: str) -> None:
    """MO-Gymnasium's vector wrapper sums the [B, K] reward itself (it counts NEXT_STEP autoreset)."""
    from mo_gymnasium.wrappers.vector import MORecordEpisodeStatistics

    right, down = 1, 2
    env = MORecordEpisodeStatistics(RemoteVectorEnv(address, "dst", B, discount=0.9, autoreset="next_step"), gamma=0.9)
    try:
        env.reset(seed=0)
        _, _, terminated, _, infos = env.step([down, right])  # instance 0 takes the 0.7 treasure
        assert terminated.tolist() == [True, False] and infos["_episode"].tolist() == [True, False]
        server = infos["server_episode"]
        np.testing.assert_allclose(infos["episode"]["r"][0], server["episode_return"][0], rtol=1e-6)
        np.testing.assert_allclose(infos["episode"]["dr"][0], server["discounted_return"][0], rtol=1e-6)
        env.step([right, down])  # instance 0 resets
        _, _, terminated, _, infos = env.step([down, down])  # 0.7 again; instance 1 takes 8.2
        assert terminated.all()
        server = infos["server_episode"]
        np.testing.assert_allclose(infos["episode"]["r"], server["episode_return"], rtol=1e-6)
        assert infos["episode"]["l"].tolist() == server["length"].tolist() == [1, 3]
        np.testing.assert_allclose(server["episode_return"], [[-1, 0.7], [-3, 8.2]], rtol=1e-6)
        # Instance 1's first episode only: mo-gymnasium 1.3.2 never zeroes a finished
        # episode's discounted return, so instance 0's second "dr" adds up both episodes.
        np.testing.assert_allclose(infos["episode"]["dr"][1], server["discounted_return"][1], rtol=1e-6)
    finally:
        env.close()


def test_partial_reset_and_seeds_as_gymnasium(address: str) -> None:
    local = _local(AutoresetMode.DISABLED)
    with RemoteVectorEnv(address, "gym:Pendulum-v1", B, autoreset="disabled") as remote:
        for envs in (remote, local):
            envs.reset(seed=10)
            envs.step(_actions(3)[0])
        mask = np.array([False, True])
        obs, _ = remote.reset(seed=10, options={"reset_mask": mask})
        np.testing.assert_array_equal(obs, local.reset(seed=10, options={"reset_mask": mask})[0])
        obs, _ = remote.reset(seed=[None, 99], options={"reset_mask": mask})
        np.testing.assert_array_equal(obs, local.reset(seed=[None, 99], options={"reset_mask": mask})[0])
        np.testing.assert_array_equal(remote.reset(seed=[7, 8])[0], local.reset(seed=[7, 8])[0])
    local.close()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"options": {"reset_mask": np.array([1, 0])}}, "options['reset_mask']: expected bool [2] (num_envs) with at"),
        ({"options": {"reset_mask": np.zeros(2, bool)}}, "got bool [2] [False, False]"),
        ({"options": {"reset_mask": np.ones(3, bool)}}, "got bool [3] [True, True, True]"),
        ({"options": {"difficulty": 2}}, "options: expected at most the key 'reset_mask', got also ['difficulty']"),
        ({"seed": [1, 2, 3]}, "seed: expected None, an int or 2 seeds (one per instance), got 3"),
        (
            {"seed": [1, None]},
            "or None for all of them (the server seeds a Reset's instances all or none), got [1, None]",
        ),
    ],
)
def test_bad_reset_arguments_name_the_field(address: str, kwargs: dict, message: str) -> None:
    with RemoteVectorEnv(address, "dst", B) as env:
        env.reset()
        with pytest.raises(ValueError) as info:
            env.reset(**kwargs)
    assert message in str(info.value)


def test_bad_autoreset_names_the_field(address: str) -> None:
    with pytest.raises(ValueError) as info:
        RemoteVectorEnv(address, "dst", B, autoreset="sometimes")
    assert (
        str(info.value)
        == "autoreset: expected an Autoreset or one of ['same_step', 'next_step', 'disabled'], got 'sometimes'"
    )


def test_gymnasium_make_and_make_vec_build_remote_envs(address: str) -> None:
    assert all(f"env_server/{env_id}" in gymnasium.registry for env_id in REGISTRY)
    env = gymnasium.make("env_server/dst", address=address)
    try:
        assert isinstance(env.unwrapped, RemoteEnv) and env.spec.id == "env_server/dst"
        env.reset(seed=0)
        _, reward, terminated, _, _ = env.step(2)  # down onto the 0.7 treasure
        assert terminated and reward.tolist() == pytest.approx([-1, 0.7])
    finally:
        env.close()
    envs = gymnasium.make_vec("env_server/dst", num_envs=3, address=address, autoreset="next_step")
    try:
        assert isinstance(envs, RemoteVectorEnv) and envs.num_envs == 3 and envs.spec.id == "env_server/dst"
        assert envs.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
        assert envs.reset(seed=0)[0].shape == (3, 2)
    finally:
        envs.close()


def test_register_names_a_prefix_id(address: str) -> None:
    with pytest.raises(ValueError) as info:
        register("gym:Pendulum-v1")
    assert str(info.value).startswith("name: expected a gymnasium env name without ':' or '/'")
    assert register("gym:Pendulum-v1", name="Pendulum-v1") == "env_server/Pendulum-v1"
    envs = gymnasium.make_vec("env_server/Pendulum-v1", num_envs=2, address=address)
    try:
        assert envs.reward_space.shape == (1,) and envs.single_action_space.shape == (1,)
    finally:
        envs.close()
    with pytest.raises(ValueError) as info:
        register("mo:deep-sea-treasure-v0", name="Pendulum-v1")
    assert (
        str(info.value)
        == "name: env_server/Pendulum-v1 is registered for env id 'gym:Pendulum-v1', got 'mo:deep-sea-treasure-v0'"
    )


def test_gymnasium_imports_the_client_for_a_module_qualified_id(address: str) -> None:
    """gymnasium 1.x has no plug-in discovery: a fresh process that has not imported
    env_server names the module in the id, and gymnasium imports it."""
    code = (
        "import gymnasium, sys; assert 'env_server.client' not in sys.modules; "
        f"envs = gymnasium.make_vec('env_server.client:env_server/dst', num_envs=2, address={address!r}); "
        "print(type(envs).__name__, envs.num_envs); envs.close()"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=server_env(), check=True)
    assert out.stdout.split() == ["RemoteVectorEnv", "2"]
