"""Sawyer peg-in-hole with a Cartesian velocity controller (the MO-MPO paper, appendix B.5).

robosuite 1.5.2's Sawyer arm model (its MJCF and meshes,
`robosuite/models/assets/robots/sawyer/robot.xml`) in plain MuJoCo, with our own controller
and fixture. We do not use robosuite's environment class or its OSC controller (see "Simplified"
below). A square peg hangs below a wrist force-torque sensor on the flange; the agent
commands the peg's Cartesian velocity at 20 Hz, and the controller holds the gripper
orientation fixed.

Controller (once per 20 Hz step): the Cartesian velocity setpoint v = 0.05 m/s * clip(a, -1, 1)
plus an orientation-hold angular velocity 5 * rotvec(R0 R^T) becomes the joint velocity
command qd_cmd = J^+ [v; w] + (I - J^+ J) 2 (q0 - q) (damped least squares at the peg tip,
null space pulled towards the start posture), clipped to +-1.5 rad/s. MuJoCo velocity servos
(kv per joint, the Sawyer's torque limits) track qd_cmd over 25 substeps of 2 ms. Gravity is
compensated exactly (MuJoCo gravcomp) on the arm, sensor and peg. The wrist sensor is tared:
its reading at rest in the home posture (the peg's weight, 0.49 N) is subtracted, so with the
orientation held it reads contact (and small inertial) forces only.

## Observation
float32 [123]: three stacked frames [t, t-1, t-2] of 41 entries each (at reset all three are
the first frame). One frame:
[0:7]   joint positions (rad)        [7:14]  joint velocities (rad/s)
[14:21] joint torques (actuator force, N m)
[21:24] end-effector (peg tip) position (m), [24:28] end-effector quaternion (w, x, y, z)
[28:31] wrist force (N), [31:34] wrist torque (N m), tared, in the sensor frame (aligned with the
        world axes while the orientation is held)
[34:41] the controller's joint velocity command qd_cmd (rad/s)

## Action
Box(-1, 1, (3,), float32): the Cartesian velocity setpoint, x 0.05 m/s per axis (world frame).

## Reward Space
0: insertion, max(0.2 r_approach, r_inserted) (paper eqs. 9-13), in [0, 1]:
   r_approach = s(p_peg, p_opening; l=0.95, eps=0.01),
   r_inserted = [|p_peg,xy - p_opening,xy| < d/2] * s(p_peg,z, p_bottom,z; l=0.5, eps=0.04),
   s(p1, p2) = 1 - tanh^2(atanh(sqrt(l)) / eps * |p1 - p2|), p_peg the peg tip, d = 0.03 m
1: force, -||F||_1 of the wrist force (N), <= 0 (paper eq. 14)

## Termination
When |F_x| or |F_y| exceeds 15 N or |F_z| exceeds 5 N (sensor frame = world axes); otherwise
truncation after 600 steps (30 s).

## Geometry (ours, not the paper's)
Hole: a square hole 3.0 x 3.0 cm (d = 0.03 in eq. 12), 4 cm deep, opening centred at
(0.45, 0.16, 0.10) m, in a static block of four walls and a bottom. Peg: 2.7 x 2.7 x 6 cm
(1.5 mm clearance per side), 50 g, axis-aligned with the hole (the sensor frame is set
world-aligned at the start posture, so the arm's 10 degree flange yaw does not matter). The
hole depth equals eps_inserted = 0.04 so r_inserted = 0.5 at the opening, as the paper
intends. Peg start: the tip uniform in an 8 cm cube centred 6 cm above the opening (tip
2-10 cm above it, +-4 cm in x and y), reached by damped-least-squares IK from robosuite's
Sawyer home posture. Only the peg collides, with the fixture; arm self-collisions and
arm-fixture contacts are off.

## Simplified relative to the paper
A simulated arm; the paper's Robotiq F/T sensor and 2F85 gripper are replaced by a MuJoCo
force/torque sensor on the flange and a rigid peg. The Cartesian controller is ours
(resolved-rate with velocity servos), not Sawyer's own.
"""

from __future__ import annotations

import importlib.util
import math
import os
from typing import Any

import gymnasium
import mujoco
import numpy as np

from env_server.render import FreeCamera, MujocoView
from env_server.task import Objective, StepOutcome, Task

