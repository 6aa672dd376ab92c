"""wire.StepEncoder writes exactly the bytes of the StepResponse protobuf would build."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

from env_server import wire
from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server.instances import LocalInstances
from env_server.session import Autoreset, Session, StepResult
from env_server.task import Objective, StepOutcome, Task


class Counter(Task):
    """Dict observation {pos float32 [2], tick int64 [], flags bool [3]}; episodes of 2 steps."""

    objectives = (Objective("a", ""), Objective("b", ""), Objective("c", ""))
    max_episode_steps = 2
    info_keys = ("energy",)

    def __init__(self, seed: int) -> None:
        self.observation_space = gymnasium.spaces.Dict(
            {
                "pos": gymnasium.spaces.Box(-np.inf, np.inf, (2,), np.float32),
                "tick": gymnasium.spaces.Discrete(100),
                "flags": gymnasium.spaces.Box(0, 1, (3,), np.bool_),
            }
        )
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.rng = np.random.default_rng(seed)
        self.tick = 0

    def _obs(self) -> dict:
        return {"pos": self.rng.normal(size=2), "tick": self.tick, "flags": self.rng.random(3) < 0.5}

    def reset(self, seed=None):
        self.tick = 0
        return self._obs(), {"energy": 0.0}

    def step(self, action):
        self.tick += 1
        return StepOutcome(self._obs(), self.rng.normal(size=3).astype(np.float32), False, False, {"energy": self.tick})


def reference(result: StepResult) -> pb.StepResponse:
    return pb.StepResponse(
        observation=wire.named(result.observation),
        reward=wire.tensor(result.reward),
        terminated=result.terminated.tolist(),
        truncated=result.truncated.tolist(),
        info=wire.named(result.info),
        episodes=[
            pb.EpisodeEnd(
                env_index=e.env_index,
                episode_return=e.episode_return.tolist(),
                discounted_return=e.discounted_return.tolist(),
                length=e.length,
                terminated=e.terminated,
                truncated=e.truncated,
            )
            for e in result.episodes
        ],
        final_observation=wire.named(result.final_observation),
    )


@pytest.mark.parametrize("autoreset", list(Autoreset))
@pytest.mark.parametrize("info_keys", [(), ("energy",)])
@pytest.mark.parametrize("num_envs", [1, 3])
def test_encoded_step_equals_protobuf(autoreset: Autoreset, info_keys: tuple[str, ...], num_envs: int) -> None:
    tasks = LocalInstances([Counter(i) for i in range(num_envs)])
    session = Session("counter", tasks, autoreset=autoreset, info_keys=info_keys)
    session.reset()
    encoder = wire.StepEncoder(session.leaves, session.num_envs, len(session.objectives))
    ended = 0
    for _ in range(5):
        result = session.step_actions(np.zeros((num_envs, 2), np.float32))
        ended += len(result.episodes)
        expected = reference(result)
        assert encoder.encode(result) == expected.SerializeToString()
        assert pb.StepResponse.FromString(encoder.encode(result)) == expected
        if result.episodes and autoreset is Autoreset.DISABLED:
            session.reset()
    assert ended > 0


def test_single_leaf_observation_has_no_name() -> None:
    class Flat(Counter):
        def __init__(self) -> None:
            super().__init__(0)
            self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (4,), np.float64)

        def _obs(self) -> np.ndarray:
            return self.rng.normal(size=4)

    session = Session("flat", LocalInstances([Flat(), Flat()]))
    session.reset()
    result = session.step_actions(np.zeros((2, 2), np.float32))
    encoded = wire.StepEncoder(session.leaves, 2, 3).encode(result)
    assert encoded == reference(result).SerializeToString()
    assert pb.StepResponse.FromString(encoded).observation[0].name == ""
