"""Shared Shadow Hand machinery for shadow-touch, shadow-turn and shadow-orient (paper B.2).

The hand is the gymnasium-robotics Shadow Dexterous Hand with 92 touch sensors
(`gymnasium_robotics/envs/assets/hand/manipulate_block_touch_sensors.xml`): 24 joints,
20 position actuators, timestep 0.002 s, stepped 20 substeps per control step (25 Hz,
gymnasium-robotics' own rate). The asset's block and its target are removed and each task
adds its own object with MuJoCo's MjSpec editing; the model is compiled once per Task
instance and reset with mj_resetData.

## Observation (the first 63 entries, shared by the three tasks)
[0:24]   joint angles (qpos of the 24 hand joints, asset order WRJ1, WRJ0, FFJ3..THJ0), rad
[24:48]  joint velocities, rad/s
[48:63]  fingertip touch, 3 channels per fingertip in the order ff, mf, rf, lf, th:
         [normal, tangential_x, tangential_y] in newtons.
         normal = the sum of the fingertip's 5 MuJoCo touch sensors (`robot0:TS_<f>tip_*`);
         this is the paper's 4x4 grid summed to 1x1, but MuJoCo touch sensors only measure
         normal force, and the asset has 5 pads, not 16.
         tangential_x / tangential_y = the net contact force on the distal phalanx's
         collision geom, from mj_contactForce, along the distal body's x axis (across the
         finger) and z axis (along the finger). The pad normal is the body's y axis.
Task-specific entries follow (see each task).

## Action
Box(-1, 1, (20,), float32), mapped linearly to each position actuator's ctrlrange
(-1 -> lower limit, +1 -> upper limit).
"""

from __future__ import annotations

import abc
import importlib.util
import math
import os
from typing import Any

import gymnasium
import mujoco
import numpy as np

from env_server.render import FreeCamera, MujocoView
from env_server.task import Objective, StepOutcome, Task

FINGERS = ("ff", "mf", "rf", "lf", "th")
PADS = ("front_left", "front_right", "back_left", "back_right", "tip")
N_SUBSTEPS = 20  # 20 x 0.002 s = 0.04 s per control step (25 Hz)
N_HAND_OBS = 63
#: Success threshold of shadow-touch (paper: "greater than 5N").
TOUCH_SUCCESS_N = 5.0
#: Pain acceptability sigmoid(lambda1 * (-m + lambda2)), lambda = [2, 2] (paper eq. 7).
PAIN_LAMBDA = (2.0, 2.0)
#: Render's default view: the palm, the fingers and the object above them, from the fingertips' side.
VIEW = FreeCamera(lookat=(0.98, 0.85, 0.2), distance=0.4, azimuth=180.0, elevation=-30.0)


def hand_asset_path() -> str:
    # find_spec locates the package without importing it: gymnasium_robotics' __init__ registers
    # every env and prints a deprecation notice on stdout, which the server must not emit.
    spec = importlib.util.find_spec("gymnasium_robotics")
    assert spec is not None and spec.submodule_search_locations, "gymnasium-robotics is not installed"
    return os.path.join(
        spec.submodule_search_locations[0], "envs", "assets", "hand", "manipulate_block_touch_sensors.xml"
    )


def hand_spec() -> mujoco.MjSpec:
    """The touch-sensor hand asset with the block and target removed."""
    spec = mujoco.MjSpec.from_file(hand_asset_path())
    for name in ("object", "target"):
        spec.detach_body(spec.body(name))  # mujoco 3.3.2 API (newer versions: spec.delete)
    return spec


def pain(impact: float) -> float:
    """Paper eqs. 6-7: -(1 - sigmoid(2 * (-m + 2))) * m, with m the (non-negative) impact force."""
    l1, l2 = PAIN_LAMBDA
    z = l1 * (-impact + l2)
    acceptability = 1.0 / (1.0 + math.exp(-z)) if z >= 0 else math.exp(z) / (1.0 + math.exp(z))
    return -(1.0 - acceptability) * impact