CONTROL_HZ = 20
TIMESTEP = 0.002
N_SUBSTEPS = 25  # 25 x 2 ms = 50 ms
MAX_SPEED = 0.05  # m/s per axis
HOME_QPOS = np.array([0.0, -1.18, 0.0, 2.18, 0.0, 0.57, -1.57])  # robosuite Sawyer init_qpos
KV = np.array([60.0, 60.0, 30.0, 30.0, 6.0, 6.0, 4.0])
QD_MAX = 1.5
OPENING = np.array([0.45, 0.16, 0.10])
HOLE_WIDTH = 0.03
HOLE_DEPTH = 0.04
PEG_HALF = (0.0135, 0.0135, 0.03)
START_CENTRE = OPENING + np.array([0.0, 0.0, 0.06])
START_HALF = 0.04
FORCE_LIMIT_XY = 15.0
FORCE_LIMIT_Z = 5.0
#: Render's default view: the arm, the peg and the hole block, from the front and above.
VIEW = FreeCamera(lookat=(0.3, 0.12, 0.35), distance=1.3, azimuth=135.0, elevation=-20.0)
L_APPROACH, EPS_APPROACH = 0.95, 0.01
L_INSERTED, EPS_INSERTED = 0.5, 0.04
FRAME = 41
HISTORY = 3


def sawyer_xml_path() -> str:
    # find_spec locates robosuite without running its (slow, chatty) __init__.
    spec = importlib.util.find_spec("robosuite")
    assert spec is not None and spec.submodule_search_locations, "robosuite is not installed"
    return os.path.join(spec.submodule_search_locations[0], "models", "assets", "robots", "sawyer", "robot.xml")


def shaping(dist: float, l: float, eps: float) -> float:  # noqa: E741 (the paper names it l)
    """Paper eq. 13: 1 - tanh^2(atanh(sqrt(l)) / eps * dist); equals 1 - l at dist = eps."""
    return 1.0 - math.tanh(math.atanh(math.sqrt(l)) / eps * dist) ** 2


def insertion_reward(tip: np.ndarray) -> float:
    """Paper eqs. 9-12 for the peg tip position."""
    approach = shaping(float(np.linalg.norm(tip - OPENING)), L_APPROACH, EPS_APPROACH)
    aligned = float(np.linalg.norm(tip[:2] - OPENING[:2])) < HOLE_WIDTH / 2
    inserted = shaping(abs(tip[2] - (OPENING[2] - HOLE_DEPTH)), L_INSERTED, EPS_INSERTED) if aligned else 0.0
    return max(0.2 * approach, inserted)


def _rotvec(r: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, r.reshape(-1))
    vel = np.zeros(3)
    mujoco.mju_quat2Vel(vel, quat, 1.0)
    return vel


