"""Pendulum swing-up with an action-norm objective: a small continuous two-objective task.

gymnasium's Pendulum-v1 (200 steps, torque in [-2, 2]) with its reward as `task` and the
paper's humanoid-run penalty, -||a||_2 (appendix B.3), as `action_norm`. Not a task of the
paper: it is the CPU-sized check that Gaussian MO-MPO trades the two off as epsilon does.

## Observation
float32 [3]: cos(theta), sin(theta), angular velocity.

## Action
Box(-2, 2, (1,), float32): the torque.

## Reward Space
0: task, Pendulum-v1's reward -(theta^2 + 0.1 thetadot^2 + 0.001 u^2), in [-16.3, 0]
1: action_norm, -||u||_2 = -|u|, in [-2, 0]
"""

from __future__ import annotations

from typing import Any

from env_server.backends.gymnasium import GymTask
from env_server.task import ClosedForm, Objective, StepOutcome


class Pendulum(GymTask):
    """Pendulum-v1, objectives [task, action_norm]."""

    description = "gymnasium Pendulum-v1 with [task, action_norm = -||u||_2], obs 3, act 1 in [-2, 2], 200 steps"
    objectives = (
        Objective("task", "Pendulum-v1's reward", -16.2736044, 0.0),
        Objective("action_norm", "-||u||_2 of the torque", -2.0, 0.0, closed_form=ClosedForm.ACTION_NORM),
    )
    max_episode_steps = 200

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("Pendulum-v1", **kwargs)

    def step(self, action: Any) -> StepOutcome:
        out = super().step(action)
        self._reward[1] = -abs(float(action[0]))
        return out
