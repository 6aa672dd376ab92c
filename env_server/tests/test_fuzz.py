"""Seeded fuzzing of every method on both fronts with random and mutated request bytes.

A client's garbage must never come back as INTERNAL or UNKNOWN (those say the server is
broken), and a healthy session stepping on its own channel meanwhile must never fail.
Bounded: CASES requests per method and front, about 5-10 s per front on 2 cores (3000 per
method, 40-60 s per front, found nothing more once undecodable bytes were INVALID_ARGUMENT).
"""

from __future__ import annotations

import random
import threading

import grpc
import numpy as np
import pytest
from conftest import FRONTS, make, running_server, step

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server._proto.mo_env.v1 import env_pb2_grpc
from env_server.client import to_tensor

CASES = 400
SEED = 14
SERVER_ERRORS = (grpc.StatusCode.INTERNAL, grpc.StatusCode.UNKNOWN)


def _mutate(rng: random.Random, valid: bytes) -> bytes:
    """Random bytes, or `valid` bit-flipped, truncated or extended."""
    kind = rng.randrange(4)
    if kind == 0 or not valid:
        return rng.randbytes(rng.randrange(0, 64))
    data = bytearray(valid)
    if kind == 1:
        for _ in range(rng.randint(1, 3)):
            bit = rng.randrange(len(data) * 8)
            data[bit // 8] ^= 1 << (bit % 8)
    elif kind == 2:
        del data[rng.randrange(len(data)) :]
    else:
        data[rng.randrange(len(data) + 1) : 0] = rng.randbytes(rng.randint(1, 16))
    return bytes(data)


def _templates(session_id: str) -> dict[str, bytes]:
    """A valid request per method, for the fuzz target session."""
    return {
        "GetVersion": b"",
        "ListEnvs": b"",
        "Make": pb.MakeRequest(
            env_id="dst", num_envs=2, seed=1, kwargs_json="{}", autoreset_mode=2, discount=0.9, info_keys=[]
        ).SerializeToString(),
        "Reset": pb.ResetRequest(session_id=session_id, env_indices=[0, 1], seeds=[3, 4]).SerializeToString(),
        "Step": pb.StepRequest(session_id=session_id, action=to_tensor(np.array([1, 2], np.int64))).SerializeToString(),
        "StepStream": pb.StepRequest(
            session_id=session_id, action=to_tensor(np.array([2, 1], np.int64))
        ).SerializeToString(),
        "Close": pb.CloseRequest(session_id=session_id).SerializeToString(),
    }


class _Healthy(threading.Thread):
    """Steps a dst session of its own over its own channel until stopped; records any error."""

    def __init__(self, address: str) -> None:
        super().__init__(daemon=True)
        self.address = address
        self.stop = threading.Event()
        self.errors: list[str] = []
        self.steps = 0

    def run(self) -> None:
        with grpc.insecure_channel(self.address) as channel:
            s = env_pb2_grpc.EnvServiceStub(channel)
            session_id = make(s, "dst", 2, seed=0).session_id
            s.Reset(pb.ResetRequest(session_id=session_id))
            while not self.stop.is_set():
                try:
                    step(s, session_id, np.array([1, 2], np.int64))
                    self.steps += 1
                except grpc.RpcError as exc:
                    self.errors.append(f"{exc.code()}: {exc.details()}")
                    return


def _close(stub: env_pb2_grpc.EnvServiceStub, session_id: str) -> None:
    try:
        stub.Close(pb.CloseRequest(session_id=session_id))
    except grpc.RpcError as exc:
        assert exc.code() == grpc.StatusCode.NOT_FOUND, exc.details()


def _call(channel: grpc.Channel, method: str, body: bytes, rng: random.Random) -> grpc.RpcError | bytes:
    path = f"/mo_env.v1.EnvService/{method}"
    try:
        if method == "StepStream":
            extra = [rng.choice([body, _mutate(rng, body)]) for _ in range(rng.randrange(3))]
            return b"".join(channel.stream_stream(path)(iter([body, *extra]), timeout=10))
        return channel.unary_unary(path)(body, timeout=10)
    except grpc.RpcError as exc:
        return exc


@pytest.mark.parametrize("front", FRONTS)
def test_fuzzed_requests_are_never_server_errors(front: str) -> None:
    rng = random.Random(SEED)
    # No worker processes: a fuzzed Make may ask for some, which would only slow the test.
    with running_server("--front", front, "--max-workers", "0") as addr, grpc.insecure_channel(addr) as channel:
        s = env_pb2_grpc.EnvServiceStub(channel)
        healthy = _Healthy(addr)
        healthy.start()
        failures: list[str] = []
        for method in _templates(""):
            target = make(s, "dst", 2).session_id
            s.Reset(pb.ResetRequest(session_id=target))
            valid = _templates(target)[method]
            for case in range(CASES):
                body = _mutate(rng, valid)
                result = _call(channel, method, body, rng)
                if isinstance(result, grpc.RpcError):
                    if result.code() in SERVER_ERRORS:
                        failures.append(f"{method} case {case} {body!r}: {result.code()}: {result.details()}")
                elif method == "Make":
                    _close(s, pb.MakeResponse.FromString(result).session_id)
            _close(s, target)  # unless a fuzzed Close or a finished StepStream closed it
        healthy.stop.set()
        healthy.join(10)
        assert not failures, "\n".join(failures[:20])
        assert not healthy.errors and healthy.steps > 0, (healthy.errors, healthy.steps)
        assert s.GetVersion(pb.GetVersionRequest()).protocol_version
