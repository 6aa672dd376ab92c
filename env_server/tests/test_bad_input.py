"""Every malformed request gets the right gRPC code and a message naming field, expectation and value."""

from __future__ import annotations

import json

import grpc
import numpy as np
import pytest
from conftest import FRONTS, make, rpc_error, running_server, step

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server._proto.mo_env.v1 import env_pb2_grpc
from env_server.client import to_tensor


@pytest.fixture(scope="module")
def humanoid(stub) -> str:
    """A reset humanoid-run session with 2 instances (errors leave it unchanged)."""
    session_id = make(stub, "humanoid-run", 2, seed=0).session_id
    stub.Reset(pb.ResetRequest(session_id=session_id))
    return session_id


@pytest.fixture(scope="module")
def dst(stub) -> str:
    session_id = make(stub, "dst", 3).session_id
    stub.Reset(pb.ResetRequest(session_id=session_id))
    return session_id


def test_valid_step_still_works(stub, humanoid) -> None:
    response = step(stub, humanoid, np.zeros((2, 21), np.float32))
    assert list(response.reward.shape) == [2, 2]


def test_wrong_action_shape(stub, humanoid) -> None:
    err = rpc_error(step, stub, humanoid, np.zeros((2, 20), np.float32))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert "action: expected shape [2, 21]" in err.details()
    assert "num_envs=2" in err.details() and "got [2, 20]" in err.details()


def test_wrong_action_dtype(stub, humanoid) -> None:
    err = rpc_error(step, stub, humanoid, np.zeros((2, 21), np.int64))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert err.details() == "action: expected dtype float32, got int64"


def test_data_length_mismatch(stub, humanoid) -> None:
    tensor = pb.Tensor(dtype=pb.DTYPE_FLOAT32, shape=[2, 21], data=b"\0" * 12)
    err = rpc_error(stub.Step, pb.StepRequest(session_id=humanoid, action=tensor))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert "expected 168 data bytes" in err.details() and "got 12" in err.details()


@pytest.mark.parametrize("value, word", [(np.nan, "nan"), (np.inf, "inf")])
def test_non_finite_action(stub, humanoid, value, word) -> None:
    a = np.zeros((2, 21), np.float32)
    a[1, 5] = value
    err = rpc_error(step, stub, humanoid, a)
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert "env 1 element (5,)" in err.details() and word in err.details() and "finite" in err.details()


def test_box_action_out_of_bounds(stub, humanoid) -> None:
    a = np.zeros((2, 21), np.float32)
    a[0, 3] = 1.5
    err = rpc_error(step, stub, humanoid, a)
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    msg = err.details()
    assert "env 0 element (3,)" in msg and "1.5" in msg and "<= 1.0" in msg and "-1.0 <=" in msg


def test_discrete_action_out_of_range(stub, dst) -> None:
    err = rpc_error(step, stub, dst, np.array([0, 4, 1], np.int64))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    msg = err.details()
    assert "env 1 = 4" in msg and "Discrete(4)" in msg and "<= 3" in msg


def test_unknown_env_id(stub) -> None:
    err = rpc_error(make, stub, "dts")
    assert err.code() == grpc.StatusCode.NOT_FOUND
    assert "'dts'" in err.details() and "dst" in err.details() and "humanoid-run" in err.details()


def test_unknown_adapter_id(stub) -> None:
    err = rpc_error(make, stub, "gym:Pendulum-v9")
    assert err.code() == grpc.StatusCode.NOT_FOUND
    assert "Pendulum-v1" in err.details()


def test_unknown_session(stub) -> None:
    err = rpc_error(step, stub, "abc", np.zeros((1,), np.int64))
    assert err.code() == grpc.StatusCode.NOT_FOUND
    assert err.details() == "unknown session 'abc' (closed, expired, or never made)"


def test_closed_session(stub) -> None:
    session_id = make(stub, "dst").session_id
    stub.Close(pb.CloseRequest(session_id=session_id))
    for call in (
        lambda: stub.Reset(pb.ResetRequest(session_id=session_id)),
        lambda: stub.Close(pb.CloseRequest(session_id=session_id)),
    ):
        err = rpc_error(call)
        assert err.code() == grpc.StatusCode.NOT_FOUND and session_id in err.details()


def test_step_before_reset(stub) -> None:
    session_id = make(stub, "dst").session_id
    err = rpc_error(step, stub, session_id, np.zeros((1,), np.int64))
    assert err.code() == grpc.StatusCode.FAILED_PRECONDITION
    assert f"session {session_id}: call Reset before Step" in err.details()
    stub.Close(pb.CloseRequest(session_id=session_id))


