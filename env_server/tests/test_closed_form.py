"""Objective.closed_form: declared on the Task, served as ObjectiveSpec.closed_form, its
bounds checked against the action space when a session is made."""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
import pytest
from conftest import make

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server.construction import _check_action_norm, _check_task
from env_server.errors import Internal
from env_server.instances import TaskInfo
from env_server.remote import objectives
from env_server.task import ClosedForm, Objective, StepOutcome, Task
from env_server.wire import objectives_pb


def test_served_in_make_and_list_envs(stub) -> None:
    want = {
        "pendulum": [pb.CLOSED_FORM_NONE, pb.CLOSED_FORM_ACTION_NORM],
        "humanoid-run": [pb.CLOSED_FORM_NONE, pb.CLOSED_FORM_ACTION_NORM],
        "dst": [pb.CLOSED_FORM_NONE, pb.CLOSED_FORM_NONE],
    }
    listed = {e.env_id: [o.closed_form for o in e.objectives] for e in stub.ListEnvs(pb.ListEnvsRequest()).envs}
    for env_id, forms in want.items():
        assert listed[env_id] == forms, env_id
    response = make(stub, "pendulum")
    assert [o.closed_form for o in response.spec.objectives] == want["pendulum"]
    stub.CloseSession(pb.CloseRequest(session_id=response.session_id))


def test_round_trips_and_reads_old_servers_as_undeclared() -> None:
    declared = (
        Objective("task", "t"),
        Objective("action_norm", "-|u|", -2.0, 0.0, closed_form=ClosedForm.ACTION_NORM),
        Objective("relayed", "r", closed_form=ClosedForm.UNDECLARED),
    )
    assert objectives(objectives_pb(declared)) == declared
    old = pb.ObjectiveSpec(name="action_norm", description="-|u|", min=-2.0, max=0.0)
    assert objectives([old])[0].closed_form is ClosedForm.UNDECLARED


BOX = gymnasium.spaces.Box(np.array([-2.0, 0.5], np.float32), np.array([2.0, 1.5], np.float32))


def test_action_norm_bounds_are_those_of_the_box() -> None:
    # ||a|| over [-2, 2] x [0.5, 1.5]: largest sqrt(4 + 2.25), smallest 0.5 (0 not in the second).
    low, high = -np.sqrt(6.25), -0.5
    _check_action_norm("e", Objective("n", "", low, high, closed_form=ClosedForm.ACTION_NORM), BOX)
    _check_action_norm("e", Objective("n", "", 2 * low, 2 * high, 2.0, ClosedForm.ACTION_NORM), BOX)
    with pytest.raises(Internal, match=r"objective 'n' \(closed_form = action_norm\): expected min, max = -2.5, -0.5"):
        _check_action_norm("e", Objective("n", "", -2.5, 0.0, closed_form=ClosedForm.ACTION_NORM), BOX)
    with pytest.raises(Internal, match="expected a Box action space, got Discrete"):
        _check_action_norm(
            "e", Objective("n", "", -1, 0, closed_form=ClosedForm.ACTION_NORM), gymnasium.spaces.Discrete(3)
        )


class _WrongActionNorm(Task):
    """Declares action_norm with min -1 on Box(-1, 1, (2,)), whose largest norm is sqrt(2)."""

    objectives = (Objective("effort", "-||a||_2", -1.0, 0.0, closed_form=ClosedForm.ACTION_NORM),)
    observation_space = gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)

    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        return np.zeros(1, np.float32), {}

    def step(self, action: Any) -> StepOutcome:
        return StepOutcome(np.zeros(1, np.float32), np.zeros(1), False, False)


def test_sessions_check_the_declaration_against_the_action_space() -> None:
    with pytest.raises(Internal, match=r"expected min, max = -1.41421356, 0 \(-\|\|a\|\|_2 over the action space"):
        _check_task("wrong", TaskInfo.of(_WrongActionNorm()), [])
