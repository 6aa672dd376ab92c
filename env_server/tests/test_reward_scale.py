"""The Make kwarg every env takes, `reward_scale = {objective: factor}`: the session
multiplies that objective's reward (and so its episode returns) by the factor, reports
it in the EnvSpec, and refuses what is not a positive factor of a named objective."""

import json

import grpc
import numpy as np
import pytest
from conftest import make, rpc_error, step

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server.client import from_tensor

STEPS = 12


def rollout(stub, env_id: str, actions: np.ndarray, kwargs: dict) -> tuple[pb.MakeResponse, np.ndarray, list]:
    """Rewards [STEPS, B, K] and the ended episodes' returns of one seeded session."""
    made = make(stub, env_id, len(actions[0]), seed=3, kwargs_json=json.dumps(kwargs))
    sid = made.session_id
    stub.Reset(pb.ResetRequest(session_id=sid))
    rewards, returns = [], []
    for a in actions:
        out = step(stub, sid, a)
        rewards.append(from_tensor(out.reward))
        returns.extend(list(e.episode_return) for e in out.episodes)
    stub.CloseSession(pb.CloseRequest(session_id=sid))
    return made, np.stack(rewards), returns


@pytest.mark.parametrize(
    ("env_id", "actions"),
    [
        # DST: right, then down (the 0.7 treasure ends the episode at step 2).
        ("dst", np.array([[1, 1], [2, 2]] * (STEPS // 2), np.int64)),
        ("pendulum", np.linspace(-2, 2, STEPS * 2, dtype=np.float32).reshape(STEPS, 2, 1)),
    ],
)
def test_a_scaled_objective_is_the_same_reward_times_its_factor(stub, env_id, actions):
    plain, reward, returns = rollout(stub, env_id, actions, {})
    first, second = (o.name for o in plain.spec.objectives)
    scaled, scaled_reward, scaled_returns = rollout(stub, env_id, actions, {"reward_scale": {second: 10.0}})
    np.testing.assert_array_equal(scaled_reward[..., 0], reward[..., 0])
    np.testing.assert_allclose(scaled_reward[..., 1], 10.0 * reward[..., 1], rtol=1e-6)
    # Episode returns are sums of the scaled rewards (DST's episodes end within STEPS;
    # pendulum's 200-step episodes do not).
    assert len(returns) == len(scaled_returns) and (returns or env_id == "pendulum")
    if returns:
        np.testing.assert_allclose(np.array(scaled_returns), np.array(returns) * [1.0, 10.0], rtol=1e-6)
    unscaled, factor = plain.spec.objectives[1], scaled.spec.objectives[1]
    assert (scaled.spec.objectives[0].scale, factor.scale, unscaled.scale) == (1.0, 10.0, 1.0)
    assert (factor.min, factor.max) == (10.0 * unscaled.min, 10.0 * unscaled.max)
    assert first == scaled.spec.objectives[0].name


def test_reward_scale_is_a_capability(stub):
    assert "reward_scale" in stub.GetVersion(pb.GetVersionRequest()).capabilities


@pytest.mark.parametrize(
    ("scale", "expected"),
    [
        ({"treasure": 0}, "kwargs_json.reward_scale.'treasure': expected a finite number > 0, got 0"),
        ({"treasure": -2.5}, "expected a finite number > 0, got -2.5"),
        ({"treasure": "x"}, "expected a finite number > 0, got 'x'"),
        ({"treasure": True}, "expected a finite number > 0, got True"),
        ([1.0, 2.0], "kwargs_json.reward_scale: expected an object {objective name: factor}, got [1.0, 2.0]"),
        ({"gold": 2.0}, "kwargs_json.reward_scale: expected objective names of dst, one of ['time', 'treasure']"),
    ],
)
def test_bad_scales_are_invalid_argument_naming_the_field(stub, scale, expected):
    err = rpc_error(make, stub, "dst", kwargs_json=json.dumps({"reward_scale": scale}))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert expected in err.details(), err.details()
    # The server goes on serving.
    ok = make(stub, "dst")
    stub.CloseSession(pb.CloseRequest(session_id=ok.session_id))