def test_bad_num_envs(stub) -> None:
    err = rpc_error(make, stub, "dst", 0)
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert "num_envs: expected >= 1, got 0" in err.details()


def test_reset_index_out_of_range(stub, dst) -> None:
    err = rpc_error(stub.Reset, pb.ResetRequest(session_id=dst, env_indices=[0, 3]))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert "env_indices" in err.details() and "< 3" in err.details() and "got 3" in err.details()


@pytest.mark.parametrize("text", ["{not json", "[1, 2]"])
def test_bad_kwargs_json(stub, text) -> None:
    err = rpc_error(make, stub, "dst", 1, kwargs_json=text)
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert "kwargs_json: expected a JSON object" in err.details() and text in err.details()


def test_deeply_nested_kwargs_json_is_the_clients_error(stub, humanoid) -> None:
    depth = 100_000
    text = '{"a":' * depth + "1" + "}" * depth
    err = rpc_error(make, stub, "dst", 1, kwargs_json=text)
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert err.details().startswith("kwargs_json: expected a JSON object nested at most"), err.details()[:200]
    # The message quotes a short prefix of the 600 kB value, not all of it.
    assert len(err.details()) < 300 and f"({len(repr(text))} characters)" in err.details()
    test_valid_step_still_works(stub, humanoid)


@pytest.mark.parametrize("dtype", [99, 20, 36, 68])
def test_unknown_action_dtype_number(stub, humanoid, dtype) -> None:
    tensor = pb.Tensor(dtype=dtype, shape=[2, 21], data=b"\0" * 168)
    err = rpc_error(stub.Step, pb.StepRequest(session_id=humanoid, action=tensor))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert err.details().startswith("action.dtype: expected a mo_env.v1.DType value")
    assert err.details().endswith(f"got {dtype}")
    test_valid_step_still_works(stub, humanoid)


@pytest.fixture(scope="module")
def dmc(stub) -> str:
    """A reset dm_control session of 2 instances (32-bit seeds)."""
    session_id = make(stub, "dmc:cartpole-balance", 2, seed=0).session_id
    stub.Reset(pb.ResetRequest(session_id=session_id))
    return session_id


@pytest.mark.parametrize("seeds", [[2**32], [2**32 - 1], [0, 2**64 - 1]])
def test_seed_outside_32_bits_is_refused_and_the_session_keeps_working(stub, dmc, seeds) -> None:
    # [2**32 - 1] alone is fine for instance 0 but gives instance 1 the seed 2**32.
    err = rpc_error(stub.Reset, pb.ResetRequest(session_id=dmc, seeds=seeds))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert err.details().startswith("seeds: expected instance seeds in [0, 2**32)"), err.details()
    response = step(stub, dmc, np.zeros((2, 1), np.float32))
    assert list(response.reward.shape) == [2, 1]
    stub.Reset(pb.ResetRequest(session_id=dmc, seeds=[2**32 - 2]))


def test_make_seed_outside_32_bits(stub) -> None:
    err = rpc_error(make, stub, "dst", 3, seed=2**32 - 2)
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert (
        err.details()
        == "seed: expected instance seeds in [0, 2**32) (a seed s for B instances uses s .. s+B-1), got 4294967296"
    )


@pytest.mark.parametrize("env_id", ["pendulum", "gym:Pendulum-v1"])
def test_kwarg_of_the_wrong_type_fails_at_make(stub, env_id) -> None:
    err = rpc_error(make, stub, env_id, 1, kwargs_json=json.dumps({"g": "x"}))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert err.details() == (
        "kwargs_json: env 'Pendulum-v1' keyword 'g' expects a float (its default is 10.0), got 'x'"
    )
    for good in (9.81, 9):
        session_id = make(stub, env_id, 1, kwargs_json=json.dumps({"g": good})).session_id
        stub.Reset(pb.ResetRequest(session_id=session_id))
        step(stub, session_id, np.zeros((1, 1), np.float32))
        stub.Close(pb.CloseRequest(session_id=session_id))


