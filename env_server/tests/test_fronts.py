"""The two transports (native tonic front, grpc.aio) serve one EnvService identically.

Every test on the shared `stub` already runs through both fronts (conftest.FRONTS);
these cover what differs between them: busy polling, flags, and shutdown with a
stream still open (tonic's graceful shutdown would wait for it forever).
"""

from __future__ import annotations

import queue
import subprocess
import sys
import time

import grpc
import numpy as np
import pytest
from conftest import FRONTS, make, running_server, server_env

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server._proto.mo_env.v1 import env_pb2_grpc
from env_server.client import to_tensor


def _streamed_humanoid(*server_args: str, steps: int = 30) -> list[bytes]:
    """Observation and reward bytes of a seeded humanoid-run x2 StepStream."""
    actions = np.random.default_rng(7).uniform(-1, 1, (steps, 2, 21)).astype(np.float32)
    with running_server(*server_args) as addr, grpc.insecure_channel(addr) as channel:
        stub = env_pb2_grpc.EnvServiceStub(channel)
        session_id = make(stub, "humanoid-run", 2, seed=3).session_id
        stub.Reset(pb.ResetRequest(session_id=session_id))
        requests = (pb.StepRequest(session_id=session_id, action=to_tensor(a)) for a in actions)
        return [r.observation[0].tensor.data + r.reward.data for r in stub.StepStream(requests)]


def test_busy_polling_native_front_steps_exactly_as_grpcio() -> None:
    polled = _streamed_humanoid("--front", "native", "--busy-poll-us", "300")
    assert len(polled) == 30
    assert polled == _streamed_humanoid("--front", "grpcio")


@pytest.mark.parametrize(
    "args, expected",
    [
        (
            ["--front", "grpcio", "--busy-poll-us", "5"],
            "--busy-poll-us: expected 0, or > 0 with the native front; got 5 with the grpcio front",
        ),
        (["--busy-poll-us", "-1"], "--busy-poll-us: expected 0, or > 0 with the native front; got -1"),
        # The flags' values in their order: --keepalive-seconds last.
        (["--keepalive-seconds", "0"], "1024, 4096, 0.0\n"),
    ],
)
def test_bad_front_flags_exit_with_a_message(args: list[str], expected: str) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "env_server", "--port", "0", *args],
        capture_output=True,
        text=True,
        env=server_env(),
        timeout=60,
    )
    assert proc.returncode == 2 and expected in proc.stderr, proc.stderr


@pytest.mark.parametrize("front", FRONTS)
def test_sigterm_with_a_stream_still_open_stops_after_the_grace(front: str) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "env_server", "--port", "0", "--front", front],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=server_env(),
    )
    address = proc.stdout.readline().split()[1]
    with grpc.insecure_channel(address) as channel:
        stub = env_pb2_grpc.EnvServiceStub(channel)
        session_id = make(stub, "dst").session_id
        stub.Reset(pb.ResetRequest(session_id=session_id))
        requests: queue.Queue = queue.Queue()
        requests.put(pb.StepRequest(session_id=session_id, action=to_tensor(np.array([1], np.int64))))
        call = stub.StepStream(iter(requests.get, None))
        next(call)  # the stream is open and idle
        start = time.monotonic()
        proc.terminate()
        _, err = proc.communicate(timeout=15)
        requests.put(None)
    assert proc.returncode == 0, err
    assert time.monotonic() - start < 10, "shutdown waited on the open stream"
    assert "server shutdown" in err or "StepStream broke" in err  # its session was closed