class ShadowHandTask(Task):
    """Base: builds the model, maps actions, computes the 63-entry hand observation.

    Subclasses implement `_edit(spec)` (add the object), `_extra_obs_size`,
    `_reset_object(rng)`, `_extra_obs(out)` and `_reward()`.
    """

    _extra_obs_size = 0
    #: Render's default camera.
    view = VIEW
    render_fps = 1.0 / (N_SUBSTEPS * 0.002)  # 25 Hz control

    def __init__(self) -> None:
        spec = hand_spec()
        self._edit(spec)
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        assert m.nu == 20 and m.nq >= 24
        self._ctrl_low = m.actuator_ctrlrange[:, 0].copy()
        self._ctrl_half = 0.5 * (m.actuator_ctrlrange[:, 1] - m.actuator_ctrlrange[:, 0])
        hand_joints = [m.joint(i) for i in range(m.njnt) if m.joint(i).name.startswith("robot0:")]
        assert len(hand_joints) == 24
        self._hand_qpos = np.array([j.qposadr[0] for j in hand_joints])
        self._hand_qvel = np.array([j.dofadr[0] for j in hand_joints])
        self._tip_sensors = np.array(
            [[m.sensor_adr[m.sensor(f"robot0:TS_{f}tip_{p}").id] for p in PADS] for f in FINGERS]
        )
        self._distal_body = np.array([m.body(f"robot0:{f}distal").id for f in FINGERS])
        self._distal_geom = np.array([m.geom(f"robot0:C_{f}distal").id for f in FINGERS])
        self._geom_finger = np.full(m.ngeom, -1)
        self._geom_finger[self._distal_geom] = np.arange(len(FINGERS))
        self._obs = np.zeros(N_HAND_OBS + self._extra_obs_size, np.float32)
        self._reward = np.zeros(len(self.objectives), np.float32)
        self._force6 = np.zeros(6)
        self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, self._obs.shape, np.float32)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (m.nu,), np.float32)
        self._rng = np.random.default_rng()
        self._view = MujocoView(self.model, self.data, self.view)
        self.cameras = self._view.cameras

    # -- subclass hooks -------------------------------------------------------------------
    @abc.abstractmethod
    def _edit(self, spec: mujoco.MjSpec) -> None:
        """Add the task's object (bodies, sites, sensors) to the hand's MjSpec."""

    def _reset_object(self, rng: np.random.Generator) -> None:
        """Set the object's state in self.data after mj_resetData (before mj_forward)."""

    def _extra_obs(self, out: np.ndarray) -> None:
        """Fill the task-specific observation entries."""

    def _after_reset(self) -> None:
        """Called after mj_forward at reset (e.g. to record the object's force)."""

    @abc.abstractmethod
    def _reward_and_done(self) -> tuple[np.ndarray, bool]:
        """The step's reward vector (objective order) and whether the task succeeded."""

    # -- shared machinery -----------------------------------------------------------------
    def ctrl_from_action(self, action: np.ndarray) -> np.ndarray:
        """[-1, 1] -> actuator ctrlrange (linear)."""
        return self._ctrl_low + (np.clip(action, -1.0, 1.0) + 1.0) * self._ctrl_half

    def action_from_ctrl(self, ctrl: np.ndarray) -> np.ndarray:
        """Inverse of ctrl_from_action (for scripted controllers)."""
        return np.clip((np.asarray(ctrl) - self._ctrl_low) / self._ctrl_half - 1.0, -1, 1).astype(np.float32)

    def fingertip_touch(self) -> np.ndarray:
        """[5, 3]: per fingertip [normal (touch sensors), tangential x, tangential y]."""
        m, d = self.model, self.data
        out = np.zeros((len(FINGERS), 3))
        out[:, 0] = d.sensordata[self._tip_sensors].sum(axis=1)
        for c in range(d.ncon):
            con = d.contact[c]
            f1, f2 = self._geom_finger[con.geom1], self._geom_finger[con.geom2]
            if f1 < 0 and f2 < 0:
                continue
            mujoco.mj_contactForce(m, d, c, self._force6)
            # Force of geom1 on geom2, in the contact frame (rows of `frame` are its axes).
            f_world = con.frame.reshape(3, 3).T @ self._force6[:3]
            for finger, sign in ((f1, -1.0), (f2, 1.0)):
                if finger >= 0:
                    r = d.xmat[self._distal_body[finger]].reshape(3, 3)
                    local = r.T @ (sign * f_world)
                    out[finger, 1] += local[0]
                    out[finger, 2] += local[2]
        return out

    def _observe(self) -> np.ndarray:
        d = self.data
        self._obs[0:24] = d.qpos[self._hand_qpos]
        self._obs[24:48] = d.qvel[self._hand_qvel]
        self._obs[48:63] = self.fingertip_touch().reshape(-1)
        self._extra_obs(self._obs[N_HAND_OBS:])
        return self._obs

    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        mujoco.mj_resetData(self.model, self.data)
        self._reset_object(self._rng)
        mujoco.mj_forward(self.model, self.data)
        self._after_reset()
        return self._observe(), self._info()

    def _info(self) -> dict[str, Any]:
        return {}

    def step(self, action: Any) -> StepOutcome:
        self.data.ctrl[:] = self.ctrl_from_action(np.asarray(action, np.float64))
        mujoco.mj_step(self.model, self.data, nstep=N_SUBSTEPS)
        # mj_step leaves sensordata at the pre-step state of the last substep; refresh it.
        mujoco.mj_forward(self.model, self.data)
        reward, terminated = self._reward_and_done()
        return StepOutcome(self._observe(), reward, terminated, False, self._info())

    def render(self, width: int, height: int, camera: str) -> np.ndarray:
        return self._view.render(width, height, camera)

    def close(self) -> None:
        self._view.close()


