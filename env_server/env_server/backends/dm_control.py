"""`dmc:<domain>-<task>`: a dm_control suite task as a Task.

Observations are the suite's observation dict flattened in spec order to one float32
vector. dm_control's episode end maps to gymnasium's split: discount == 0 is
`terminated`, any other last step (the suite's time limit) is `truncated`.
Seeding: a seeded reset installs np.random.RandomState(seed) as the task's RNG, which
is exactly what suite.load(task_kwargs={"random": seed}) does at construction
(RandomState takes seeds below 2**32; a larger one fails the Reset as INTERNAL).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from env_server.render import FreeCamera, MujocoView
from env_server.task import Objective, StepOutcome, Task

#: The view of a domain without cameras (dm_control's own free-camera default).
_FREE = FreeCamera(lookat=(0.0, 0.0, 0.5), distance=3.0, azimuth=90.0, elevation=-20.0)


def physics_view(physics: Any, default: str | None, current: MujocoView | None = None) -> MujocoView:
    """Frames of a dm_control Physics (its MuJoCo model and data) from its named cameras;
    "" means `default`, else the first camera, else a free camera. `current` is reused
    while it still shows this physics (composer recompiles its physics on reset).

    This is what dm_control's `physics.render(height, width, camera_id)` draws, through
    render.MujocoView so that every task in a server shares one OpenGL stack.
    """
    model, data = physics.model.ptr, physics.data.ptr
    if current is not None:
        if current.model is model and current.data is data:
            return current
        current.close()
    first = physics.model.id2name(0, "camera") if physics.model.ncam else None
    return MujocoView(model, data, default or first or _FREE)


class DmcTask(Task):
    """suite.load(domain, task, task_kwargs=kwargs); one objective "reward" in [0, 1]."""

    description = "any dm_control suite task: dmc:<domain>-<task>, flattened float32 observation"
    # Every Control Suite reward lies in the unit interval (Tassa et al. 2018, section 2).
    objectives: tuple[Objective, ...] = (Objective("reward", "the suite reward", 0.0, 1.0),)
    #: The camera Render's "" means: None = the domain's first camera (a free camera when it has none).
    default_camera: str | None = None

    def __init__(self, domain: str, task: str, environment_kwargs: dict | None = None, **task_kwargs: Any) -> None:
        import gymnasium
        from dm_control import suite

        self.env = suite.load(domain, task, task_kwargs=task_kwargs or None, environment_kwargs=environment_kwargs)
        self._obs_specs = list(self.env.observation_spec().items())
        sizes = [int(np.prod(spec.shape)) for _, spec in self._obs_specs]
        self._slices = []
        start = 0
        for size in sizes:
            self._slices.append(slice(start, start + size))
            start += size
        self._obs = np.zeros(start, np.float32)
        self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (start,), np.float32)
        aspec = self.env.action_spec()
        self.action_space = gymnasium.spaces.Box(
            aspec.minimum.astype(np.float32), aspec.maximum.astype(np.float32), aspec.shape, np.float32
        )
        step_limit = getattr(self.env, "_step_limit", math.inf)
        self.max_episode_steps = int(round(step_limit)) if math.isfinite(step_limit) else None
        self._reward = np.zeros(len(self.objectives), np.float32)
        self._view = physics_view(self.env.physics, self.default_camera)
        self.cameras = self._view.cameras
        self.render_fps = 1.0 / self.env.control_timestep()

    def _flatten(self, observation: dict[str, Any]) -> np.ndarray:
        for (key, _), sl in zip(self._obs_specs, self._slices):
            self._obs[sl] = np.asarray(observation[key], np.float32).reshape(-1)
        return self._obs

    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self.env.task._random = np.random.RandomState(seed)
        ts = self.env.reset()
        return self._flatten(ts.observation), {}

    def reward(self, time_step: Any, action: np.ndarray) -> np.ndarray:
        """The vector reward for one step; subclasses add objectives here."""
        self._reward[0] = time_step.reward
        return self._reward

    def step(self, action: Any) -> StepOutcome:
        ts = self.env.step(action)
        last = ts.last()
        terminated = last and ts.discount == 0.0
        return StepOutcome(self._flatten(ts.observation), self.reward(ts, action), terminated, last and not terminated)

    def render(self, width: int, height: int, camera: str) -> np.ndarray:
        self._view = physics_view(self.env.physics, self.default_camera, self._view)
        return self._view.render(width, height, camera)

    def close(self) -> None:
        self._view.close()
        self.env.close()
