"""`gym:<id>`: any gymnasium environment as a Task with one objective, "reward"."""

from __future__ import annotations

from typing import Any

import numpy as np

from env_server.task import Objective, StepOutcome, Task


class GymTask(Task):
    """gymnasium.make(<id>, **kwargs); the scalar reward becomes K=1 "reward".

    gymnasium's own TimeLimit (from the env's registration) stays in place and its
    truncation passes through; the session reports the same limit in the spec.
    """

    description = "any gymnasium env: gymnasium.make(<id>, **kwargs), scalar reward as K=1"
    objectives = (Objective("reward", "the env's scalar reward"),)

    def __init__(self, gym_id: str, **kwargs: Any) -> None:
        import gymnasium

        self.env = gymnasium.make(gym_id, **kwargs)
        self.observation_space = self.env.observation_space
        self.action_space = self.env.action_space
        spec = self.env.spec
        self.max_episode_steps = spec.max_episode_steps if spec is not None else None
        self._reward = np.zeros(1, np.float32)

    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        return self.env.reset(seed=seed)

    def step(self, action: Any) -> StepOutcome:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._reward[0] = reward
        return StepOutcome(obs, self._reward, bool(terminated), bool(truncated), info)

    def close(self) -> None:
        self.env.close()