class ForceObjectTask(ShadowHandTask):
    """touch / turn: objectives [task, pain]; the object's touch sensor is `obj_touch`."""

    objectives = (
        Objective("task", "1 on the step the task succeeds (the episode then terminates), else 0", 0.0, 1.0),
        Objective(
            "pain",
            "-(1 - sigmoid(2(-m + 2))) m, m = max(0, increase of the object's touch force since the last step)",
            -math.inf,
            0.0,
        ),
    )
    info_keys = ("object_force", "impact")

    def __init__(self) -> None:
        super().__init__()
        self._obj_touch_adr = self.model.sensor_adr[self.model.sensor("obj_touch").id]
        self._prev_force = 0.0
        self._impact = 0.0

    def object_force(self) -> float:
        return float(self.data.sensordata[self._obj_touch_adr])

    @staticmethod
    def _add_touch_sensor(spec: mujoco.MjSpec, body: mujoco.MjsBody, half_size: tuple[float, ...]) -> None:
        """The object's `obj_touch` sensor: a MuJoCo touch sensor on an invisible box site
        2 mm larger than the object's box (half sizes `half_size`), so that it sees every
        contact on the object's faces."""
        body.add_site(
            name="obj_touch_site",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[h + 0.002 for h in half_size],
            rgba=[0, 0, 0, 0],
        )
        spec.add_sensor(
            name="obj_touch",
            type=mujoco.mjtSensor.mjSENS_TOUCH,
            objtype=mujoco.mjtObj.mjOBJ_SITE,
            objname="obj_touch_site",
        )

    def _after_reset(self) -> None:
        self._prev_force = self.object_force()
        self._impact = 0.0

    @abc.abstractmethod
    def _success(self) -> bool:
        """Whether the object's state completes the task this step."""

    def _reward_and_done(self) -> tuple[np.ndarray, bool]:
        force = self.object_force()
        self._impact = max(0.0, force - self._prev_force)
        self._prev_force = force
        success = self._success()
        self._reward[0] = 1.0 if success else 0.0
        self._reward[1] = pain(self._impact)
        return self._reward, success

    def _info(self) -> dict[str, Any]:
        return {"object_force": self._prev_force, "impact": self._impact}
