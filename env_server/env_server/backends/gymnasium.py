"""`gym:<id>`: any gymnasium environment as a Task with one objective, "reward", and with
`action_norm_objective = true` a second, "action_norm" = -||a||_2 of the action sent,
declared a closed form so that a learner may compute it instead of learning it."""

from __future__ import annotations

import inspect
from typing import Any

import gymnasium
import numpy as np

from env_server import gl, render
from env_server.errors import FailedPrecondition, InvalidArgument, quote
from env_server.kwarg_types import check_kwarg_types
from env_server.task import ClosedForm, Objective, StepOutcome, Task, action_norm_bounds

#: The gym: kwarg that adds the "action_norm" objective (handled here, not by gymnasium).
ACTION_NORM_OBJECTIVE = "action_norm_objective"


def with_rgb_array(gym_id: str, kwargs: dict[str, Any]) -> dict[str, Any]:
    """`kwargs` plus render_mode="rgb_array" when the env supports it and none was asked for.

    gymnasium fixes an env's render mode at construction; "rgb_array" draws only when
    render() is called, so asking for it costs nothing per step.
    """
    import gymnasium
    from gymnasium.envs.registration import load_env_creator

    if "render_mode" in kwargs:
        return kwargs
    entry = gymnasium.spec(gym_id).entry_point
    creator = load_env_creator(entry) if isinstance(entry, str) else entry
    modes = getattr(creator, "metadata", {}).get("render_modes", [])
    return {**kwargs, "render_mode": "rgb_array"} if "rgb_array" in modes else kwargs


def gym_frame(env_id: str, env: Any, width: int, height: int) -> np.ndarray:
    """A gymnasium env's own rgb_array frame, resampled to width x height.

    gymnasium draws at the env's own size (for MuJoCo envs, the `width`/`height` Make
    kwargs; pygame envs have a fixed size), so the frame is fitted to the size asked for.
    """
    if env.render_mode != "rgb_array":
        raise FailedPrecondition(
            f"env {env_id}: made with render_mode={env.render_mode!r}; Render needs 'rgb_array' "
            "(leave render_mode out of the Make kwargs)"
        )
    if hasattr(env.unwrapped, "mujoco_renderer"):
        gl.require()
    frame = env.render()
    if frame is None:
        raise FailedPrecondition(f"env {env_id}: render() returned no frame")
    return render.resize(frame, width, height)


def check_gym_kwarg_types(gym_id: str, kwargs: dict[str, Any]) -> None:
    """check_kwarg_types against the gymnasium env class's constructor: gymnasium stores a
    keyword of the wrong type and the env fails on its first step instead."""
    import gymnasium
    from gymnasium.envs.registration import load_env_creator

    entry = gymnasium.spec(gym_id).entry_point
    creator = load_env_creator(entry) if isinstance(entry, str) else entry
    try:
        params = inspect.signature(creator).parameters
    except (TypeError, ValueError):
        return
    check_kwarg_types(gym_id, params, kwargs)


class GymTask(Task):
    """gymnasium.make(<id>, **kwargs); the scalar reward becomes K=1 "reward".

    gymnasium's own TimeLimit (from the env's registration) stays in place and its
    truncation passes through; the session reports the same limit in the spec.
    """

    description = "any gymnasium env: gymnasium.make(<id>, **kwargs), scalar reward as K=1"
    objectives = (Objective("reward", "the env's scalar reward"),)

    def __init__(self, gym_id: str, **kwargs: Any) -> None:
        action_norm = kwargs.pop(ACTION_NORM_OBJECTIVE, False)
        if not isinstance(action_norm, bool):
            raise InvalidArgument(
                f"kwargs_json.{ACTION_NORM_OBJECTIVE}: expected true or false, got {quote(action_norm)}"
            )
        if action_norm and any(o.name == "action_norm" for o in type(self).objectives):
            raise InvalidArgument(f"kwargs_json.{ACTION_NORM_OBJECTIVE}: this env already has an action_norm objective")
        check_gym_kwarg_types(gym_id, kwargs)
        self.gym_id = gym_id
        self.env = gymnasium.make(gym_id, **with_rgb_array(gym_id, kwargs))
        self.observation_space = self.env.observation_space
        self.action_space = self.env.action_space
        spec = self.env.spec
        self.max_episode_steps = spec.max_episode_steps if spec is not None else None
        self.render_fps = float(self.env.metadata.get("render_fps") or 0.0)
        self._action_norm = action_norm
        if action_norm:
            self.objectives = (*type(self).objectives, self._action_norm_objective())
        self._reward = np.zeros(len(self.objectives), np.float32)

    def _action_norm_objective(self) -> Objective:
        space = self.action_space
        finite = isinstance(space, gymnasium.spaces.Box) and np.all(np.isfinite(space.low) & np.isfinite(space.high))
        if not finite:
            self.env.close()
            raise InvalidArgument(
                f"kwargs_json.{ACTION_NORM_OBJECTIVE}: expected an env with a bounded Box action space, "
                f"gym:{self.gym_id} has {space}"
            )
        low, high = action_norm_bounds(space)
        return Objective("action_norm", "-||a||_2 of the action sent", low, high, closed_form=ClosedForm.ACTION_NORM)

    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        return self.env.reset(seed=seed)

    def step(self, action: Any) -> StepOutcome:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._reward[0] = reward
        if self._action_norm:
            self._reward[-1] = -np.linalg.norm(np.asarray(action, np.float64).ravel())
        return StepOutcome(obs, self._reward, bool(terminated), bool(truncated), info)

    def render(self, width: int, height: int, camera: str) -> np.ndarray:
        return gym_frame(f"gym:{self.gym_id}", self.env, width, height)

    def close(self) -> None:
        self.env.close()
