"""A plug-in package with broken and working entry points, for test_plugin_failures.py.

Kept out of tests/plugins (which every test server loads) so that only the tests about
failing plug-ins see them. Its dist-info declares, in the `env_server.envs` group:
`missing` (a module that does not exist), `not-a-task` (a function), `bad-objectives`
(strings where Objectives belong), `huge-error` (an import error with a 10000-character
message), `buggy` (a constructor with a bug), `crashy` (a
constructor that raises unless told not to) and `stepper` (a working Task that
validates its kwargs).
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np

from env_server.task import Objective, StepOutcome, Task


def not_a_task() -> None:
    """An entry point that names a function, not a Task class."""


class Stepper(Task):
    """x <- x + step_size * a; one objective, -|x|."""

    description = "test only: a walk whose step size is a kwarg in (0, 1]"
    objectives = (Objective("stay", "-|x|", -np.inf, 0.0),)
    max_episode_steps = 10

    def __init__(self, step_size: float = 0.1) -> None:
        if not 0.0 < step_size <= 1.0:
            raise ValueError(f"step_size: expected a number in (0, 1], got {step_size}")
        self.step_size = float(step_size)
        self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (1,), np.float32)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self._x = 0.0

    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        self._x = 0.0
        return np.zeros(1, np.float32), {}

    def step(self, action: Any) -> StepOutcome:
        self._x += self.step_size * float(action[0])
        return StepOutcome(np.array([self._x], np.float32), np.array([-abs(self._x)], np.float32), False, False)


class BadObjectives(Stepper):
    objectives = ("stay", "move")  # type: ignore[assignment]  (the mistake under test)


class Buggy(Stepper):
    """A bug, not a bad request: it raises ValueError with no kwargs at all."""

    description = "test only: the constructor always raises ValueError"

    def __init__(self, step_size: float = 0.1) -> None:
        np.zeros(-1)  # ValueError: negative dimensions are not allowed


class Crashy(Stepper):
    """Its simulator is 'down' unless the caller passes up=True."""

    description = "test only: the constructor raises RuntimeError unless up=True"

    def __init__(self, up: bool = False) -> None:
        if not up:
            raise RuntimeError("licence server not reachable")
        super().__init__()
