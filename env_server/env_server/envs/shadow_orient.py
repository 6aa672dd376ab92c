"""Shadow Hand orient: hold a rectangular peg upright at 7 cm (the MO-MPO paper, appendix B.2.2).

The gymnasium-robotics Shadow Hand, palm up, lowered so that its palm is 3 cm above the
ground; a rectangular peg starts lying across the palm, in the same pose every episode (so
the seed has nothing to randomise). The three objectives are aligned: keep touching the peg,
bring its centre of mass to 7 cm above the ground, and stand it upright (x and y free).
Shared hand details (asset, 25 Hz control, touch channels): env_server/envs/_shadow_hand.py.

## Observation
float32 [75]: [0:24] joint angles, [24:48] joint velocities, [48:63] fingertip touch
(ff, mf, rf, lf, th) x [normal, tangential_x, tangential_y] (see _shadow_hand.py),
[63:75] the peg pose as the world xyz of four of its corners (the paper's encoding), in the
peg frame (+h,+h,+L), (-h,-h,+L), (+h,-h,-L), (-h,+h,-L) with h = 1.2 cm, L = 4 cm; these
four corners determine the pose.

## Action
Box(-1, 1, (20,), float32) -> the 20 position actuators' ctrlrange.

## Reward Space
0: touch, 1 when the peg's touch is active, i.e. the summed normal force of the contacts
   between the peg and the hand is > 0, else 0. (The paper uses a touch sensor on the peg;
   we count hand contacts only, so a peg lying on the ground does not count as touched.)
1: height, 1 - tanh(50 |0.07 - z|), z the peg's centre-of-mass height above the ground (m)
2: orientation, 1 - tanh(2 d), d = min over the 8 upright quaternions (long axis up or down,
   times yaw 0/90/180/270 degrees) of the rotation angle (rad) between them and the peg's
   quaternion

## Termination
None; truncation after 200 control steps (8 s).

## Geometry (ours, not the paper's)
Peg: a free box 2.4 x 2.4 x 8 cm (half-sizes 1.2, 1.2, 4 cm), density 500 kg/m^3 (23 g).
Hand mount moved from the asset's z = 0.15 m down to z = 0.0375 m, which puts the palm
surface at about 3 cm above the ground (the floor, z = 0): the peg standing upright on the
palm then has its centre of mass at about 7 cm. The hand does not collide with the floor
(floor contype/conaffinity 2, hand 1/0, peg 3/3). Peg start: lying along x across the palm,
centre (1.0, 0.87, 0.043) m, quaternion (0.7071, 0, 0.7071, 0).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from env_server.envs._shadow_hand import ShadowHandTask
from env_server.render import FreeCamera
from env_server.task import Objective

PEG_HALF = (0.012, 0.012, 0.04)
PEG_START_POS = (1.0, 0.87, 0.043)
PEG_START_QUAT = (math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0)
MOUNT_Z = 0.0375
TARGET_Z = 0.07
_H, _L = PEG_HALF[0], PEG_HALF[2]
CORNERS = np.array([[_H, _H, _L], [-_H, -_H, _L], [_H, -_H, -_L], [-_H, _H, -_L]])


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def upright_quaternions() -> np.ndarray:
    """[8, 4]: yaw k * 90 degrees, with the long (z) axis up, then flipped (180 deg about x)."""
    yaws = [np.array([math.cos(k * math.pi / 4), 0.0, 0.0, math.sin(k * math.pi / 4)]) for k in range(4)]
    flip = np.array([0.0, 1.0, 0.0, 0.0])
    return np.stack(yaws + [_qmul(q, flip) for q in yaws])


UPRIGHT = upright_quaternions()


def orientation_distance(quat: np.ndarray) -> float:
    """min over the 8 upright targets of the axis-angle norm (rad) of the rotation between them."""
    q = np.asarray(quat, np.float64)
    q = q / np.linalg.norm(q)
    dots = np.abs(UPRIGHT @ q)
    return float(2.0 * math.acos(min(1.0, float(dots.max()))))


def height_reward(z: float) -> float:
    return 1.0 - math.tanh(50.0 * abs(TARGET_Z - z))


def orientation_reward(quat: np.ndarray) -> float:
    return 1.0 - math.tanh(2.0 * orientation_distance(quat))


class ShadowOrient(ShadowHandTask):
    """Lift and orient a peg; objectives [touch, height, orientation]."""

    description = "Shadow Hand orient (paper B.2.2): peg upright at 7 cm; [touch, height, orientation], obs 75, act 20"
    objectives = (
        Objective("touch", "1 when the peg touches the hand (summed hand-peg normal force > 0), else 0", 0.0, 1.0),
        Objective("height", "1 - tanh(50 |0.07 - z|), z the peg's centre-of-mass height (m)", 0.0, 1.0),
        Objective("orientation", "1 - tanh(2 d), d the angle (rad) to the nearest of 8 upright poses", 0.0, 1.0),
    )
    max_episode_steps = 200
    info_keys = ("peg_force", "peg_height", "peg_angle")
    _extra_obs_size = 12
    # The hand is mounted lower here (palm about 3 cm above the floor).
    view = FreeCamera(lookat=(0.98, 0.87, 0.07), distance=0.4, azimuth=180.0, elevation=-30.0)

    def _edit(self, spec: mujoco.MjSpec) -> None:
        spec.body("robot0:hand mount").pos[2] = MOUNT_Z
        floor = spec.geom("floor0")
        floor.contype, floor.conaffinity = 2, 2
        body = spec.worldbody.add_body(name="peg", pos=list(PEG_START_POS), quat=list(PEG_START_QUAT))
        body.add_freejoint(name="peg")
        body.add_geom(
            name="peg",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=list(PEG_HALF),
            density=500.0,
            contype=3,
            conaffinity=3,
            condim=4,
            rgba=[0.9, 0.7, 0.1, 1],
        )

    def __init__(self) -> None:
        super().__init__()
        m = self.model
        self._peg_body = m.body("peg").id
        self._peg_geom = m.geom("peg").id
        hand_bodies = {i for i in range(m.nbody) if m.body(i).name.startswith("robot0:")}
        self._hand_geom = np.array([m.geom_bodyid[g] in hand_bodies for g in range(m.ngeom)])
        self._peg_qpos = m.joint("peg").qposadr[0]
        self._peg_force = 0.0

    def peg_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(centre-of-mass position, quaternion wxyz) of the peg."""
        return self.data.xipos[self._peg_body].copy(), self.data.xquat[self._peg_body].copy()

    def hand_peg_force(self) -> float:
        """Summed normal force of the contacts between the peg and any hand geom."""
        d = self.data
        total = 0.0
        for c in range(d.ncon):
            g1, g2 = d.contact[c].geom1, d.contact[c].geom2
            if (g1 == self._peg_geom and self._hand_geom[g2]) or (g2 == self._peg_geom and self._hand_geom[g1]):
                mujoco.mj_contactForce(self.model, d, c, self._force6)
                total += self._force6[0]
        return total

    def shaped_rewards(self) -> np.ndarray:
        """[touch, height, orientation] of the current (forwarded) state."""
        pos, quat = self.peg_pose()
        self._peg_force = self.hand_peg_force()
        self._reward[0] = 1.0 if self._peg_force > 0.0 else 0.0
        self._reward[1] = height_reward(pos[2])
        self._reward[2] = orientation_reward(quat)
        return self._reward

    def _extra_obs(self, out: np.ndarray) -> None:
        pos = self.data.xpos[self._peg_body]
        rot = self.data.xmat[self._peg_body].reshape(3, 3)
        out[:] = (pos + CORNERS @ rot.T).reshape(-1)

    def _after_reset(self) -> None:
        self._peg_force = self.hand_peg_force()

    def _reward_and_done(self) -> tuple[np.ndarray, bool]:
        return self.shaped_rewards(), False

    def _info(self) -> dict:
        pos, quat = self.peg_pose()
        return {"peg_force": self._peg_force, "peg_height": pos[2], "peg_angle": orientation_distance(quat)}
