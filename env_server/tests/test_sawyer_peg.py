"""sawyer-peg: a scripted insertion raises `insertion` to its inserted level; `force` is -||F||_1."""

from __future__ import annotations

import math

import numpy as np
import pytest

from env_server.envs import REGISTRY
from env_server.envs.sawyer_peg import HOLE_DEPTH, OPENING, insertion_reward, shaping

BOTTOM_Z = OPENING[2] - HOLE_DEPTH


def test_shaping_constants() -> None:
    assert shaping(0.0, 0.95, 0.01) == 1.0
    assert shaping(0.01, 0.95, 0.01) == pytest.approx(0.05)  # 1 - l at eps
    assert shaping(0.04, 0.5, 0.04) == pytest.approx(0.5)
    # At the opening, r_inserted = 0.5 dominates 0.2 r_approach = 0.2; at the bottom it is 1.
    assert insertion_reward(OPENING) == pytest.approx(0.5)
    assert insertion_reward(OPENING - [0, 0, HOLE_DEPTH]) == pytest.approx(1.0)
    # Not aligned (beside the hole, at the bottom's height): only the approach term, x 0.2.
    beside = OPENING + [0.02, 0, -HOLE_DEPTH]
    assert insertion_reward(beside) == pytest.approx(0.2 * shaping(math.hypot(0.02, HOLE_DEPTH), 0.95, 0.01))


def test_reset_start_cube_and_stacked_observation() -> None:
    env = REGISTRY["sawyer-peg"]()
    starts = []
    for seed in range(6):
        obs, info = env.reset(seed=seed)
        assert obs.shape == (123,)
        np.testing.assert_array_equal(obs[:41], obs[41:82])
        np.testing.assert_array_equal(obs[:41], obs[82:])
        tip = info["peg_tip"]
        np.testing.assert_allclose(obs[21:24], tip, atol=1e-6)
        assert np.all(np.abs(tip - (OPENING + [0, 0, 0.06])) <= 0.04 + 1e-4), tip
        assert np.abs(info["wrist_force"]).max() < 1e-6  # tared, no contact
        starts.append(tip)
    assert np.ptp(np.array(starts), axis=0).min() > 0.01
    np.testing.assert_array_equal(env.reset(seed=2)[0], env.reset(seed=2)[0])


def test_velocity_limit_and_fixed_orientation() -> None:
    env = REGISTRY["sawyer-peg"]()
    env.reset(seed=0)
    quat0 = env.reset(seed=0)[0][24:28].copy()
    tips = [env.tip()]
    for _ in range(20):
        out = env.step(np.array([1.0, -1.0, 1.0], np.float32))
        tips.append(env.tip())
    speed = np.abs(np.diff(np.array(tips)[5:], axis=0)).mean(axis=0) * 20
    assert np.all(speed > 0.045) and np.all(speed < 0.052), speed
    np.testing.assert_allclose(np.abs(out.observation[24:28]), np.abs(quat0), atol=2e-3)
    prev = out.observation
    out = env.step(np.zeros(3, np.float32))
    np.testing.assert_array_equal(out.observation[41:], prev[:82])  # history shifts by one frame


def test_scripted_insertion() -> None:
    env = REGISTRY["sawyer-peg"]()
    env.reset(seed=4)
    best = 0.0
    for t in range(300):
        tip = env.tip()
        err = OPENING[:2] - tip[:2]
        if np.linalg.norm(err) > 0.002:
            vz = (OPENING[2] + 0.01) - tip[2]  # hover 1 cm above the opening while centring
        else:
            vz = -0.02
        action = np.clip(np.array([err[0], err[1], vz]) * 20.0, -1.0, 1.0)
        if np.linalg.norm(err) <= 0.002:
            action[2] = -0.4
        out = env.step(action.astype(np.float32))
        force = out.info["wrist_force"]
        assert out.reward[1] == pytest.approx(-np.abs(force).sum(), rel=1e-5, abs=1e-5)
        np.testing.assert_allclose(out.observation[28:31], force, rtol=1e-5, atol=1e-5)
        assert out.reward[0] == pytest.approx(insertion_reward(out.info["peg_tip"]), abs=1e-6)
        best = max(best, float(out.reward[0]))
        if out.info["peg_tip"][2] < OPENING[2] - 0.005:
            assert out.reward[0] > 0.5  # inside the hole: the inserted term dominates
        if out.terminated:
            break
    assert best > 0.97  # the inserted level (1 at the bottom)
    # Bottoming out: the vertical force exceeds 5 N and terminates the episode.
    assert out.terminated and abs(out.info["wrist_force"][2]) > 5.0
    assert out.info["peg_tip"][2] == pytest.approx(BOTTOM_Z, abs=0.003)
