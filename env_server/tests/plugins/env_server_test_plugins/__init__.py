"""Deliberately broken Tasks, registered only for the tests through a real entry point.

tests/plugins is put on the server's PYTHONPATH; its dist-info declares these in the
`env_server.envs` group, exactly as a user package would.
"""

from __future__ import annotations

import time
from typing import Any

import gymnasium
import numpy as np

from env_server.task import Objective, StepOutcome, Task


class FaultyTask(Task):
    """A 1-D walk that raises on action 3 (a simulated simulator crash)."""

    description = "test only: raises RuntimeError on action 3"
    objectives = (Objective("steps", "-1 per step", -1.0, -1.0),)
    max_episode_steps = 50
    info_keys = ("position",)

    def __init__(self) -> None:
        self.observation_space = gymnasium.spaces.Box(-100.0, 100.0, (1,), np.float32)
        self.action_space = gymnasium.spaces.Discrete(4)
        self._x = 0

    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        self._x = 0
        return np.zeros(1, np.float32), {"position": self._x}

    def step(self, action: Any) -> StepOutcome:
        if action == 3:
            raise RuntimeError("the simulator exploded")
        self._x += int(action) - 1
        return StepOutcome(
            np.array([self._x], np.float32), np.array([-1.0], np.float32), False, False, {"position": self._x}
        )


class BadRewardTask(FaultyTask):
    """Declares one objective but returns a reward with three entries."""

    description = "test only: returns 3 reward entries for 1 objective"

    def step(self, action: Any) -> StepOutcome:
        out = super().step(action)
        out.reward = np.zeros(3, np.float32)
        return out


class DictObsTask(Task):
    """A nested Dict observation: {"pos": Box(2), "goal": {"index": Discrete(3)}}."""

    description = "test only: nested Dict observation"
    objectives = (Objective("progress", "+1 per step toward nothing", 1.0, 1.0),)

    def __init__(self) -> None:
        self.observation_space = gymnasium.spaces.Dict(
            {
                "pos": gymnasium.spaces.Box(-10.0, 10.0, (2,), np.float64),
                "goal": gymnasium.spaces.Dict({"index": gymnasium.spaces.Discrete(3)}),
            }
        )
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self._pos = np.zeros(2)
        self._goal = 0

    def _obs(self) -> dict[str, Any]:
        return {"pos": self._pos.copy(), "goal": {"index": self._goal}}

    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        self._pos = np.zeros(2)
        self._goal = int(np.random.default_rng(seed).integers(3))
        return self._obs(), {}

    def step(self, action: Any) -> StepOutcome:
        self._pos = self._pos + action
        return StepOutcome(self._obs(), np.ones(1, np.float32), False, False)


class SlowBuildTask(Task):
    """Takes `build_seconds` to construct; its observation is how many instances this
    process has constructed so far, so a test can tell whether a Make kept building."""

    description = "test only: slow constructor; observes the process's construction count"
    objectives = (Objective("none", "always 0", 0.0, 0.0),)
    constructed = 0

    def __init__(self, build_seconds: float = 0.05) -> None:
        time.sleep(build_seconds)
        SlowBuildTask.constructed += 1
        self.observation_space = gymnasium.spaces.Box(0.0, np.inf, (1,), np.float64)
        self.action_space = gymnasium.spaces.Discrete(2)

    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        return np.array([SlowBuildTask.constructed], np.float64), {}

    def step(self, action: Any) -> StepOutcome:
        return StepOutcome(np.array([SlowBuildTask.constructed], np.float64), np.zeros(1, np.float32), False, False)
