"""The Python client and the `--list` CLI."""

from __future__ import annotations

import subprocess
import sys
import warnings

import grpc
import gymnasium
import numpy as np
import pytest
from conftest import server_env
from gymnasium.utils.env_checker import check_env

from env_server.client import InvalidArgumentError, NotFoundError, RemoteEnv, RemoteVectorEnv, list_envs
from env_server.envs import REGISTRY


def test_remote_env_is_a_gymnasium_env_with_vector_reward(address: str) -> None:
    env = RemoteEnv(address, "dst")
    try:
        assert isinstance(env, gymnasium.Env)
        assert env.objective_names == ("time", "treasure")
        assert env.reward_space.shape == (2,)
        np.testing.assert_allclose(env.reward_space.low, [-1, 0])
        np.testing.assert_allclose(env.reward_space.high, [-1, 23.7], rtol=1e-6)
        assert env.action_space == gymnasium.spaces.Discrete(4)
        obs, info = env.reset(seed=3)
        assert obs.tolist() == [0, 0] and info == {}
        obs, reward, terminated, truncated, info = env.step(2)
        assert reward.shape == (2,) and reward.dtype == np.float32
        np.testing.assert_allclose(reward, [-1, 0.7], rtol=1e-6)
        assert terminated and not truncated and info["server_episode"]["length"] == 1
        assert obs.tolist() == [1, 0]  # autoreset is off: the caller resets
    finally:
        env.close()


def test_a_refused_step_leaves_the_remote_env_usable(address: str) -> None:
    """Steps ride a StepStream, which a refused action ends; the next step opens another
    on the same session, and the episode goes on where it was."""
    env = RemoteEnv(address, "dst")
    try:
        env.reset(seed=0)
        env.step(1)  # right
        with pytest.raises(InvalidArgumentError) as info:
            env.step(7)
        assert "action" in info.value.message and "7" in info.value.message
        env.step(2)  # down
        obs, reward, terminated, _, info = env.step(2)  # down onto the 8.2 treasure
        assert obs.tolist() == [2, 1] and terminated and info["server_episode"]["length"] == 3
        np.testing.assert_allclose(reward, [-1, 8.2], rtol=1e-6)
    finally:
        env.close()


def _run_episode(env: gymnasium.Env, actions: list[int]) -> dict:
    env.reset(seed=0)
    for action in actions:
        _, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return info
    raise AssertionError("the episode did not end")


def test_gymnasium_record_episode_statistics_wraps_the_remote_env(address: str) -> None:
    env = gymnasium.wrappers.RecordEpisodeStatistics(RemoteEnv(address, "dst"))
    try:
        info = _run_episode(env, [1, 2, 2])  # right, then down onto the 8.2 treasure
        server = info["server_episode"]
        assert info["episode"]["l"] == server["length"] == 3
        np.testing.assert_allclose(info["episode"]["r"], server["episode_return"], rtol=1e-6)
        np.testing.assert_allclose(server["episode_return"], [-3, 8.2], rtol=1e-6)
        assert len(env.return_queue) == 1
    finally:
        env.close()


def test_mo_gymnasium_record_episode_statistics_wraps_the_remote_env(address: str) -> None:
    from mo_gymnasium.wrappers import MORecordEpisodeStatistics

    env = MORecordEpisodeStatistics(RemoteEnv(address, "dst", discount=0.9), gamma=0.9)
    try:
        info = _run_episode(env, [1, 2, 2])
        server = info["server_episode"]
        np.testing.assert_allclose(info["episode"]["r"], server["episode_return"], rtol=1e-6)
        np.testing.assert_allclose(info["episode"]["dr"], server["discounted_return"], rtol=1e-5)
        assert info["episode"]["l"] == server["length"]
    finally:
        env.close()


@pytest.mark.parametrize("env_id", ["dst", "humanoid-run"])
def test_check_env(address: str, env_id: str) -> None:
    """gymnasium's checker accepts the vector reward (it only warns that it is not a scalar)."""
    env = RemoteEnv(address, env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env, skip_render_check=True)
    env.close()


