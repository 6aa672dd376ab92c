"""shadow-touch / shadow-turn / shadow-orient: scripted controllers exercise each reward."""

from __future__ import annotations

import math

import numpy as np
import pytest

from env_server.envs import REGISTRY
from env_server.envs._shadow_hand import FINGERS

FFJ2, FFJ1, MFJ2, MFJ1, RFJ2 = 3, 4, 6, 7, 9  # actuator indices


def ref_pain(m: float) -> float:
    """Paper eqs. 6-7 written out independently: -(1 - sigmoid(2(-m + 2))) m."""
    return -(1.0 - 1.0 / (1.0 + np.exp(-2.0 * (-m + 2.0)))) * m


def test_pain_formula_shape() -> None:
    from env_server.envs._shadow_hand import pain

    for m in (0.0, 0.5, 2.0, 3.4, 10.0, 100.0, 300.0):
        assert pain(m) == pytest.approx(ref_pain(m), rel=1e-9, abs=1e-12)
    assert pain(0.0) == 0.0
    assert pain(100.0) == pytest.approx(-100.0)  # high impact: the full force


def test_touch_press_succeeds_with_formula_pain() -> None:
    env = REGISTRY["shadow-touch"]()
    obs, info = env.reset(seed=0)
    assert obs.shape == (63,) and env.action_space.shape == (20,)
    assert info["object_force"] == 0.0
    ctrl = np.zeros(20)
    prev_force = 0.0
    pains, impacts = [], []
    for t in range(60):
        ctrl[[FFJ2, MFJ2]] = min(1.571, 0.1 * t)  # flex index and middle into the block
        out = env.step(env.action_from_ctrl(ctrl))
        force = out.info["object_force"]
        impact = max(0.0, force - prev_force)
        prev_force = force
        assert out.info["impact"] == pytest.approx(impact)
        assert out.reward[1] == pytest.approx(ref_pain(impact), rel=1e-5, abs=1e-7)
        pains.append(out.reward[1])
        impacts.append(impact)
        if out.terminated:
            break
    assert out.terminated and not out.truncated
    assert out.reward[0] == 1.0 and force > 5.0
    assert max(impacts) > 0.5 and min(pains) < -0.1  # the first impact is penalised
    # Before success the task reward is 0; the fingertips report the press.
    touch = out.observation[48:63].reshape(len(FINGERS), 3)
    assert touch[0, 0] > 1.0 and touch[1, 0] > 1.0 and touch[4, 0] == 0.0


def test_touch_resting_hand_gets_nothing() -> None:
    env = REGISTRY["shadow-touch"]()
    env.reset(seed=1)
    for _ in range(10):
        out = env.step(env.action_from_ctrl(np.zeros(20)))
        assert out.reward.tolist() == [0.0, 0.0] and not out.terminated


@pytest.mark.parametrize("seed", [0, 1, 3])
def test_turn_scripted_dial_to_zero(seed: int) -> None:
    env = REGISTRY["shadow-turn"]()
    obs, info = env.reset(seed=seed)
    start = info["dial_angle"]
    assert obs.shape == (64,) and obs[63] == np.float32(start)
    assert math.radians(3) <= abs(start) <= math.radians(30)
    ctrl = np.zeros(20)
    prev_force = 0.0
    for t in range(80):
        # Positive angle: the index half is up, so the ring finger lifts the other half.
        finger = RFJ2 if out_angle(env) > 0 else FFJ2
        ctrl[:] = 0.0
        ctrl[finger] = min(1.571, 0.05 * t)
        out = env.step(env.action_from_ctrl(ctrl))
        impact = max(0.0, out.info["object_force"] - prev_force)
        prev_force = out.info["object_force"]
        assert out.reward[1] == pytest.approx(ref_pain(impact), rel=1e-5, abs=1e-7)
        if out.terminated:
            break
        assert out.reward[0] == 0.0
    assert out.terminated and out.reward[0] == 1.0
    assert abs(out.info["dial_angle"]) < math.radians(3)
    assert out.observation[63] == np.float32(out.info["dial_angle"])
    assert np.sign(out.info["dial_angle"]) != np.sign(start) or abs(out.info["dial_angle"]) < abs(start)


