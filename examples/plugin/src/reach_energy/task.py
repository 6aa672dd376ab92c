"""Reach and energy: move a point to x = 0.8 while spending little energy.

A one-dimensional task with two objectives that pull against each other: big actions
reach the target sooner, small ones cost less. It is the example of env_server's
"Add an env" guide (docs/adding-an-env.md), not a task of the paper.

## Observation
float32 [1]: the position x, in [-1, 1]. Each episode starts at x ~ Uniform(-1, 1).

## Action
Box(-1, 1, (1,), float32): a. The dynamics are x <- clip(x + step_size * a, -1, 1),
with step_size a constructor kwarg (default 0.1, any number in (0, 1]).

## Reward Space
0: reach, -|x - 0.8| after the move, in [-1.8, 0]
1: energy, -a^2, in [-1, 0]

Episodes never terminate; the server truncates them after 50 steps.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np

from env_server.task import Objective, StepOutcome, Task

TARGET = 0.8


class ReachEnergy(Task):
    """x <- clip(x + step_size * a, -1, 1); objectives [reach, energy]."""

    description = "example plug-in: reach x = 0.8 [reach = -|x - 0.8|, energy = -a^2], obs 1, act 1, 50 steps"
    # min and max are the exact per-step bounds: clients read them as the reward space.
    objectives = (
        Objective("reach", "-|x - 0.8| after the move", -1.8, 0.0),
        Objective("energy", "-a^2 of the action", -1.0, 0.0),
    )
    max_episode_steps = 50
    info_keys = ("x",)
    render_fps = 25.0

    def __init__(self, step_size: float = 0.1) -> None:
        # A ValueError for a bad kwarg: the server answers the caller INVALID_ARGUMENT.
        if not 0.0 < step_size <= 1.0:
            raise ValueError(f"step_size: expected a number in (0, 1], got {step_size}")
        self.step_size = float(step_size)
        self.observation_space = gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self._rng = np.random.default_rng()
        self._x = 0.0

    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        # A seed restarts the generator; without one, episodes continue its stream, so
        # a session seeded once at Make is reproducible from then on.
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        self._x = float(self._rng.uniform(-1.0, 1.0))
        return self._obs(), {"x": self._x}

    def step(self, action: Any) -> StepOutcome:
        a = float(action[0])  # the server has checked shape, dtype and bounds
        self._x = float(np.clip(self._x + self.step_size * a, -1.0, 1.0))
        reward = np.array([-abs(self._x - TARGET), -(a**2)], np.float32)
        return StepOutcome(self._obs(), reward, terminated=False, truncated=False, info={"x": self._x})

    def render(self, width: int, height: int, camera: str) -> np.ndarray:
        """A white strip for [-1, 1]: the target as a green column, x as a blue one."""
        frame = np.full((height, width, 3), 255, np.uint8)
        frame[:, self._column(TARGET, width)] = (0, 160, 0)
        frame[:, self._column(self._x, width)] = (0, 0, 255)
        return frame

    def _obs(self) -> np.ndarray:
        return np.array([self._x], np.float32)

    @staticmethod
    def _column(x: float, width: int) -> int:
        return min(width - 1, int((x + 1.0) / 2.0 * width))
