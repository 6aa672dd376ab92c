"""Shadow Hand turn: turn a dial to 0 degrees (the MO-MPO paper, appendix B.2.1).

The gymnasium-robotics Shadow Hand (palm up, as the asset mounts it) under a dial: a flat
paddle on a horizontal hinge whose axis runs along the fingers, above the middle finger.
The dial starts at an angle drawn uniformly from [-30, 30] degrees minus the success band
(|angle| < 3 degrees), so no episode succeeds without contact; the seed draws it. The
index finger lifts one half of the paddle and the ring finger the other, so flexing the
finger under the lower half turns the dial towards 0. Shared hand details (asset, 25 Hz
control, touch channels): env_server/envs/_shadow_hand.py.

## Observation
float32 [64]: [0:24] joint angles, [24:48] joint velocities, [48:63] fingertip touch
(ff, mf, rf, lf, th) x [normal, tangential_x, tangential_y] (see _shadow_hand.py),
[63] the dial angle in radians (its joint-position sensor), as the paper includes it;
     positive = the index-finger (-x) half of the paddle is up.

## Action
Box(-1, 1, (20,), float32) -> the 20 position actuators' ctrlrange.

## Reward Space
0: task, 1 on the step the dial angle is within 3 degrees of 0, else 0 (the episode then
   terminates, so an episode's task return is 0 or 1)
1: pain, -(1 - sigmoid(2(-m + 2))) * m with m = max(0, f_t - f_{t-1}) the increase of the
   dial's touch force between consecutive control steps (paper eqs. 6-7), <= 0

## Termination
On success; otherwise truncation after 100 control steps (4 s).

## Geometry and tolerance (ours, not the paper's)
Dial: a box paddle, half-sizes 4.5 x 1.5 x 0.3 cm, on a hinge along world y through
(0.989, 0.835, 0.205) m (above the middle finger, 6.5 cm above the resting fingertips),
damping 0.01 N m s/rad, armature 1e-4, paddle mass 20 g; the paddle is balanced on its
axis, so gravity does not turn it. Hinge range +-45 degrees. Success tolerance: |angle| < 3
degrees (0.0524 rad). Its force is read by a MuJoCo touch sensor on a site (half-sizes
4.7 x 1.7 x 0.5 cm) enclosing the paddle.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from env_server.envs._shadow_hand import ForceObjectTask

DIAL_AXIS_POS = (0.989, 0.835, 0.205)
DIAL_HALF = (0.045, 0.015, 0.003)
DIAL_INIT_MAX = math.radians(30.0)
SUCCESS_TOL = math.radians(3.0)


class ShadowTurn(ForceObjectTask):
    """Turn a dial from [-30, 30] degrees to 0; objectives [task, pain]."""

    description = "Shadow Hand turn (paper B.2.1): dial to 0 deg +-3; [task, pain], obs 64, act 20, 100 steps"
    max_episode_steps = 100
    info_keys = ("object_force", "impact", "dial_angle")
    _extra_obs_size = 1

    def _edit(self, spec: mujoco.MjSpec) -> None:
        body = spec.worldbody.add_body(name="dial", pos=list(DIAL_AXIS_POS))
        body.add_joint(
            name="dial",
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=[0, 1, 0],
            damping=0.01,
            armature=1e-4,
            limited=mujoco.mjtLimited.mjLIMITED_TRUE,
            range=[-math.radians(45), math.radians(45)],
        )
        body.add_geom(
            name="dial", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(DIAL_HALF), mass=0.02, rgba=[0.8, 0.4, 0.2, 1]
        )
        self._add_touch_sensor(spec, body, DIAL_HALF)
        spec.add_sensor(
            name="dial_angle", type=mujoco.mjtSensor.mjSENS_JOINTPOS, objtype=mujoco.mjtObj.mjOBJ_JOINT, objname="dial"
        )

    def __init__(self) -> None:
        super().__init__()
        self._dial_qpos = self.model.joint("dial").qposadr[0]
        self._angle_adr = self.model.sensor_adr[self.model.sensor("dial_angle").id]

    def dial_angle(self) -> float:
        return float(self.data.sensordata[self._angle_adr])

    def _reset_object(self, rng: np.random.Generator) -> None:
        # Uniform on [-30, -3] U [3, 30] degrees: the magnitude, then the side.
        magnitude = rng.uniform(SUCCESS_TOL, DIAL_INIT_MAX)
        self.data.qpos[self._dial_qpos] = magnitude if rng.random() < 0.5 else -magnitude

    def _extra_obs(self, out: np.ndarray) -> None:
        out[0] = self.dial_angle()

    def _success(self) -> bool:
        return abs(self.dial_angle()) < SUCCESS_TOL

    def _info(self) -> dict:
        info = super()._info()
        info["dial_angle"] = self.dial_angle()
        return info
