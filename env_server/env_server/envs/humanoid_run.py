"""dm_control humanoid run with an action-norm objective (the MO-MPO paper, appendix B.3).

Observation: the suite's six observation entries (joint_angles 21, head_height 1,
extremities 12, torso_vertical 3, com_velocity 3, velocity 27) flattened in spec order
to float32 [67]. Action: Box(-1, 1, (21,), float32). Episodes last 1000 steps and end
by truncation (the suite's time limit, discount 1).

## Reward Space
0: task, the suite's humanoid run reward, in [0, 1]
1: action_norm, -||a||_2, in [-sqrt(21), 0]

## Source
dm_control suite `humanoid`/`run` (Tassa et al. 2018).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from env_server.backends.dm_control import DmcTask
from env_server.task import ClosedForm, Objective


class HumanoidRun(DmcTask):
    """Humanoid run, objectives [task, action_norm]."""

    description = "dm_control humanoid run (paper B.3): [task, action_norm], obs 67, act 21, 1000 steps"
    objectives = (
        Objective("task", "dm_control humanoid run reward", 0.0, 1.0),
        Objective("action_norm", "-||a||_2 of the action", -math.sqrt(21.0), 0.0, closed_form=ClosedForm.ACTION_NORM),
    )
    max_episode_steps = 1000
    # Tracks the body from the side, so a run shows as motion across the frame.
    default_camera = "side"

    def __init__(self, **task_kwargs: Any) -> None:
        # The instance's max_episode_steps comes from the suite's time limit (25 s at 0.025 s
        # per step = 1000 by default, or whatever a `time_limit` kwarg makes it).
        super().__init__("humanoid", "run", **task_kwargs)

    def reward(self, time_step: Any, action: np.ndarray) -> np.ndarray:
        self._reward[0] = time_step.reward
        self._reward[1] = -np.linalg.norm(action)
        return self._reward
