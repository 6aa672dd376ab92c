"""Resource limits for untrusted clients: instances per session, live instances across the
server, and a Make whose client gives up stops building."""

from __future__ import annotations

import time

import grpc
import numpy as np
import pytest
from conftest import FRONTS, make, rpc_error, running_server, step

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server._proto.mo_env.v1 import env_pb2_grpc


@pytest.fixture(scope="module")
def dst(stub) -> str:
    session_id = make(stub, "dst", 2).session_id
    stub.Reset(pb.ResetRequest(session_id=session_id))
    return session_id


def _still_steps(stub, session_id: str) -> None:
    assert list(step(stub, session_id, np.array([1, 1], np.int64)).reward.shape) == [2, 2]


@pytest.mark.parametrize("num_envs", [1025, 10**6, 2**31 - 1])
def test_num_envs_past_the_per_session_limit_is_refused_at_once(stub, dst, num_envs) -> None:
    # Accepted before the limit: 10**6 dst instances took 44 s and 1.6 GiB, 2**31-1 ran
    # the server out of memory.
    start = time.monotonic()
    err = rpc_error(make, stub, "dst", num_envs)
    assert time.monotonic() - start < 2.0
    assert err.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
    assert err.details() == (
        f"num_envs: this server allows at most 1024 instances per session (--max-envs-per-session), got {num_envs}"
    )
    _still_steps(stub, dst)


@pytest.mark.parametrize("front", FRONTS)
def test_live_instances_across_sessions_are_capped(front) -> None:
    args = ("--front", front, "--max-envs-per-session", "8", "--max-live-envs", "10")
    with running_server(*args) as addr, grpc.insecure_channel(addr) as channel:
        s = env_pb2_grpc.EnvServiceStub(channel)
        err = rpc_error(make, s, "dst", 9)
        assert err.code() == grpc.StatusCode.RESOURCE_EXHAUSTED and "(--max-envs-per-session), got 9" in err.details()
        first = make(s, "dst", 8).session_id
        s.Reset(pb.ResetRequest(session_id=first))
        err = rpc_error(make, s, "dst", 3)
        assert err.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
        assert err.details() == (
            "num_envs: 3 more instances would pass this server's limit of 10 live instances across all "
            "sessions (--max-live-envs; 8 live now); close sessions or ask for fewer"
        )
        second = make(s, "dst", 2).session_id  # exactly at the cap
        assert list(step(s, first, np.ones(8, np.int64)).reward.shape) == [8, 2]
        s.Close(pb.CloseRequest(session_id=first))
        make(s, "dst", 8)  # a closed session's instances count no more
        s.Close(pb.CloseRequest(session_id=second))


def _constructed(stub) -> int:
    """How many slow-build instances the server process has constructed so far (+1 for this probe)."""
    session_id = make(stub, "slow-build", 1, kwargs_json='{"build_seconds": 0}').session_id
    observation = stub.Reset(pb.ResetRequest(session_id=session_id)).observation[0].tensor
    stub.Close(pb.CloseRequest(session_id=session_id))
    return int(np.frombuffer(observation.data, np.float64)[0])


def test_make_whose_client_gives_up_stops_building(stub, dst) -> None:
    # 200 instances of 50 ms each would build for 10 s; the client waits 0.5 s. If the
    # build went on, about 20 instances would be built in each second after the deadline.
    before = _constructed(stub)
    request = pb.MakeRequest(env_id="slow-build", num_envs=200, kwargs_json='{"build_seconds": 0.05}')
    err = rpc_error(stub.Make, request, timeout=0.5)
    # tonic answers a passed grpc-timeout with CANCELLED "Timeout expired", which may
    # reach the client before its own DEADLINE_EXCEEDED.
    assert err.code() in (grpc.StatusCode.DEADLINE_EXCEEDED, grpc.StatusCode.CANCELLED), err.details()
    time.sleep(0.5)  # the build notices at its next instance (<= 50 ms)
    after_deadline = _constructed(stub)
    time.sleep(1.0)
    later = _constructed(stub)
    assert later - after_deadline == 1, (before, after_deadline, later)  # only the probe's own instance
    assert after_deadline - before < 40, (before, after_deadline)  # ~10 in the 0.5 s, + 1 probe
    _still_steps(stub, dst)
