"""Shadow Hand touch: press a fixed block with more than 5 N (the MO-MPO paper, appendix B.2.1).

The gymnasium-robotics Shadow Hand (palm up, as the asset mounts it) under a static block
that hangs above the index and middle fingers. The block is always in the same pose, so the
seed has nothing to randomise. Shared hand details (asset, 25 Hz control, touch channels):
env_server/envs/_shadow_hand.py.

## Observation
float32 [63]: [0:24] joint angles, [24:48] joint velocities, [48:63] fingertip touch
(ff, mf, rf, lf, th) x [normal, tangential_x, tangential_y]; see _shadow_hand.py.

## Action
Box(-1, 1, (20,), float32) -> the 20 position actuators' ctrlrange.

## Reward Space
0: task, 1 on the step the block's touch sensor reads more than 5 N, else 0 (the episode
   then terminates, so an episode's task return is 0 or 1)
1: pain, -(1 - sigmoid(2(-m + 2))) * m with m = max(0, f_t - f_{t-1}) the increase of the
   block's touch force between consecutive control steps (paper eqs. 6-7), <= 0

## Termination
On success; otherwise truncation after 100 control steps (4 s).

## Geometry (ours, not the paper's)
Block: a static box, half-sizes 3 x 3 x 1.5 cm, centred at (0.975, 0.80, 0.225) m in the
asset's world frame, 7 cm above the resting fingertips, over the index and middle fingers
(flexing FFJ2/MFJ2 presses it). Its force is read by a MuJoCo touch sensor on a site
(half-sizes 3.2 x 3.2 x 1.7 cm) enclosing the block.
"""

from __future__ import annotations

import mujoco

from env_server.envs._shadow_hand import TOUCH_SUCCESS_N, ForceObjectTask

BLOCK_POS = (0.975, 0.80, 0.225)
BLOCK_HALF = (0.03, 0.03, 0.015)


class ShadowTouch(ForceObjectTask):
    """Press a fixed block with > 5 N; objectives [task, pain]."""

    description = "Shadow Hand touch (paper B.2.1): press a block > 5 N; [task, pain], obs 63, act 20, 100 steps"
    max_episode_steps = 100

    def _edit(self, spec: mujoco.MjSpec) -> None:
        body = spec.worldbody.add_body(name="block", pos=list(BLOCK_POS))  # no joint: static
        body.add_geom(name="block", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(BLOCK_HALF), rgba=[0.2, 0.4, 0.8, 1])
        self._add_touch_sensor(spec, body, BLOCK_HALF)

    def _success(self) -> bool:
        return self._prev_force > TOUCH_SUCCESS_N
