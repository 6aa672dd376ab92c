"""Plug-ins fail alone: a broken entry point or constructor is listed as unavailable with
its package and reason, and every other env keeps working.

The entry points come from tests/broken_plugins (a real dist-info on sys.path, as an
installed package would be): see its shaky_pkg/__init__.py for what each one gets wrong.
"""

from __future__ import annotations

import json
import logging
import pathlib
import subprocess
import sys

import grpc
import numpy as np
import pytest
from conftest import FRONTS, make, rpc_error, running_server, server_env, step

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server._proto.mo_env.v1 import env_pb2_grpc
from env_server.client import from_tensor
from env_server.errors import ConstructorError, FailedPrecondition, InvalidArgument
from env_server.registry import Registry, construct

BROKEN = pathlib.Path(__file__).parent / "broken_plugins"
PACKAGE = "package shaky_pkg 2.0"
# env id -> what its unavailable reason must say (the package is checked separately).
LOAD_FAILURES = {
    "missing": "failed to load: ModuleNotFoundError: No module named 'shaky_pkg.nowhere'",
    "not-a-task": "expected a subclass of env_server.task.Task, got <function not_a_task",
    "bad-objectives": "BadObjectives.objectives: expected a tuple of env_server.task.Objective, got ('stay', 'move')",
    # Cut to 300 characters: the reason travels in status metadata, which clients cap.
    "huge-error": f"failed to load: ImportError: {'x' * 300}... (10000 characters)",
}


def broken_env() -> dict[str, str]:
    env = server_env()
    env["PYTHONPATH"] = f"{BROKEN}:{env['PYTHONPATH']}"
    return env


@pytest.fixture
def registry(monkeypatch: pytest.MonkeyPatch) -> Registry:
    monkeypatch.syspath_prepend(str(BROKEN))
    return Registry()


def test_broken_entry_points_are_listed_with_package_and_reason(registry: Registry) -> None:
    entries = {e.env_id: e for e in registry.entries()}
    for env_id, reason in LOAD_FAILURES.items():
        listed = registry.listed_description(entries[env_id])
        assert listed.startswith(f"unavailable: {reason}"), listed
        assert PACKAGE in listed and f"entry point {env_id} = shaky_pkg" in listed
        with pytest.raises(FailedPrecondition) as info:
            registry.resolve(env_id)
        assert info.value.message.startswith(f"env_id: env '{env_id}' is unavailable: {reason}")
        assert PACKAGE in info.value.message
    # The good entry point and the shipped envs are untouched.
    assert registry.listed_description(entries["stepper"]) == entries["stepper"].description
    assert registry.listed_description(entries["dst"]) == entries["dst"].description
    construct(registry.resolve("stepper"), {"step_size": 0.5}).reset()


def test_each_broken_entry_point_is_logged_once(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.syspath_prepend(str(BROKEN))
    with caplog.at_level(logging.ERROR, logger="env_server.registry"):
        Registry()
    for env_id, reason in LOAD_FAILURES.items():
        lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith(f"env {env_id} ")]
        assert len(lines) == 1 and PACKAGE.removeprefix("package ") in lines[0] and reason in lines[0], lines


def test_the_callers_kwargs_are_invalid_argument(registry: Registry) -> None:
    stepper = registry.resolve("stepper")
    # The value's type cannot be the default's: refused before the constructor runs.
    with pytest.raises(InvalidArgument) as info:
        construct(stepper, {"step_size": "big"})
    assert info.value.message == (
        "kwargs_json: env 'stepper' keyword 'step_size' expects a float (its default is 0.1), got 'big'"
    )
    # The constructor's own validation raises ValueError: the caller's error too.
    with pytest.raises(InvalidArgument) as info:
        construct(stepper, {"step_size": 5.0})
    assert info.value.message.startswith(
        "kwargs_json: env 'stepper' rejected keyword arguments ['step_size']: "
        "ValueError: 'step_size: expected a number in (0, 1], got 5.0'"
    )
    assert PACKAGE in info.value.message


def test_constructor_bugs_are_not_the_callers(registry: Registry) -> None:
    # Without kwargs nothing the caller sent can be at fault, whatever the exception type.
    with pytest.raises(ValueError, match="negative dimensions"):
        construct(registry.resolve("buggy"), {})
    # A RuntimeError is no "bad argument", kwargs or not.
    with pytest.raises(RuntimeError, match="licence server"):
        construct(registry.resolve("crashy"), {"up": False})
    # The rule's limit, said in the message: a ValueError from a bug that only kwargs reach
    # is answered as the caller's.
    with pytest.raises(InvalidArgument, match=r"if these values are valid, the constructor of package shaky_pkg"):
        construct(registry.resolve("buggy"), {"step_size": 0.5})