def out_angle(env) -> float:
    return env.dial_angle()


def test_turn_initial_angles_cover_both_sides() -> None:
    env = REGISTRY["shadow-turn"]()
    angles = np.array([env.reset(seed=s)[1]["dial_angle"] for s in range(40)])
    assert (angles > 0).any() and (angles < 0).any()
    assert np.all(np.abs(angles) >= math.radians(3)) and np.all(np.abs(angles) <= math.radians(30))
    assert env.reset(seed=5)[1]["dial_angle"] == env.reset(seed=5)[1]["dial_angle"]


def _place_peg(env, pos, quat) -> None:
    import mujoco

    adr = env._peg_qpos
    env.data.qpos[adr : adr + 3] = pos
    env.data.qpos[adr + 3 : adr + 7] = quat
    env.data.qvel[:] = 0.0
    mujoco.mj_forward(env.model, env.data)


def _quat_axis_angle(axis, angle) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis])


def test_orient_shaped_values_at_known_poses() -> None:
    from env_server.envs.shadow_orient import UPRIGHT

    env = REGISTRY["shadow-orient"]()
    obs, _ = env.reset(seed=0)
    assert obs.shape == (75,)
    away = (0.5, 0.5, 0.07)  # in the air, away from the hand
    # Upright at the target height: height 1, orientation 1, no touch.
    for q in UPRIGHT:
        _place_peg(env, away, q)
        np.testing.assert_allclose(env.shaped_rewards(), [0.0, 1.0, 1.0], atol=1e-6)
    # Known offsets: too high/low and tilted about x, after a symmetric 90-degree yaw.
    for dz, tilt in [(0.02, math.radians(30)), (-0.01, math.radians(10)), (0.0, math.pi / 2)]:
        yaw = _quat_axis_angle([0, 0, 1], math.pi / 2)
        q = np.array([yaw[0], 0, 0, yaw[3]])
        tilt_q = _quat_axis_angle([1, 0, 0], tilt)
        from env_server.envs.shadow_orient import _qmul

        _place_peg(env, (0.5, 0.5, 0.07 + dz), _qmul(q, tilt_q))
        got = env.shaped_rewards()
        assert got[1] == pytest.approx(1 - math.tanh(50 * abs(dz)), abs=1e-6)
        assert got[2] == pytest.approx(1 - math.tanh(2 * tilt), abs=1e-6)
    # Upside down is as good as upright (the peg is symmetric).
    _place_peg(env, away, _quat_axis_angle([1, 0, 0], math.pi))
    assert env.shaped_rewards()[2] == pytest.approx(1.0)
    # The corner observation follows the pose: the corners of an upright peg at `away`.
    _place_peg(env, away, [1, 0, 0, 0])
    corners = env._observe()[63:].reshape(4, 3)
    np.testing.assert_allclose(corners[:, 2], [0.11, 0.11, 0.03, 0.03], atol=1e-6)


def test_orient_step_rewards_touch_and_standing_peg() -> None:
    env = REGISTRY["shadow-orient"]()
    env.reset(seed=0)
    hold = env.action_from_ctrl(np.zeros(20))
    # The starting peg lies on the palm: touched, low, horizontal.
    for _ in range(5):
        out = env.step(hold)
    z, angle = out.info["peg_height"], out.info["peg_angle"]
    assert out.reward[0] == 1.0
    assert out.reward[1] == pytest.approx(1 - math.tanh(50 * abs(0.07 - z)), abs=1e-6) and z < 0.05
    assert out.reward[2] == pytest.approx(1 - math.tanh(2 * angle), abs=1e-6) and angle > 1.4
    # Stood upright on the palm (our geometry puts its centre at ~7 cm): near-max height/orientation.
    _place_peg(env, (1.0, 0.90, 0.0705), [1, 0, 0, 0])
    out = env.step(hold)
    assert out.reward[0] == 1.0
    assert out.reward[1] > 0.9 and out.reward[2] > 0.9, out.reward
    # Dropped away from the hand onto the floor: no touch.
    _place_peg(env, (0.5, 0.5, 0.0125), [1, 0, 0, 0])
    out = env.step(hold)
    assert out.reward[0] == 0.0 and out.info["peg_force"] == 0.0
