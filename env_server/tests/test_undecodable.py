"""Request bytes that are not a valid protobuf message of the method's request type are
INVALID_ARGUMENT naming the method and the message type, on both fronts (tonic's codec
said INTERNAL, grpc.aio UNKNOWN)."""

from __future__ import annotations

import grpc
import numpy as np
import pytest
from conftest import make, rpc_error, step

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server.client import to_tensor

UNARY = ["GetVersion", "ListEnvs", "Make", "Reset", "Step", "Close"]
# A varint that never ends: no message of any type parses from it.
NOT_PROTOBUF = b"\xff\xff\xff"
# Field 1 (env_id / session_id, a string) holding two bytes that are not UTF-8.
BAD_UTF8 = b"\x0a\x02\xff\xfe"


def raw_unary(address: str, method: str, body: bytes) -> grpc.RpcError:
    with grpc.insecure_channel(address) as channel:
        call = channel.unary_unary(f"/mo_env.v1.EnvService/{method}")  # no serializers: raw bytes
        return rpc_error(call, body, timeout=10)


def _expected(method: str, body: bytes) -> str:
    request_type = "StepRequest" if method == "StepStream" else f"{method}Request"
    return f"{method}: expected a serialized mo_env.v1.{request_type}, got {len(body)} bytes that do not parse as one ("


@pytest.fixture(scope="module")
def dst(stub) -> str:
    session_id = make(stub, "dst", 2).session_id
    stub.Reset(pb.ResetRequest(session_id=session_id))
    return session_id


@pytest.mark.parametrize("method", UNARY)
def test_bytes_that_are_not_protobuf(address, stub, dst, method) -> None:
    err = raw_unary(address, method, NOT_PROTOBUF)
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT, (err.code(), err.details())
    assert err.details().startswith(_expected(method, NOT_PROTOBUF)), err.details()
    assert list(step(stub, dst, np.array([1, 1], np.int64)).reward.shape) == [2, 2]


@pytest.mark.parametrize("method", ["Make", "Reset", "Step", "Close"])
def test_invalid_utf8_in_a_string_field(address, stub, dst, method) -> None:
    err = raw_unary(address, method, BAD_UTF8)
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT, (err.code(), err.details())
    assert err.details().startswith(_expected(method, BAD_UTF8)), err.details()
    assert list(step(stub, dst, np.array([1, 1], np.int64)).reward.shape) == [2, 2]


@pytest.mark.parametrize("body", [NOT_PROTOBUF, BAD_UTF8])
def test_step_stream_with_an_undecodable_request(address, stub, body) -> None:
    session_id = make(stub, "dst", 2).session_id
    stub.Reset(pb.ResetRequest(session_id=session_id))
    good = pb.StepRequest(session_id=session_id, action=to_tensor(np.array([1, 1], np.int64))).SerializeToString()
    with grpc.insecure_channel(address) as channel:
        call = channel.stream_stream("/mo_env.v1.EnvService/StepStream")
        responses = call(iter([good, body]), timeout=10)
        assert next(responses)  # the good request's reply
        with pytest.raises(grpc.RpcError) as info:
            next(responses)
    assert info.value.code() == grpc.StatusCode.INVALID_ARGUMENT, info.value.details()
    assert info.value.details().startswith(_expected("StepStream", body)), info.value.details()
    # Like any bad request on a stream, it leaves the session usable.
    assert list(step(stub, session_id, np.array([1, 1], np.int64)).reward.shape) == [2, 2]
    stub.Close(pb.CloseRequest(session_id=session_id))