def test_a_failed_make_is_logged_once_per_reason(registry: Registry, caplog: pytest.LogCaptureFixture) -> None:
    crashy = registry.resolve("crashy")
    failure = ConstructorError("env crashy: constructor raised ...", "RuntimeError: licence server not reachable")
    with caplog.at_level(logging.ERROR, logger="env_server.registry"):
        registry.note_make(crashy, failure)
        registry.note_make(crashy, failure)  # a client retrying
    assert len(caplog.records) == 1
    assert registry.listed_description(crashy).startswith(
        "unavailable: its constructor raised at the last Make: RuntimeError: licence server not reachable"
    )
    registry.note_make(crashy, None)
    assert registry.listed_description(crashy) == crashy.description


def test_list_shows_unavailable_envs_and_logs_each_once() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "env_server", "--list"], capture_output=True, text=True, env=broken_env(), timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    for env_id, reason in LOAD_FAILURES.items():
        assert any(line.startswith(f"{env_id}  unavailable: {reason}") for line in lines), proc.stdout
        assert proc.stderr.count(f"env {env_id} (package shaky_pkg 2.0") == 1, proc.stderr
    assert any(line.startswith("stepper  test only: a walk") for line in lines)
    assert any(line.startswith("dst  ") for line in lines)


def _listed(stub: env_pb2_grpc.EnvServiceStub) -> dict[str, pb.EnvInfo]:
    return {e.env_id: e for e in stub.ListEnvs(pb.ListEnvsRequest()).envs}


def _kwargs(**kwargs) -> dict[str, str]:
    return {"kwargs_json": json.dumps(kwargs)}


@pytest.mark.parametrize("front", FRONTS)
def test_server_serves_around_broken_plugins(front: str) -> None:
    with running_server("--front", front, extra_env={"PYTHONPATH": broken_env()["PYTHONPATH"]}) as address:
        channel = grpc.insecure_channel(address)
        stub = env_pb2_grpc.EnvServiceStub(channel)
        listed = _listed(stub)
        for env_id, reason in LOAD_FAILURES.items():
            assert listed[env_id].description.startswith(f"unavailable: {reason}")
            assert PACKAGE in listed[env_id].description and not listed[env_id].objectives
            err = rpc_error(make, stub, env_id)
            assert err.code() == grpc.StatusCode.FAILED_PRECONDITION
            assert err.details().startswith(f"env_id: env '{env_id}' is unavailable: {reason}")
            assert PACKAGE in err.details()

        # The caller's kwargs: INVALID_ARGUMENT naming the keyword.
        err = rpc_error(make, stub, "stepper", **_kwargs(step_size="big"))
        assert err.code() == grpc.StatusCode.INVALID_ARGUMENT and "keyword 'step_size' expects a float" in err.details()
        err = rpc_error(make, stub, "stepper", **_kwargs(step_size=5.0))
        assert err.code() == grpc.StatusCode.INVALID_ARGUMENT and "ValueError: 'step_size: expected" in err.details()

        # A constructor that raises on its own: INTERNAL naming env and package, then
        # listed as unavailable until a Make of it succeeds.
        err = rpc_error(make, stub, "crashy", 2)
        assert err.code() == grpc.StatusCode.INTERNAL
        assert err.details() == (
            "env crashy (package shaky_pkg 2.0): constructor raised RuntimeError: licence server not reachable"
        )
        assert _listed(stub)["crashy"].description.startswith(
            "unavailable: its constructor raised at the last Make: RuntimeError: licence server not reachable"
        )
        assert make(stub, "crashy", **_kwargs(up=True)).session_id
        assert not _listed(stub)["crashy"].description.startswith("unavailable")

        # Every other env keeps working, shipped and plug-in alike.
        for env_id, action in (("dst", np.array([1], np.int64)), ("stepper", np.array([[0.5]], np.float32))):
            session = make(stub, env_id).session_id
            stub.Reset(pb.ResetRequest(session_id=session))
            assert from_tensor(step(stub, session, action).reward).shape == (1, 2 if env_id == "dst" else 1)
        channel.close()