def test_remote_vector_env_round_trip(address: str) -> None:
    with RemoteVectorEnv(address, "dmc:cartpole-swingup", 3, seed=5) as env:
        assert env.objective_names == ("reward",)
        obs, infos = env.reset()
        assert obs.shape == (3, 5) and obs.dtype == np.float32 and infos == {}
        obs, reward, terminated, truncated, infos = env.step(np.zeros((3, 1)))
        assert reward.shape == (3, 1) and terminated.shape == (3,) and infos == {}
    with pytest.raises(NotFoundError) as info:
        RemoteVectorEnv(address, "no-such-env", 1)
    assert info.value.code == grpc.StatusCode.NOT_FOUND


def test_list_envs_client(address: str) -> None:
    envs = {env_id: [o.name for o in objectives] for env_id, _, objectives in list_envs(address)}
    for env_id, cls in REGISTRY.items():
        assert envs[env_id] == [o.name for o in cls.objectives]


def test_cli_list() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "env_server", "--list"], capture_output=True, text=True, env=server_env(), check=True
    ).stdout
    for env_id, cls in REGISTRY.items():
        assert any(line.startswith(f"{env_id}  ") for line in out.splitlines()), env_id
        for objective in cls.objectives:
            assert f"    {objective.name}: " in out
    for pattern in ("gym:<gymnasium id>", "mo:<MO-Gymnasium id>", "dmc:<domain>-<task>"):
        assert pattern in out
    assert "faulty  " in out  # entry-point envs are listed too
    # A declared closed form is listed; none is the default and not shown.
    assert "    action_norm: -||u||_2 of the torque [-2, 0], closed_form = action_norm\n" in out
    assert "    task: Pendulum-v1's reward [-16.2736, 0]\n" in out


def test_dict_observation_round_trip(address: str) -> None:
    with RemoteVectorEnv(address, "dict-obs", 2, seed=1) as env:
        space = env.single_observation_space
        assert isinstance(space, gymnasium.spaces.Dict)
        # gymnasium sorts a plain dict's keys; the wire keeps the task's (sorted) order.
        assert list(space.spaces) == ["goal", "pos"] and space["goal"]["index"] == gymnasium.spaces.Discrete(3)
        obs, _ = env.reset()
        assert env.observation_space.contains(obs)
        assert obs["pos"].shape == (2, 2) and obs["pos"].dtype == np.float64
        assert obs["goal"]["index"].shape == (2,) and obs["goal"]["index"].dtype == np.int64
        expected_goals = [int(np.random.default_rng(1 + i).integers(3)) for i in range(2)]
        assert obs["goal"]["index"].tolist() == expected_goals
        obs, *_ = env.step(np.array([[0.5, -0.25], [1.0, 1.0]], np.float32))
        assert obs["pos"].tolist() == [[0.5, -0.25], [1.0, 1.0]]
        obs, _ = env.reset(options={"reset_mask": np.array([False, True])})  # instance 0 keeps its leaves
        assert obs["pos"].tolist() == [[0.5, -0.25], [0.0, 0.0]] and env.observation_space.contains(obs)


def test_record_video(address, tmp_path) -> None:
    """gymnasium's RecordVideo records a RemoteEnv made with render_mode="rgb_array"."""
    import imageio_ffmpeg
    from gymnasium.wrappers import RecordVideo

    env = RemoteEnv(address, "dst", render_mode="rgb_array", render_width=64, render_height=48, render_fps=10)
    assert env.metadata["render_fps"] == 10 and RemoteEnv.metadata["render_fps"] == 30
    env = RecordVideo(env, str(tmp_path / "videos"), episode_trigger=lambda episode: True, disable_logger=True)
    env.reset(seed=0)
    for action in (1, 2, 2):  # right, down, down: the 8.2 treasure in 3 steps
        _, _, terminated, truncated, _ = env.step(action)
    assert terminated
    env.close()
    (video,) = (tmp_path / "videos").glob("*.mp4")
    probe = subprocess.run(
        [imageio_ffmpeg.get_ffmpeg_exe(), "-i", str(video), "-f", "rawvideo", "-pix_fmt", "rgb24", "-"],
        capture_output=True,
        check=True,
    )
    assert len(probe.stdout) == 4 * 48 * 64 * 3  # the reset frame and one per step
