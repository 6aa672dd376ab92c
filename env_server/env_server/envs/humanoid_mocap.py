"""Humanoid motion-capture tracking with five reward objectives (the MO-MPO paper, appendix B.4).

dm_control's CMU humanoid (`CMUHumanoidPositionControlled`, 56 position-controlled joints) on a
flat floor tracks a reference clip with `MultiClipMocapTracking` (Hasenclever et al. 2020),
reward_type "comic", termination error threshold 0.3, reference frames for the next 5 steps
(ref_steps 1..5) in the observation. An episode starts at a random frame of a random clip
(drawn by the seed; at least `min_steps` = 10 frames from the clip's end).

Clips: `clip_path` is an HDF5 file in dm_control's mocap format. By default it is the
package's `env_server/mocap/clips/synthetic_lying.h5`: SYNTHETIC physics rollouts of the
same humanoid recorded by `env_server/tools/make_clips.py`, NOT CMU motion capture data (the
CMU database cannot be downloaded on our machines). With the real database, pass
`clip_path="/path/to/cmu_2020_dfe3e9e0.h5"` and `clip_ids=[...]` (for example the ids of
dm_control's `cmu_subsets.LOCOMOTION_SMALL`). dm_control 1.0.28's loader needs a protobuf-7
fix, applied by `env_server.mocap.patch_loader()`.

## Observation
The composer environment's observation dict (the walker's proprioception and the reference
observables for the next 5 frames), each entry flattened and concatenated in the
environment's observation-spec order, float32. The layout (key -> slice) is
`self.obs_slices`; with the default walker it has 2722 entries. With
`dict_observation=True` the same entries arrive as a Dict space of flat float32 Boxes
(empty entries dropped), so that a client can tell the reference observables
(`walker/reference_*`) from proprioception, as the paper's A.3 policy architecture needs.

## Action
Box(-1, 1, (56,), float32), mapped linearly to each position actuator's ctrlrange (the joint
range): -1 -> lower limit, +1 -> upper limit. The zero action therefore commands every joint
to the middle of its range (not the zero pose).

## Reward Space (unweighted, each in [0, 1])
0: com,   exp(-10 ||p_com - p_com_ref||^2)
1: vel,   exp(-0.1 ||qvel - qvel_ref||^2)
2: app,   exp(-40 ||p_app - p_app_ref||^2)   (5 appendages)
3: quat,  exp(-2 ||q_quat (-) q_quat_ref||^2) (body quaternions, dm_control's bounded distance)
4: trunc, 1 - eps / 0.3, eps = dm_control's termination error (0.5 mean |body-position error|
   over the tracked bodies + 0.5 mean |joint-angle error|); the paper writes eps with L1 sums
These are dm_control's "comic" reward channels with their weights (0.5*0.1, 0.5*1.0,
0.5*0.15, 0.5*0.65, 0.5) divided out.
With `scalarized_lambda=lam` the task instead has ONE objective `reward`, eq. 8:
0.5 trunc + 0.5 (0.1 com + lam vel + 0.15 app + 0.65 quat) (the VMPO baseline).

## Termination
Terminated when eps > 0.3 (dm_control's early termination, discount 0); truncated at the end
of the clip.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np

from env_server.backends.dm_control import physics_view
from env_server.task import Objective, StepOutcome, Task

#: dm_control "comic" channel -> (our objective, the weight dm_control multiplies it by).
CHANNELS = (
    ("center_of_mass", "com", 0.5 * 0.1),
    ("joints_velocity", "vel", 0.5 * 1.0),
    ("appendages", "app", 0.5 * 0.15),
    ("body_quaternions", "quat", 0.5 * 0.65),
    ("termination", "trunc", 0.5),
)
TERMINATION_THRESHOLD = 0.3
REF_STEPS = (1, 2, 3, 4, 5)
#: Render's default camera: tracks the walker from the side and above.
DEFAULT_CAMERA = "walker/side"


def scalarized(reward: np.ndarray, lam: float) -> float:
    """Paper eq. 8 from the vector [com, vel, app, quat, trunc]."""
    com, vel, app, quat, trunc = (float(x) for x in reward)
    return 0.5 * trunc + 0.5 * (0.1 * com + lam * vel + 0.15 * app + 0.65 * quat)


class HumanoidMocap(Task):
    """CMU humanoid mocap tracking; objectives [com, vel, app, quat, trunc]."""

    description = (
        "humanoid mocap tracking (paper B.4): [com, vel, app, quat, trunc], act 56; synthetic clips unless clip_path"
    )
    objectives = (
        Objective("com", "exp(-10 ||p_com - p_com_ref||^2)", 0.0, 1.0),
        Objective("vel", "exp(-0.1 ||qvel - qvel_ref||^2)", 0.0, 1.0),
        Objective("app", "exp(-40 ||p_app - p_app_ref||^2)", 0.0, 1.0),
        Objective("quat", "exp(-2 ||q_quat (-) q_quat_ref||^2)", 0.0, 1.0),
        Objective("trunc", "1 - eps / 0.3 (terminates when eps > 0.3)", 0.0, 1.0),
    )
    max_episode_steps = None  # episodes end with the clip
    info_keys = ("termination_error", "clip_step")

    def __init__(
        self,
        clip_path: str | None = None,
        clip_ids: Sequence[str] | None = None,
        scalarized_lambda: float | None = None,
        min_steps: int = 10,
        dict_observation: bool = False,
    ) -> None:
        import h5py
        from dm_control import composer
        from dm_control.locomotion import arenas, walkers
        from dm_control.locomotion.tasks.reference_pose import tracking, types

        from env_server.mocap import SHIPPED_CLIPS, patch_loader

        patch_loader()
        self.clip_path = clip_path or SHIPPED_CLIPS
        if clip_ids is None:
            with h5py.File(self.clip_path, "r") as f:
                clip_ids = sorted(f.keys())
        self.clip_ids = tuple(clip_ids)
        self.task = tracking.MultiClipMocapTracking(
            walker=walkers.CMUHumanoidPositionControlled,
            arena=arenas.Floor(),
            ref_path=self.clip_path,
            dataset=types.ClipCollection(ids=self.clip_ids),
            ref_steps=REF_STEPS,
            min_steps=min_steps,
            reward_type="comic",
            termination_error_threshold=TERMINATION_THRESHOLD,
        )
        self.env = composer.Environment(task=self.task, strip_singleton_obs_buffer_dim=True)
        spec = self.env.observation_spec()
        self.obs_slices: dict[str, slice] = {}
        start = 0
        for key, s in spec.items():
            size = int(np.prod(s.shape))
            self.obs_slices[key] = slice(start, start + size)
            start += size
        self._obs = np.zeros(start, np.float32)
        self.dict_observation = dict_observation
        if dict_observation:
            self.observation_space = gymnasium.spaces.Dict(
                [
                    (key, gymnasium.spaces.Box(-np.inf, np.inf, (sl.stop - sl.start,), np.float32))
                    for key, sl in self.obs_slices.items()
                    if sl.stop > sl.start
                ]
            )
        else:
            self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (start,), np.float32)
        aspec = self.env.action_spec()
        self._ctrl_low = aspec.minimum.astype(np.float64)
        self._ctrl_half = 0.5 * (aspec.maximum - aspec.minimum).astype(np.float64)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, aspec.shape, np.float32)
        self.scalarized_lambda = scalarized_lambda
        if scalarized_lambda is not None:
            self.objectives = (
                Objective(
                    "reward",
                    f"eq. 8: 0.5 trunc + 0.5 (0.1 com + {scalarized_lambda:g} vel + 0.15 app + 0.65 quat)",
                    0.0,
                    0.5 + 0.5 * (0.1 + max(scalarized_lambda, 0.0) + 0.15 + 0.65),
                ),
            )
        self._vector = np.zeros(len(CHANNELS), np.float32)
        self._reward = np.zeros(len(self.objectives), np.float32)
        self._view = physics_view(self.env.physics, DEFAULT_CAMERA)
        self.cameras = self._view.cameras
        self.render_fps = 1.0 / self.env.control_timestep()

    # -- helpers --------------------------------------------------------------------------
    def ctrl_from_action(self, action: np.ndarray) -> np.ndarray:
        return self._ctrl_low + (np.clip(action, -1.0, 1.0) + 1.0) * self._ctrl_half

    def action_from_ctrl(self, ctrl: np.ndarray) -> np.ndarray:
        return np.clip((np.asarray(ctrl) - self._ctrl_low) / self._ctrl_half - 1.0, -1.0, 1.0).astype(np.float32)

    @property
    def clip_step(self) -> int:
        """Index of the current reference frame in the current clip."""
        return int(self.task._time_step)

    @property
    def clip_id(self) -> str:
        return self.clip_ids[self.task._current_clip_index]

    def _flatten(self, observation: dict[str, Any]) -> Any:
        for key, sl in self.obs_slices.items():
            self._obs[sl] = np.asarray(observation[key], np.float32).reshape(-1)
        if self.dict_observation:
            return {key: self._obs[sl] for key, sl in self.obs_slices.items() if sl.stop > sl.start}
        return self._obs

    def _info(self) -> dict[str, Any]:
        return {"termination_error": float(self.task._termination_error), "clip_step": self.clip_step}

    # -- Task -----------------------------------------------------------------------------
    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self.env.random_state.seed(seed % 2**32)
        ts = self.env.reset()
        return self._flatten(ts.observation), self._info()

    def step(self, action: Any) -> StepOutcome:
        ts = self.env.step(self.ctrl_from_action(np.asarray(action, np.float64)))
        channels = self.task.last_reward_channels
        for i, (key, _, weight) in enumerate(CHANNELS):
            self._vector[i] = channels[key] / weight
        # Rounding can put a channel a hair outside [0, 1] (e.g. trunc at error 0).
        np.clip(self._vector, 0.0, 1.0, out=self._vector)
        if self.scalarized_lambda is None:
            self._reward[:] = self._vector
        else:
            self._reward[0] = scalarized(self._vector, self.scalarized_lambda)
        last = ts.last()
        terminated = bool(last and ts.discount == 0.0)
        return StepOutcome(
            self._flatten(ts.observation), self._reward, terminated, last and not terminated, self._info()
        )

    def render(self, width: int, height: int, camera: str) -> np.ndarray:
        self._view = physics_view(self.env.physics, DEFAULT_CAMERA, self._view)
        return self._view.render(width, height, camera)

    def close(self) -> None:
        self._view.close()
        self.env.close()