class SawyerPeg(Task):
    """Peg-in-hole; objectives [insertion, force]."""

    description = (
        "Sawyer peg-in-hole (paper B.5): Cartesian velocity 20 Hz; [insertion, force], obs 123, act 3, 600 steps"
    )
    objectives = (
        Objective("insertion", "max(0.2 r_approach, r_inserted), paper eqs. 9-13", 0.0, 1.0),
        Objective("force", "-||F||_1 of the wrist force sensor (N), paper eq. 14", -math.inf, 0.0),
    )
    max_episode_steps = 600
    info_keys = ("peg_tip", "wrist_force")
    render_fps = float(CONTROL_HZ)

    def __init__(self) -> None:
        self.model = self._build()
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._tip_site = m.site("peg_tip").id
        self._ft_site = m.site("ft_site").id
        self._force_adr = m.sensor_adr[m.sensor("wrist_force").id]
        self._torque_adr = m.sensor_adr[m.sensor("wrist_torque").id]
        self._jacp = np.zeros((3, m.nv))
        self._jacr = np.zeros((3, m.nv))
        self._qd_cmd = np.zeros(7)
        self._frames = np.zeros((HISTORY, FRAME), np.float32)
        self._reward = np.zeros(2, np.float32)
        self._rng = np.random.default_rng()
        self._view = MujocoView(m, self.data, VIEW)
        self.cameras = self._view.cameras
        self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (HISTORY * FRAME,), np.float32)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (3,), np.float32)
        # The peg/sensor frame is world-aligned at home; hold that orientation.
        self._r0 = np.eye(3)
        # Tare: the sensor's reading at rest in the home posture (the peg's weight, 0.49 N on z),
        # constant while the orientation is held; subtracted from every reading.
        self._tare = np.zeros(6)
        self.data.qpos[:7] = HOME_QPOS
        mujoco.mj_forward(m, self.data)
        self._tare[:3] = self.data.sensordata[self._force_adr : self._force_adr + 3]
        self._tare[3:] = self.data.sensordata[self._torque_adr : self._torque_adr + 3]

    # -- model ----------------------------------------------------------------------------
    @staticmethod
    def _build() -> mujoco.MjModel:
        # Home-pose flange orientation, to make the sensor/peg frame world-aligned there.
        arm = mujoco.MjSpec.from_file(sawyer_xml_path()).compile()
        d = mujoco.MjData(arm)
        d.qpos[:] = HOME_QPOS
        mujoco.mj_kinematics(arm, d)
        hand_quat = d.body("right_hand").xquat.copy()
        inv = np.zeros(4)
        mujoco.mju_negQuat(inv, hand_quat)

        spec = mujoco.MjSpec.from_file(sawyer_xml_path())
        spec.option.timestep = TIMESTEP
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        for body in spec.bodies:
            if body.name != "world":
                body.gravcomp = 1.0
        for geom in spec.geoms:
            geom.contype, geom.conaffinity = 0, 0
        for i, act in enumerate(spec.actuators):
            torque = float(act.ctrlrange[1])
            act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
            act.gainprm[0] = KV[i]
            act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
            act.biasprm[:3] = [0.0, 0.0, -KV[i]]
            act.ctrlrange = [-QD_MAX, QD_MAX]
            act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
            act.forcerange = [-torque, torque]
        spec.worldbody.add_geom(
            name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2, 2, 0.1], contype=0, conaffinity=0
        )
        ft = spec.body("right_hand").add_body(name="ft_frame", quat=list(inv), gravcomp=1.0)
        ft.add_site(name="ft_site", size=[0.01, 0.01, 0.01])
        spec.add_sensor(
            name="wrist_force", type=mujoco.mjtSensor.mjSENS_FORCE, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="ft_site"
        )
        spec.add_sensor(
            name="wrist_torque",
            type=mujoco.mjtSensor.mjSENS_TORQUE,
            objtype=mujoco.mjtObj.mjOBJ_SITE,
            objname="ft_site",
        )
        peg = ft.add_body(name="peg", pos=[0, 0, -PEG_HALF[2]], gravcomp=1.0)
        peg.add_geom(
            name="peg",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=list(PEG_HALF),
            mass=0.05,
            contype=4,
            conaffinity=4,
            rgba=[0.2, 0.6, 0.9, 1],
            condim=3,
            friction=[0.3, 0.005, 0.0001],
        )
        peg.add_site(name="peg_tip", pos=[0, 0, -PEG_HALF[2]], size=[0.003, 0.003, 0.003])
        # The fixture: a square hole, opening at OPENING, HOLE_DEPTH deep, on a pedestal to the floor.
        fixture = spec.worldbody.add_body(name="hole", pos=list(OPENING))
        wall, h = 0.03, HOLE_WIDTH / 2
        bottom = OPENING[2] - HOLE_DEPTH
        half_z = HOLE_DEPTH / 2
        for name, pos, size in [
            ("wall_px", [h + wall / 2, 0, -half_z], [wall / 2, h + wall, half_z]),
            ("wall_nx", [-h - wall / 2, 0, -half_z], [wall / 2, h + wall, half_z]),
            ("wall_py", [0, h + wall / 2, -half_z], [h, wall / 2, half_z]),
            ("wall_ny", [0, -h - wall / 2, -half_z], [h, wall / 2, half_z]),
            ("hole_bottom", [0, 0, -HOLE_DEPTH - bottom / 2], [h + wall, h + wall, bottom / 2]),
        ]:
            fixture.add_geom(
                name=name,
                type=mujoco.mjtGeom.mjGEOM_BOX,
                pos=pos,
                size=size,
                contype=4,
                conaffinity=4,
                rgba=[0.6, 0.6, 0.6, 1],
                condim=3,
                friction=[0.3, 0.005, 0.0001],
            )
        fixture.add_site(name="hole_opening", size=[0.003, 0.003, 0.003])
        return spec.compile()

    # -- controller -----------------------------------------------------------------------
    def _jacobian(self) -> np.ndarray:
        mujoco.mj_jacSite(self.model, self.data, self._jacp, self._jacr, self._tip_site)
        return np.vstack([self._jacp[:, :7], self._jacr[:, :7]])

    def _joint_command(self, velocity: np.ndarray) -> np.ndarray:
        d = self.data
        jac = self._jacobian()
        r = d.site_xmat[self._tip_site].reshape(3, 3)
        twist = np.concatenate([velocity, 5.0 * _rotvec(self._r0 @ r.T)])
        jjt = jac @ jac.T + 1e-4 * np.eye(6)
        pinv = jac.T @ np.linalg.solve(jjt, np.eye(6))
        null = (np.eye(7) - pinv @ jac) @ (2.0 * (HOME_QPOS - d.qpos[:7]))
        return np.clip(pinv @ twist + null, -QD_MAX, QD_MAX)

    def _ik(self, target: np.ndarray) -> None:
        """Damped least-squares IK: peg tip to `target`, orientation R0 (in place, from HOME)."""
        d = self.data
        d.qpos[:7] = HOME_QPOS
        for _ in range(50):
            mujoco.mj_kinematics(self.model, d)
            mujoco.mj_comPos(self.model, d)
            err = target - d.site_xpos[self._tip_site]
            r = d.site_xmat[self._tip_site].reshape(3, 3)
            rot = _rotvec(self._r0 @ r.T)
            if np.linalg.norm(err) < 1e-6 and np.linalg.norm(rot) < 1e-5:
                break
            jac = self._jacobian()
            dq = jac.T @ np.linalg.solve(jac @ jac.T + 1e-6 * np.eye(6), np.concatenate([err, rot]))
            d.qpos[:7] += dq

    # -- Task -----------------------------------------------------------------------------
    def tip(self) -> np.ndarray:
        return self.data.site_xpos[self._tip_site].copy()

    def wrist_force(self) -> np.ndarray:
        """Tared wrist force (N), sensor frame."""
        return self.data.sensordata[self._force_adr : self._force_adr + 3] - self._tare[:3]

    def wrist_torque(self) -> np.ndarray:
        """Tared wrist torque (N m), sensor frame."""
        return self.data.sensordata[self._torque_adr : self._torque_adr + 3] - self._tare[3:]

    def _frame(self) -> np.ndarray:
        d = self.data
        f = np.empty(FRAME, np.float32)
        f[0:7] = d.qpos[:7]
        f[7:14] = d.qvel[:7]
        f[14:21] = d.actuator_force
        f[21:24] = d.site_xpos[self._tip_site]
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, d.site_xmat[self._tip_site])
        f[24:28] = quat
        f[28:31] = self.wrist_force()
        f[31:34] = self.wrist_torque()
        f[34:41] = self._qd_cmd
        return f

    def _observe(self) -> np.ndarray:
        return self._frames.reshape(-1).copy()

    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        mujoco.mj_resetData(self.model, self.data)
        target = START_CENTRE + self._rng.uniform(-START_HALF, START_HALF, 3)
        self._ik(target)
        self.data.ctrl[:] = 0.0
        self._qd_cmd[:] = 0.0
        mujoco.mj_forward(self.model, self.data)
        self._frames[:] = self._frame()
        return self._observe(), self._info()

    def _info(self) -> dict[str, Any]:
        return {"peg_tip": self.tip(), "wrist_force": self.wrist_force()}

    def step(self, action: Any) -> StepOutcome:
        velocity = MAX_SPEED * np.clip(np.asarray(action, np.float64), -1.0, 1.0)
        self._qd_cmd[:] = self._joint_command(velocity)
        self.data.ctrl[:] = self._qd_cmd
        mujoco.mj_step(self.model, self.data, nstep=N_SUBSTEPS)
        mujoco.mj_forward(self.model, self.data)  # sensors of the final state
        force = self.wrist_force()
        self._reward[0] = insertion_reward(self.tip())
        self._reward[1] = -np.abs(force).sum()
        terminated = bool(
            abs(force[0]) > FORCE_LIMIT_XY or abs(force[1]) > FORCE_LIMIT_XY or abs(force[2]) > FORCE_LIMIT_Z
        )
        self._frames[1:] = self._frames[:-1].copy()
        self._frames[0] = self._frame()
        return StepOutcome(self._observe(), self._reward, terminated, False, self._info())

    def render(self, width: int, height: int, camera: str) -> np.ndarray:
        return self._view.render(width, height, camera)

    def close(self) -> None:
        self._view.close()