def test_huge_client_values_are_quoted_by_a_short_prefix(stub, humanoid) -> None:
    # Echoed whole, each message would pass the clients' 16 KiB metadata limit and the
    # real error would be lost behind a RESOURCE_EXHAUSTED.
    cases = [
        (grpc.StatusCode.NOT_FOUND, "env_id: unknown env 'xxxx", lambda: make(stub, "x" * 10**6, 1)),
        (
            grpc.StatusCode.NOT_FOUND,
            "env_id: unknown gymnasium id 'gym:xxxx",
            lambda: make(stub, "gym:" + "x" * 10**6, 1),
        ),
        (
            grpc.StatusCode.INVALID_ARGUMENT,
            "env_indices: expected distinct indices, got [0, 0, 0",
            lambda: stub.Reset(pb.ResetRequest(session_id=humanoid, env_indices=[0] * 10**6)),
        ),
        (
            grpc.StatusCode.INVALID_ARGUMENT,
            "action: expected shape [2, 21]",
            lambda: stub.Step(
                pb.StepRequest(
                    session_id=humanoid, action=pb.Tensor(dtype=pb.DTYPE_FLOAT32, shape=[1] * 100_000, data=b"")
                )
            ),
        ),
    ]
    for code, start, call in cases:
        err = rpc_error(call)
        assert err.code() == code, (start, err.code())
        assert err.details().startswith(start), err.details()[:200]
        assert len(err.details()) < 1000 and "characters)" in err.details(), err.details()[:200]
    test_valid_step_still_works(stub, humanoid)


def test_unknown_kwarg(stub) -> None:
    err = rpc_error(make, stub, "dst", 1, kwargs_json=json.dumps({"size": 3}))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert "kwargs_json" in err.details() and "'size'" in err.details()


def test_unknown_kwarg_adapter(stub) -> None:
    err = rpc_error(make, stub, "gym:Pendulum-v1", 1, kwargs_json=json.dumps({"gravity": 9.8, "wings": 2}))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert "kwargs_json" in err.details() and "wings" in err.details()


def test_bad_info_key(stub) -> None:
    err = rpc_error(make, stub, "faulty", 1, info_keys=["velocity"])
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert "info_keys" in err.details() and "velocity" in err.details() and "position" in err.details()


def test_simulator_exception_isolated(stub, dst) -> None:
    faulty = make(stub, "faulty", 2).session_id
    stub.Reset(pb.ResetRequest(session_id=faulty))
    err = rpc_error(step, stub, faulty, np.array([1, 3], np.int64))
    assert err.code() == grpc.StatusCode.INTERNAL
    assert err.details() == f"env faulty session {faulty} instance 1: RuntimeError: the simulator exploded"
    # The failed session needs a Reset; every other session keeps working.
    err = rpc_error(step, stub, faulty, np.array([1, 1], np.int64))
    assert err.code() == grpc.StatusCode.FAILED_PRECONDITION and "call Reset before Step" in err.details()
    assert list(step(stub, dst, np.array([1, 1, 1], np.int64)).terminated) == [False] * 3
    stub.Reset(pb.ResetRequest(session_id=faulty))
    assert list(step(stub, faulty, np.array([2, 0], np.int64)).reward.shape) == [2, 1]
    stub.Close(pb.CloseRequest(session_id=faulty))


def test_wrong_reward_size_is_internal(stub) -> None:
    session_id = make(stub, "bad-reward").session_id
    stub.Reset(pb.ResetRequest(session_id=session_id))
    err = rpc_error(step, stub, session_id, np.array([1], np.int64))
    assert err.code() == grpc.StatusCode.INTERNAL
    assert "env bad-reward" in err.details() and "shape [3], expected [1]" in err.details()
    stub.Close(pb.CloseRequest(session_id=session_id))


def test_too_many_sessions() -> None:
    with running_server("--max-sessions", "2") as addr, grpc.insecure_channel(addr) as channel:
        s = env_pb2_grpc.EnvServiceStub(channel)
        first = make(s, "dst").session_id
        make(s, "dst")
        err = rpc_error(make, s, "dst")
        assert err.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
        assert err.details() == (
            "session limit 2 reached (2 open); close sessions or start the server with --max-sessions"
        )
        s.Close(pb.CloseRequest(session_id=first))
        make(s, "dst")


@pytest.mark.parametrize("front", FRONTS)
def test_oversized_message(front: str) -> None:
    with running_server("--max-message-mb", "1", "--front", front) as addr, grpc.insecure_channel(addr) as channel:
        s = env_pb2_grpc.EnvServiceStub(channel)
        assert s.GetVersion(pb.GetVersionRequest()).max_message_bytes == 1024 * 1024
        session_id = make(s, "dst").session_id
        big = np.zeros(2 * 1024 * 1024 // 8, np.int64)
        err = rpc_error(step, s, session_id, big)
        assert err.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
        assert "1048576" in err.details(), err.details()  # names the limit
        requests = iter([pb.StepRequest(session_id=session_id, action=to_tensor(big))])
        with pytest.raises(grpc.RpcError) as streamed:
            list(s.StepStream(requests))
        assert streamed.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
        assert "1048576" in streamed.value.details(), streamed.value.details()
        assert s.GetVersion(pb.GetVersionRequest()).max_message_bytes == 1024 * 1024  # still serving
