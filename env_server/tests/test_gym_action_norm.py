"""`gym:<id>` with `action_norm_objective = true`: a second objective, -||a||_2 of the
action sent, declared a closed form with the exact bounds over the env's Box, so that
the agent may compute it (`source = "action_norm"`) for any gymnasium task."""

from __future__ import annotations

import math

import numpy as np
import pytest

from env_server.backends.gymnasium import GymTask
from env_server.construction import build_instances
from env_server.errors import InvalidArgument
from env_server.registry import Registry
from env_server.task import ClosedForm, action_norm_bounds


def test_the_objective_is_the_norm_of_the_action_sent_with_the_boxs_bounds():
    task = GymTask("HalfCheetah-v5", action_norm_objective=True)
    try:
        names = [o.name for o in task.objectives]
        assert names == ["reward", "action_norm"]
        norm = task.objectives[1]
        assert norm.closed_form is ClosedForm.ACTION_NORM
        # HalfCheetah's Box is [-1, 1]^6: -||a||_2 runs from -sqrt(6) to 0.
        assert (norm.min, norm.max) == (pytest.approx(-math.sqrt(6.0)), 0.0)
        task.reset(seed=0)
        action = np.array([0.5, -1.0, 0.0, 0.25, 1.0, -0.5], np.float32)
        reward = task.step(action).reward.copy()
        # 0.25 + 1 + 0 + 0.0625 + 1 + 0.25 = 2.5625, whose square root is 1.6007810593582121.
        assert reward[1] == pytest.approx(-1.6007810593582121, rel=1e-6)
        assert task.objectives[0].closed_form is ClosedForm.NONE
    finally:
        task.close()


def test_bounds_of_a_box_that_does_not_hold_zero():
    import gymnasium

    # Per element the smallest |a| is 1 and 0 (the second interval holds zero), the
    # largest 3 and 2: max = -sqrt(1 + 0) = -1, min = -sqrt(9 + 4).
    box = gymnasium.spaces.Box(np.array([1.0, -2.0]), np.array([3.0, 1.0]))
    assert action_norm_bounds(box) == (pytest.approx(-math.sqrt(13.0)), -1.0)


def test_the_declaration_passes_the_servers_own_check():
    # build_instances runs the Make-time check of every declared closed form's bounds.
    entry = Registry().resolve("gym:Pendulum-v1")
    instances = build_instances(entry, {"action_norm_objective": True}, 2, 0, ())
    try:
        objectives = instances.info.objectives
        assert [o.name for o in objectives] == ["reward", "action_norm"]
        assert (objectives[1].min, objectives[1].max) == (-2.0, 0.0)
    finally:
        instances.close()


@pytest.mark.parametrize(
    ("gym_id", "value", "says"),
    [
        ("Pendulum-v1", "yes", "expected true or false, got 'yes'"),
        ("CartPole-v1", True, "expected an env with a bounded Box action space"),
    ],
)
def test_bad_requests_name_the_kwarg(gym_id, value, says):
    with pytest.raises(InvalidArgument, match="kwargs_json.action_norm_objective") as err:
        GymTask(gym_id, action_norm_objective=value)
    assert says in str(err.value)


def test_an_env_that_already_has_the_objective_refuses_a_second():
    from env_server.envs.pendulum import Pendulum

    with pytest.raises(InvalidArgument, match="already has an action_norm objective"):
        Pendulum(action_norm_objective=True)
