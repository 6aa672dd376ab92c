"""Autoreset modes and server-side episode returns on DST with scripted paths.

Instance 0 goes DOWN (0.7 treasure in 1 step); instance 1 goes RIGHT, DOWN, DOWN
(8.2 treasure in 3 steps). Expected returns are summed here from the paper's rules. The
server's records arrive as gymnasium vector infos, `infos["server_episode"]` with masks.
"""

from __future__ import annotations

import grpc
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from env_server.client import FailedPreconditionError, RemoteVectorEnv
from env_server.session import Autoreset

UP, RIGHT, DOWN, LEFT = 0, 1, 2, 3
GAMMA = 0.9


def returns(step_rewards: list[list[float]]) -> tuple[np.ndarray, np.ndarray]:
    r = np.array(step_rewards, np.float64)
    return r.sum(0), sum(GAMMA**t * r[t] for t in range(len(r)))


def check_episode(infos: dict, index: int, step_rewards: list[list[float]], terminated: bool = True) -> None:
    undiscounted, discounted = returns(step_rewards)
    e = infos["server_episode"]
    assert infos["_server_episode"][index] and e["length"][index] == len(step_rewards)
    assert e["terminated"][index] == terminated and e["truncated"][index] != terminated
    np.testing.assert_allclose(e["episode_return"][index], undiscounted, rtol=1e-6)
    np.testing.assert_allclose(e["discounted_return"][index], discounted, rtol=1e-6)


def test_same_step(address: str) -> None:
    with RemoteVectorEnv(address, "dst", 2, discount=GAMMA) as env:
        assert env.session_spec.autoreset is Autoreset.SAME_STEP and env.session_spec.discount == GAMMA
        assert env.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
        env.reset()
        obs, reward, term, trunc, infos = env.step([DOWN, RIGHT])
        assert term.tolist() == [True, False] and trunc.tolist() == [False, False]
        assert obs.tolist() == [[0, 0], [0, 1]]  # instance 0 already starts its next episode
        assert infos["_final_obs"].tolist() == [True, False] and infos["final_obs"][0].tolist() == [1, 0]
        assert infos["_server_episode"].tolist() == [True, False]
        check_episode(infos, 0, [[-1, 0.7]])
        np.testing.assert_allclose(reward, [[-1, 0.7], [-1, 0]], rtol=1e-6)
        env.step([DOWN, DOWN])
        obs, reward, term, trunc, infos = env.step([RIGHT, DOWN])
        assert term.tolist() == [False, True]
        assert infos["_server_episode"].tolist() == [False, True]
        check_episode(infos, 1, [[-1, 0], [-1, 0], [-1, 8.2]])
        assert obs[1].tolist() == [0, 0] and infos["final_obs"][1].tolist() == [2, 1]


def test_next_step(address: str) -> None:
    with RemoteVectorEnv(address, "dst", 2, discount=GAMMA, autoreset="next_step") as env:
        assert env.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
        env.reset()
        obs, reward, term, _, infos = env.step([DOWN, RIGHT])
        assert term.tolist() == [True, False] and obs[0].tolist() == [1, 0]
        assert "final_obs" not in infos
        check_episode(infos, 0, [[-1, 0.7]])
        # Instance 0's action is ignored: it is reset, first obs, zero reward, not terminated.
        obs, reward, term, trunc, infos = env.step([RIGHT, DOWN])
        assert obs.tolist() == [[0, 0], [1, 1]]
        assert reward[0].tolist() == [0, 0] and term.tolist() == [False, False] and "server_episode" not in infos
        obs, reward, term, _, infos = env.step([DOWN, DOWN])
        assert term.tolist() == [True, True]
        check_episode(infos, 0, [[-1, 0.7]])  # the reset step is not part of the episode
        check_episode(infos, 1, [[-1, 0], [-1, 0], [-1, 8.2]])


def test_disabled(address: str) -> None:
    with RemoteVectorEnv(address, "dst", 2, discount=GAMMA, autoreset="disabled") as env:
        assert env.metadata["autoreset_mode"] is AutoresetMode.DISABLED
        env.reset()
        obs, _, term, _, infos = env.step([DOWN, RIGHT])
        assert term.tolist() == [True, False] and obs[0].tolist() == [1, 0]
        with pytest.raises(FailedPreconditionError) as info:
            env.step([DOWN, DOWN])
        assert info.value.code == grpc.StatusCode.FAILED_PRECONDITION
        assert "instances [0]" in info.value.message and "env_indices=[0]" in info.value.message
        obs, _ = env.reset(options={"reset_mask": np.array([True, False])})
        assert obs.tolist() == [[0, 0], [0, 1]]  # instance 1 keeps its observation
        obs, _, term, _, infos = env.step([RIGHT, DOWN])
        # The failed Step did not move instance 1: it is at (1, 1) after RIGHT, DOWN.
        assert obs.tolist() == [[0, 1], [1, 1]] and not term.any()


def test_time_limit_truncates(address: str) -> None:
    with RemoteVectorEnv(address, "dst", 1, discount=GAMMA) as env:
        assert env.session_spec.max_episode_steps == 200
        env.reset()
        for t in range(200):
            obs, _, term, trunc, infos = env.step([UP])
            assert not term[0] and trunc[0] == (t == 199)
        check_episode(infos, 0, [[-1, 0]] * 200, terminated=False)
