"""`mo:<id>`: any MO-Gymnasium environment as a Task; K comes from its reward_space.

Objective names: MO-Gymnasium 1.3 envs carry no reward names, so we use an env's
`reward_names` attribute when it has one and "objective_0", "objective_1", ... in
reward_space order otherwise. Bounds come from reward_space.low/high.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from env_server.backends.gymnasium import gym_frame, with_rgb_array
from env_server.task import Objective, StepOutcome, Task


class MoGymTask(Task):
    """mo_gymnasium.make(<id>, **kwargs) with its vector reward in reward_space order."""

    description = "any MO-Gymnasium env: mo_gymnasium.make(<id>, **kwargs), vector reward from reward_space"

    def __init__(self, mo_id: str, **kwargs: Any) -> None:
        import mo_gymnasium

        self.mo_id = mo_id
        self.env = mo_gymnasium.make(mo_id, **with_rgb_array(mo_id, kwargs))
        reward_space = self.env.unwrapped.reward_space
        k = int(np.prod(reward_space.shape))
        names = getattr(self.env.unwrapped, "reward_names", None)
        if names is None or len(names) != k:
            names = [f"objective_{i}" for i in range(k)]
        low = np.broadcast_to(reward_space.low, (k,))
        high = np.broadcast_to(reward_space.high, (k,))
        self.objectives = tuple(
            Objective(str(n), f"{mo_id} reward entry {i}", float(low[i]), float(high[i])) for i, n in enumerate(names)
        )
        self.observation_space = self.env.observation_space
        self.action_space = self.env.action_space
        spec = self.env.spec
        self.max_episode_steps = spec.max_episode_steps if spec is not None else None
        self.render_fps = float(self.env.metadata.get("render_fps") or 0.0)
        self._reward = np.zeros(k, np.float32)

    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        return self.env.reset(seed=seed)

    def step(self, action: Any) -> StepOutcome:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._reward[:] = np.asarray(reward, np.float32).reshape(-1)
        return StepOutcome(obs, self._reward, bool(terminated), bool(truncated), info)

    def render(self, width: int, height: int, camera: str) -> np.ndarray:
        return gym_frame(f"mo:{self.mo_id}", self.env, width, height)

    def close(self) -> None:
        self.env.close()
